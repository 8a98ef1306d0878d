"""RTI light files and RTI captures -> store, on tiny synthetic captures and the real data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import xarray as xr
from ingest_helpers import encode, tree_hashes

from ltmstore.capture.lp import read_lp
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.stages.ingest_rti import EXTENT_PER_HEIGHT, ingest_rti

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
# images, height, width, lights outside the default plane
REAL = {"realrti-item3-icon": (72, 395, 402, 19), "realrti-item9-coin": (48, 289, 279, 4),
        "loewenkopf": (240, 43, 64, 68)}
# Light directions of the tiny capture: (lx, ly, lz) before normalisation.
DIRS = np.array([[0, 0, 1], [0.5, 0, 1], [0, -0.5, 1], [1, 1, 1], [-1, 0.2, 1], [0.2, 0.1, 2],
                 [0.1, 0.1, 1], [-0.3, -0.3, 1], [0.4, 0.2, 1], [3, 0, 1], [0, 0.3, 1]])
COLOUR = np.array([0.7, 0.5, 0.3])  # linear RGB of the tiny scene


def gains(n):
    return 0.2 + 0.6 * np.arange(n) / n


def write_capture(folder: Path, dirs=DIRS, *, trailing: str = "   ") -> Path:
    """Tiny PNG capture: image i is the constant colour COLOUR * gains[i] (sRGB encoded)."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"{len(dirs)}{trailing}"]
    for i, (d, g) in enumerate(zip(dirs, gains(len(dirs)), strict=True)):
        rgb = encode(np.broadcast_to(g * COLOUR, (6, 5, 3)), "srgb")
        assert cv2.imwrite(str(folder / f"im{i:02d}.png"), rgb[..., ::-1])
        lines.append(f"im{i:02d}.png {d[0]} {d[1]} {d[2]}{trailing}")
    path = folder / "dirs.lp"
    path.write_text("\n".join(lines) + "\n\n")
    return path


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
    ("1\nim00.png 0.5 0 -0.2\n", r"line 2: lz = -0.2 for 'im00.png'; expected lz > 0"),
    ("1\nim00.png 0 0 0\n", "line 2: lz = 0.0 for 'im00.png'; expected lz > 0"),
    ("1\nmissing.png 0 0 1\n", "line 2: image 'missing.png' does not exist"),
    ("1\n../im00.png 0 0 1\n", "line 2: image '../im00.png' leaves the folder"),
])
def test_bad_lp(lp, text, match):
    bad = lp.parent / "bad.lp"
    bad.write_text(text)
    with pytest.raises(LtmError, match=match):
        read_lp(bad)


def test_lp_absolute_image_path(lp):
    bad = lp.parent / "bad.lp"
    bad.write_text(f"1\n{lp.parent / 'im00.png'} 0 0 1\n")
    with pytest.raises(LtmError, match="is an absolute path"):
        read_lp(bad)


def test_lp_missing(tmp_path):
    with pytest.raises(LtmError, match="light file '.*nope.lp' cannot be read"):
        read_lp(tmp_path / "nope.lp")


def test_ingest_rti(lp, tmp_path):
    before = tree_hashes(lp.parent)
    store = tmp_path / "s.zarr"
    report = ingest_rti(lp, store, height=2.0, extent=1.5, progress=False, chunk_frames=4)
    n = len(DIRS)
    r, s = 2.0 * DIRS[:, 0] / DIRS[:, 2], 2.0 * DIRS[:, 1] / DIRS[:, 2]
    inside = (np.abs(r) <= 1.5) & (np.abs(s) <= 1.5)
    assert report["n_frames"] == n and report["n_valid"] == inside.sum() == 8
    assert report["rejected"] == {"beyond_poses": 0, "out_of_plane": 0,
                                  "outside_bounds": n - inside.sum()}
    ds = xr.open_zarr(store, consolidated=False)
    assert dict(ds.sizes) == {"t": n, "y": 6, "x": 5, "channel": 2}
    np.testing.assert_array_equal(ds.t, np.arange(n))
    np.testing.assert_allclose(ds.pose_r, r)
    np.testing.assert_allclose(ds.pose_s, s)
    np.testing.assert_allclose(ds.pose_z, 2.0)
    np.testing.assert_array_equal(ds.pose_valid, inside)
    luma = COLOUR @ [0.299, 0.587, 0.114]
    np.testing.assert_allclose(ds.frames.mean(("y", "x")), gains(n) * luma, rtol=0.02)
    ratio = [(COLOUR[2] - luma) / 1.772 / luma, (COLOUR[0] - luma) / 1.402 / luma]
    np.testing.assert_allclose(ds.chroma.values, np.broadcast_to(ratio, (6, 5, 2)), atol=0.01)
    acq = open_store(store).attrs["acquisition"]
    assert acq["source"] == "rti" and acq["lp"] == "dirs.lp" and acq["height"] == 2.0
    assert acq["plane"] == {"r": [-1.5, 1.5], "s": [-1.5, 1.5], "height": 2.0, "unit": "m"}
    assert set(acq["sha256"]) == {"lp", "images"}
    assert tree_hashes(lp.parent) == before


def test_default_extent(lp, tmp_path):
    report = ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    # extent 2 * height: only the light at 71.6 degrees from the zenith ([3, 0, 1]) is outside
    assert report["rejected"]["outside_bounds"] == 1


def test_image_size_mismatch(lp, tmp_path):
    cv2.imwrite(str(lp.parent / "im03.png"), np.zeros((7, 5, 3), np.uint8))
    with pytest.raises(LtmError, match=r"image 'im03.png' is 5x7 pixels; expected 5x6"):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists()


def test_image_not_decodable(lp, tmp_path):
    (lp.parent / "im02.png").write_text("not an image")
    with pytest.raises(LtmError, match="image 'im02.png' cannot be decoded"):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)


@pytest.mark.parametrize("kwargs, match", [({"height": 0}, "height 0 must be a positive"),
                                           ({"extent": -1.0}, "extent -1.0 must be a positive"),
                                           ({"height": float("nan")}, "height nan must be")])
def test_bad_geometry(lp, tmp_path, kwargs, match):
    with pytest.raises(LtmError, match=match):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False, **kwargs)


def test_too_few_lights_inside(lp, tmp_path):
    with pytest.raises(LtmError, match=r"only 3 of 11 frames are valid"):
        ingest_rti(lp, tmp_path / "s.zarr", extent=0.15, progress=False)


def test_existing_store(lp, tmp_path):
    store = tmp_path / "s.zarr"
    ingest_rti(lp, store, progress=False)
    with pytest.raises(LtmError, match="already exists"):
        ingest_rti(lp, store, progress=False)
    assert ingest_rti(lp, store, extent=0.6, overwrite=True, progress=False)["n_valid"] == 8


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_data(name, tmp_path):
    folder = SHARED_DATA / name
    if not folder.is_dir():
        pytest.skip(f"shared/data/{name} not found: expected the real RTI data at {folder}")
    lp = next(folder.glob("*.lp"))
    n, height, width, n_outside = REAL[name]
    names, dirs = read_lp(lp)
    assert len(names) == n
    report = ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    ds = open_store(tmp_path / "s.zarr")
    assert ds.frames.shape == (n, height, width)
    assert ds.chroma.shape == (height, width, 2)
    # default plane [-2h, 2h]^2: a light is outside when |lx| or |ly| exceeds 2 lz; every light
    # below atan(1 / (2 sqrt 2)) ~ 19.5 degrees of elevation is outside
    outside = ~ds.pose_valid.values
    expected = np.abs(dirs[:, :2]).max(axis=1) / dirs[:, 2] > EXTENT_PER_HEIGHT
    np.testing.assert_array_equal(outside, expected)
    low = np.degrees(np.arcsin(dirs[:, 2])) < 19.4
    assert outside[low].all()
    assert outside.sum() == n_outside
    assert report["rejected"] == {"beyond_poses": 0, "out_of_plane": 0,
                                  "outside_bounds": n_outside}
    assert report["n_valid"] == n - outside.sum() >= n // 2
    assert np.isfinite(ds.frames[:: max(1, n // 8)].values).all()
    assert 0 < float(ds.frames[0].mean()) < 1
