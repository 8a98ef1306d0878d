"""`ltm compact`: a smaller store that relights the same, passes `ltm check` and says what it
dropped; the light-major copy that relight reads; the float16 option's measured SNR."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from pipeline_helpers import run_ltm

from ltmstore.core.store import open_store, store_summary
from ltmstore.stages.relight import disk_light, relight

LIGHTS = [(-0.05, 0.03), (0.08, -0.11)]


@pytest.fixture
def store_copy(small_store, tmp_path):
    """A copy of the session's reconstructed store (hard links: compact never edits a file)."""
    return shutil.copytree(small_store, tmp_path / "store.zarr", copy_function=os.link)


def test_reconstruct_writes_the_light_major_copy_relight_reads(small_store):
    ds = open_store(small_store)
    assert ds["ltm_by_light"].shape == ds["ltm"].shape
    assert np.array_equal(ds["ltm_by_light"].values, ds["ltm"].values)
    fast = relight(ds, LIGHTS).values
    slow = relight(ds.drop_vars("ltm_by_light"), LIGHTS).values
    assert np.array_equal(fast, slow)  # the same arithmetic on the same values
    area = disk_light(ds["ltm"], (0.0, 0.0), 0.08)
    assert area.sum() == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(relight(ds, area).values,
                               relight(ds.drop_vars("ltm_by_light"), area).values, rtol=1e-5)


def test_compact_drops_frames_and_keeps_relight_and_check(store_copy, small_store):
    before = relight(small_store, LIGHTS).values
    proc = run_ltm("compact", store_copy)
    assert proc.returncode == 0, proc.stderr
    assert "frames dropped" in proc.stdout and "lossless" in proc.stdout
    assert not (store_copy / "frames").exists() and not (store_copy / "frame_chroma").exists()
    assert np.array_equal(relight(store_copy, LIGHTS).values, before)
    check = run_ltm("check", store_copy)
    assert check.returncode == 0, check.stderr
    info = store_summary(store_copy)
    assert info["complete"] and info["frames"]["stored"] is False
    assert info["compact"]["precision"] == "float32" and info["compact"]["snr_db"] is None
    assert (small_store / "frames").is_dir()  # the original store is untouched


def test_float16_is_lossy_within_its_measured_snr(store_copy, small_store):
    from ltmstore.stages.compact import compact, store_bytes

    before = store_bytes(store_copy)
    info = compact(store_copy, precision="float16", keep_frames=True)
    assert info["snr_db"] > 72.7  # measured 73.71 dB (float16 keeps 11 significant bits)
    assert info["bytes_after"] < before
    ds = open_store(store_copy)
    assert ds["ltm"].dtype == np.float32  # read back as float32
    truth = open_store(small_store)["ltm"].values
    error = ds["ltm"].values - truth
    assert 10 * np.log10(np.sum(truth ** 2) / np.sum(error ** 2)) == pytest.approx(
        info["snr_db"], abs=0.01)


def test_reconstruct_after_compact_is_a_one_line_error(store_copy, capsys):
    from ltmstore.cli import main
    from ltmstore.stages.compact import compact

    compact(store_copy)
    assert main(["reconstruct", str(store_copy), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "ltm compact" in err and "ingest" in err


def test_a_store_without_the_light_major_copy_relights_the_same_and_compact_adds_it(
        small_store, tmp_path, client):
    """``reconstruct(light_major=False)`` (``--no-light-major``) writes no copy; relight reads
    ``ltm`` itself with the same result; ``ltm compact`` adds the copy later."""
    from archive_helpers import ingest_only

    from ltmstore.stages.compact import compact
    from ltmstore.stages.reconstruct import reconstruct

    store = ingest_only(small_store, tmp_path / "store.zarr")
    reconstruct(store, client=client, lattice=(16, 16), light_major=False, progress=False)
    assert "ltm_by_light" not in open_store(store)
    expected = relight(small_store, LIGHTS).values
    np.testing.assert_array_equal(relight(store, LIGHTS).values, expected)
    compact(store, keep_frames=True)
    assert "ltm_by_light" in open_store(store)
    np.testing.assert_array_equal(relight(store, LIGHTS).values, expected)
