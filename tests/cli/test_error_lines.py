"""Every error is one line, and an image is written whole or not at all: a full disk, an output
without an image suffix, a store Zarr warns about, a message about a large array."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
import zarr
from archive_helpers import copy_store
from pipeline_helpers import ltm_here, only_error_line, run_ltm, tmpfs

from ltmstore.cli import MESSAGE_MAX, one_line
from ltmstore.core.errors import LtmError, brief
from ltmstore.core.imagefile import write_image
from ltmstore.core.lights import normalise
from ltmstore.core.store import complete_stage


@pytest.fixture
def full_disk(tmp_path):
    """A folder on a 64 KiB tmpfs filled to the last byte (a real ENOSPC, not a file limit)."""
    with tmpfs(tmp_path / "full", "64k") as mount:
        with open(mount / "filler", "wb", buffering=0) as fh:
            try:
                while True:
                    fh.write(b"\0" * 4096)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
        yield mount


def test_an_image_on_a_full_disk_is_one_error_and_no_file(full_disk):
    image = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    with pytest.raises(LtmError, match=r"cannot write image .*x\.png.*No space left"):
        write_image(full_disk / "x.png", image)
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]  # no temporary, no 0 bytes


def test_a_failed_write_leaves_the_old_image(full_disk):
    (full_disk / "filler").unlink()
    old = write_image(full_disk / "x.png", np.zeros((4, 4), np.uint8)).read_bytes()
    (full_disk / "filler").write_bytes(b"\0" * 60_000)  # what is left is too small for noise
    noise = np.random.default_rng(0).integers(0, 255, (128, 128, 3), dtype=np.uint8)
    with pytest.raises(LtmError, match="No space left"):
        write_image(full_disk / "x.png", noise)
    assert (full_disk / "x.png").read_bytes() == old
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler", "x.png"]


def test_relight_onto_a_full_disk_prints_one_line_and_leaves_no_file(small_store, full_disk):
    proc = run_ltm("relight", small_store, "--light", "0,0", "-o", full_disk / "relit.png")
    only_error_line(proc, "cannot write image", "No space left on device")  # no __del__ noise
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]


def test_an_output_without_an_image_suffix_is_one_line(small_store, tmp_path):
    proc = run_ltm("relight", small_store, "--light", "0,0", "-o", tmp_path / "out")
    only_error_line(proc, "has no suffix", ".png")
    assert list(tmp_path.iterdir()) == []


def test_a_store_zarr_warns_about_prints_only_the_error(small_store, tmp_path):
    store = copy_store(small_store, tmp_path / "store.zarr")
    (store / "ltm" / "zarr.json").unlink()  # Zarr: "Object at ltm is not recognized ..."
    proc = run_ltm("relight", store, "--light", "0,0", "-o", tmp_path / "x.png")
    only_error_line(proc, "ltm")
    assert "Warning" not in proc.stderr


def test_non_finite_poses_are_a_short_error_naming_the_damage(small_store, tmp_path, capsys):
    store = copy_store(small_store, tmp_path / "store.zarr")
    pose_r = zarr.open_array(str(store / "pose_r"), mode="r+")  # checksums stay consistent
    values = pose_r[:]
    values[np.flatnonzero(zarr.open_array(str(store / "pose_valid"))[:])[:900]] = np.nan
    pose_r[:] = values  # not all NaN: Zarr would drop an all-fill chunk (a missing chunk)
    # as if ingest had written them: its record of what it wrote follows
    complete_stage(zarr.open_group(str(store), mode="r+"), "ingest", {})
    proc = ltm_here(capsys, "relight", store, "--light", "0,0", "-o", tmp_path / "x.png")
    only_error_line(proc, "poses", "not finite", "damaged")
    assert "missing" not in proc.stderr
    assert len(proc.stderr) < 200, len(proc.stderr)  # was the whole array: ~18 kB
    assert not (tmp_path / "x.png").exists()


def test_a_message_about_a_large_array_is_bounded():
    with pytest.raises(LtmError) as caught:
        normalise(np.full((1233, 3), np.nan))
    assert len(str(caught.value)) < 150 and "(1233, 3)" in str(caught.value)
    assert "3699 not finite" in str(caught.value)
    assert brief([0.5, np.nan]) == "[0.5, nan]"


def test_every_error_line_is_one_bounded_line():
    assert one_line("cannot read\n  the store\tnow") == "cannot read the store now"
    long = "x" * 5000 + " expected a finite number"
    line = one_line(long)
    assert len(line) == MESSAGE_MAX and " ... " in line
    assert line.endswith("expected a finite number")  # what was expected survives


def test_relit_gif_and_png_are_readable_after_an_atomic_write(tmp_path):
    import imageio.v3 as iio

    frames = np.random.default_rng(1).integers(0, 255, (3, 8, 10, 3), dtype=np.uint8)
    gif = write_image(tmp_path / "a.gif", frames, duration=100, loop=0)
    png = write_image(tmp_path / "a.png", frames[0])
    assert iio.imread(gif, index=None).shape == (3, 8, 10, 3)
    np.testing.assert_array_equal(iio.imread(png), frames[0])
    assert oct(png.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.png"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask

