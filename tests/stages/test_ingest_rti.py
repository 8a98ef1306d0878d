"""RTI light files and RTI captures -> store, on tiny synthetic captures and the real data."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import xarray as xr
from ingest_helpers import COLOUR, DIRS, gains, tree_hashes, write_capture
from locations import SHARED_DATA

from ltmstore.capture.lp import LpWarning, read_lp
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.stages.ingest_rti import ingest_rti

# images, height, width, lights that the old plane [-2h, 2h]^2 dropped (all are kept now)
REAL = {"realrti-item3-icon": (72, 395, 402, 19), "realrti-item9-coin": (48, 289, 279, 4),
        "loewenkopf": (240, 43, 64, 68)}
@pytest.fixture
def lp(tmp_path):
    return write_capture(tmp_path / "cap")


def test_read_lp(lp):
    names, dirs = read_lp(lp)
    assert names == [f"im{i:02d}.png" for i in range(len(DIRS))]
    np.testing.assert_allclose(dirs, DIRS / np.linalg.norm(DIRS, axis=1, keepdims=True))


def test_read_lp_names_with_subfolder_and_spaces(tmp_path):
    (tmp_path / "jpg").mkdir()
    (tmp_path / "jpg" / "a b.jpg").write_bytes(b"")
    (tmp_path / "x.lp").write_text("1\r\njpg/a b.jpg 0 0 2\r\n")
    names, dirs = read_lp(tmp_path / "x.lp")
    assert names == ["jpg/a b.jpg"]
    np.testing.assert_allclose(dirs, [[0, 0, 1]])


@pytest.mark.parametrize("text, match", [
    ("abc\nim00.png 0 0 1\n", "line 1: 'abc' must be the number of images"),
    ("0\n", "line 1: '0' must be the number of images"),
    ("", "line 1: '' must be the number of images"),
    ("2\nim00.png 0 0 1\n", "declares 2 images but lists 1"),
    ("1\nim00.png 0 0 1\nim01.png 0 0 1\n", "declares 1 images but lists 2"),
    ("1\nim00.png 0 x 1\n", "line 2: 'im00.png 0 x 1' must be 'image lx ly lz'"),
    ("1\nim00.png 0 1\n", "line 2: 'im00.png 0 1' must be 'image lx ly lz'"),
    ("1\nim00.png 0 nan 1\n", "line 2: .* three finite numbers"),
    ("1\nim00.png 0.5 0 -0.2\n", "has no light above the horizon"),
    ("1\nim00.png 0 0 0\n", "has no light above the horizon"),
    ("1\nmissing.png 0 0 1\n", "line 2: image 'missing.png' does not exist"),
    ("1\n../missing.png 0 0 1\n", r"line 2: image '../missing.png' does not exist \(nor"),
])
def test_bad_lp(lp, text, match):
    bad = lp.parent / "bad.lp"
    bad.write_text(text)
    with pytest.raises(LtmError, match=match):
        read_lp(bad)


def test_lp_absolute_and_windows_paths_resolve_by_name(lp):
    other = lp.parent / "other.lp"
    other.write_text(f"3\n{lp.parent / 'im00.png'} 0 0 1\nC:\\capture\\jpg\\im01.png 0.1 0 1\n"
                     "../im02.png 0 0.1 1\n")
    with pytest.warns(LpWarning, match=r"other.lp: 3 image path\(s\) written on another machine "
                      r"found by file name \(first: '/"):
        names, dirs = read_lp(other)
    assert names == ["im00.png", "im01.png", "im02.png"] and len(dirs) == 3


def test_lp_rtibuilder_layout(tmp_path):
    lp = write_capture(tmp_path / "project" / "jpeg-exports")
    (tmp_path / "project" / "assembly-files").mkdir()
    moved = tmp_path / "project" / "assembly-files" / "capture.lp"
    moved.write_text(lp.read_text().replace("im", "D:\\project\\jpeg-exports\\im"))
    lp.unlink()
    with pytest.warns(LpWarning, match="found by file name"):
        names, _ = read_lp(moved)
    assert names[0] == "../jpeg-exports/im00.png"
    report = ingest_rti(moved, tmp_path / "s.zarr", progress=False)
    assert report["n_valid"] == len(DIRS)


def test_lp_never_reads_outside_the_capture(tmp_path):
    write_capture(tmp_path / "elsewhere")
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "dirs.lp").write_text("1\n../elsewhere/im00.png 0 0 1\n")
    with pytest.raises(LtmError, match=r"image '../elsewhere/im00.png' does not exist \(nor "
                       r"'im00.png' beside the .lp file or in a sibling image folder\)"):
        read_lp(tmp_path / "cap" / "dirs.lp")


def test_lp_lights_below_the_horizon_are_skipped_with_one_warning(lp):
    text = lp.read_text().splitlines()
    text[0] = str(len(DIRS) + 2)
    text += ["im00.png 0.5 0 -0.001", "im01.png 1 0 -0.2"]
    lp.write_text("\n".join(text) + "\n")
    with pytest.warns(LpWarning) as caught:
        names, dirs = read_lp(lp)
    assert len(caught) == 1
    assert str(caught[0].message).endswith("skipped 2 light(s) at or below the horizon: line 14 "
                                           "(lz = -0.001), line 15 (lz = -0.2)")
    assert len(names) == len(DIRS) and (dirs[:, 2] > 0).all()


def test_lp_16_bit_images_keep_16_bits(tmp_path):
    folder = tmp_path / "cap16"
    folder.mkdir()
    levels = [1000 + 50 * i for i in range(8)]  # 16-bit levels 8 bits cannot all tell apart
    lines = [str(len(levels))]
    for i, v in enumerate(levels):
        cv2.imwrite(str(folder / f"im{i}.png"), np.full((4, 4, 3), v, np.uint16))
        lines.append(f"im{i}.png {0.1 * i} 0 1")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    ingest_rti(folder / "dirs.lp", tmp_path / "s.zarr", progress=False)
    frames = open_store(tmp_path / "s.zarr").frames.mean(("y", "x")).values
    assert len(np.unique(frames)) == 8 and np.all(np.diff(frames) > 0)


def test_lp_missing(tmp_path):
    with pytest.raises(LtmError, match="light file '.*nope.lp' cannot be read"):
        read_lp(tmp_path / "nope.lp")


def test_ingest_rti(lp, tmp_path):
    before = tree_hashes(lp.parent)
    store = tmp_path / "s.zarr"
    report = ingest_rti(lp, store, progress=False, chunk_frames=4)
    n = len(DIRS)
    unit = DIRS / np.linalg.norm(DIRS, axis=1, keepdims=True)
    assert report["n_frames"] == n and report["n_valid"] == n  # every light is kept
    assert report["rejected"] == {"beyond_poses": 0, "out_of_plane": 0, "outside_bounds": 0}
    ds = xr.open_zarr(store, consolidated=False)
    assert dict(ds.sizes) == {"t": n, "y": 6, "x": 5, "channel": 2}
    np.testing.assert_array_equal(ds.t, np.arange(n))
    np.testing.assert_allclose(np.column_stack([ds.pose_r, ds.pose_s, ds.pose_z]), unit)
    assert ds.pose_valid.values.all()
    luma = COLOUR @ [0.299, 0.587, 0.114]
    np.testing.assert_allclose(ds.frames.mean(("y", "x")), gains(n) * luma, rtol=0.02)
    ratio = [(COLOUR[2] - luma) / 1.772 / luma, (COLOUR[0] - luma) / 1.402 / luma]
    np.testing.assert_allclose(ds.chroma.values, np.broadcast_to(ratio, (6, 5, 2)), atol=0.01)
    opened = open_store(store)
    assert ds.frames.data.chunks[0][0] == 4  # 4 frames a stored chunk, all of them a task:
    assert opened.frames.data.chunks[0] == opened.frame_chroma.data.chunks[1] == (n,)
    acq = opened.attrs["acquisition"]
    assert acq["source"] == "rti" and acq["lp"] == "dirs.lp" and acq["light_kind"] == "far"
    assert acq["lp_path"] == str(lp.resolve())
    assert acq["coordinates"]["r"]["units"] == "1"
    assert set(acq["sha256"]) == {"lp", "images"}
    assert tree_hashes(lp.parent) == before


def test_ingest_rti_subset_of_lights(lp, tmp_path):
    report = ingest_rti(lp, tmp_path / "s.zarr", lights=[0, 2, 3, 4, 6, 7, 8, 10],
                        progress=False)
    assert report["n_frames"] == 8
    with pytest.raises(LtmError, match=r"lights \[0, 11\] must be indices of the 11 lights"):
        ingest_rti(lp, tmp_path / "t.zarr", lights=[0, 11], progress=False)


def test_image_size_mismatch(lp, tmp_path):
    cv2.imwrite(str(lp.parent / "im03.png"), np.zeros((7, 5, 3), np.uint8))
    with pytest.raises(LtmError, match=r"image 'im03.png' is 5x7 pixels; expected 5x6"):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists()


def test_image_not_decodable(lp, tmp_path):
    (lp.parent / "im02.png").write_text("not an image")
    with pytest.raises(LtmError, match="image 'im02.png' cannot be decoded"):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)


def test_existing_store(lp, tmp_path):
    store = tmp_path / "s.zarr"
    ingest_rti(lp, store, progress=False)
    with pytest.raises(LtmError, match="already exists"):
        ingest_rti(lp, store, progress=False)
    assert ingest_rti(lp, store, overwrite=True, progress=False)["n_valid"] == len(DIRS)


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_data(name, tmp_path):
    folder = SHARED_DATA / name
    if not folder.is_dir():
        pytest.skip(f"shared/data/{name} not found: expected the real RTI data at {folder}")
    lp = next(folder.glob("*.lp"))
    n, height, width, n_low = REAL[name]
    names, dirs = read_lp(lp)
    assert len(names) == n
    report = ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    ds = open_store(tmp_path / "s.zarr")
    assert ds.frames.shape == (n, height, width)
    assert ds.chroma.shape == (height, width, 2)
    # every light is kept, the low raking ones too (a plane [-2h, 2h]^2 dropped them)
    assert (np.abs(dirs[:, :2]).max(axis=1) / dirs[:, 2] > 2).sum() == n_low
    assert ds.pose_valid.values.all() and report["n_valid"] == n
    assert report["rejected"] == {"beyond_poses": 0, "out_of_plane": 0, "outside_bounds": 0}
    assert np.isfinite(ds.frames[:: max(1, n // 8)].values).all()
    assert 0 < float(ds.frames[0].mean()) < 1


def test_rti_commands_load_only_what_they_need(lp, tmp_path):
    """``ltm ingest-rti`` and ``ltm reconstruct`` of a far-light store, in a fresh Python: no
    Dask, xarray, Prefect or scikit-learn is imported (each costs a command 0.2-1 s of
    start-up; a small capture pays for nothing it does not use)."""
    import json
    import subprocess
    import sys

    # SciPy is not among them: Numba (the compiled far-light surface fit) loads scipy.linalg
    # to check its BLAS (0.2 s, measured; the fit saves 4-30 s on these captures)
    heavy = ("dask", "distributed", "xarray", "pandas", "prefect", "sklearn", "skimage", "av")
    code = ("import json, sys; from ltmstore.cli import main; "
            f"assert main(['ingest-rti', {str(lp)!r}, {str(tmp_path / 's.zarr')!r}]) == 0; "
            f"assert main(['reconstruct', {str(tmp_path / 's.zarr')!r}]) == 0; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.splitlines()[-1]
    assert not set(json.loads(out)) & set(heavy), out
    # ingest alone sums a short capture's frames in NumPy: Numba (0.6-0.8 s) is not loaded;
    # nor is it, or SciPy (the height map's FFT), by the first stage, the relightable store
    code = ("import json, sys; from ltmstore.cli import main; "
            f"assert main(['ingest-rti', {str(lp)!r}, {str(tmp_path / 'i.zarr')!r}]) == 0; "
            f"assert main(['reconstruct', {str(tmp_path / 'i.zarr')!r}, '--stage', "
            "'classic']) == 0; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.splitlines()[-1]
    assert not set(json.loads(out)) & {*heavy, "numba", "llvmlite", "scipy"}, out


def test_loo_mse_by_gram_matrix_is_the_direct_mean():
    from ltmstore.stages.reconstruct_far import _loo_mse

    rng = np.random.default_rng(0)
    values = rng.random((12, 500), dtype=np.float32)
    loo = rng.standard_normal((3, 12, 12))
    direct = [np.mean((a @ values.astype(np.float64)) ** 2) for a in loo]
    usable = np.array([True, True, False])
    np.testing.assert_allclose(_loo_mse(values, loo, usable)[:2], direct[:2], rtol=1e-10)
    assert _loo_mse(values, loo, usable)[2] == np.inf



def test_large_photographs_are_spilled_into_whole_chunks(lp, tmp_path, monkeypatch):
    """Where only one photograph may be held before it is written (a 24 MP capture's memory),
    ingest-rti spills them and stores the frames in chunks of ``chunk_frames`` all the same:
    the store the one held whole gives, bit for bit, whole by ``ltm check``, no spill left."""
    from ltmstore.core.store import verify_store
    from ltmstore.stages import ingest_rti as module

    ingest_rti(lp, tmp_path / "held.zarr", progress=False, chunk_frames=4)
    monkeypatch.setattr(module, "BUFFER_BYTES", 6 * 6 * 5)  # one 6 x 5 frame of Y, Cb, Cr
    ingest_rti(lp, tmp_path / "spilled.zarr", progress=False, chunk_frames=4)
    held, spilled = (xr.open_zarr(tmp_path / name, consolidated=False)
                     for name in ("held.zarr", "spilled.zarr"))
    assert set(spilled.variables) == set(held.variables)
    for name in ("frames", "frame_chroma", "chroma", "chroma_spread"):
        np.testing.assert_array_equal(spilled[name].values, held[name].values)
        assert spilled[name].encoding["chunks"] == held[name].encoding["chunks"]
    assert verify_store(tmp_path / "spilled.zarr", progress=False)["damaged"] == []
