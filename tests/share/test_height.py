"""The surface as a surface: normals integrated into a height map (:mod:`ltmstore.share.height`)
and written by ``ltm maps --height --mesh`` as a 16-bit PNG and PLY and OBJ meshes in mm."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from locations import SHARED_DATA

from ltmstore.cli import build_parser, main
from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import linear_to_srgb
from ltmstore.share import height as ht
from ltmstore.solve import height as hi
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct

BUMPS = ((40, 50, 12, 6.0), (95, 30, 9, -4.0))  # column, row, sigma, height (pixels)
TILT = (0.05, 0.02)  # dz/dcol, dz/drow


def surface(h: int = 96, w: int = 128, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A height map ``(h, w)`` in pixels (two Gaussian bumps on a tilted plane) and its exact
    unit normals, x right, y up, z towards the camera."""
    r, c = np.mgrid[0:h, 0:w].astype(np.float64) * scale
    z = TILT[0] * c + TILT[1] * r
    gx, gy = np.full_like(z, TILT[0]), np.full_like(z, TILT[1])
    for c0, r0, sigma, top in BUMPS:
        bump = top * np.exp(-((c - c0) ** 2 + (r - r0) ** 2) / (2 * sigma**2))
        z, gx, gy = z + bump, gx - bump * (c - c0) / sigma**2, gy - bump * (r - r0) / sigma**2
    normal = np.stack([-gx, gy, np.ones_like(z)], axis=-1)  # rows grow with -y
    return z / scale, normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(((a - a.mean()) - (b - b.mean())) ** 2)))


@pytest.mark.parametrize("method, bound", [("poisson", 0.002), ("fc", 0.002),
                                           ("bilateral", 0.002)])
def test_known_surface_integrates_back(method, bound):
    """Measured on a 9 px relief: RMS 0.0010 px (poisson), 0.0011 px (fc), 0.0009 px
    (bilateral: a smooth surface has no side to prefer)."""
    z, normal = surface()
    height = hi.integrate(normal, method)
    assert height.min() == 0 and rms(height, z) < bound
    assert np.ptp(height) == pytest.approx(np.ptp(z), rel=2e-3)


def test_missing_and_grazing_normals_stay_finite():
    _, normal = surface(24, 32)
    normal[3:6, 4:9] = np.nan
    normal[10, 10] = [1.0, 0.0, 0.0]
    for method in hi.INTEGRATIONS:
        assert np.isfinite(hi.integrate(normal, method)).all()
    with pytest.raises(LtmError, match="integration 'bni' must be one of poisson, fc, bilateral"):
        hi.integrate(normal, "bni")


BAS_RELIEF = SHARED_DATA / "synthrti" / "single-obj2-material1" / "normals.png"


@pytest.mark.skipif(not BAS_RELIEF.exists(), reason="SynthRTI is not beside the checkout")
def test_synthrti_bas_relief_normals():
    """SynthRTI gives the bas-relief's normals, not its depth: the height is checked by the
    normals it gives back (central differences). Measured: median 5.4 degrees (poisson) and
    5.2 (fc), where the relief's occluding edges are no gradient of any surface, 3.4
    (bilateral, which keeps those edges as steps); height range 67.5, 68.0 and 68.4 px."""
    code = cv2.imread(str(BAS_RELIEF), cv2.IMREAD_UNCHANGED)[..., ::-1]
    normal = code / 65535 * 2 - 1
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    for method, bound in (("poisson", 5.8), ("fc", 5.6), ("bilateral", 3.8)):
        height = hi.integrate(normal, method)
        back = hi.normals_of(height)
        error = np.degrees(np.arccos(np.clip((back * normal).sum(axis=-1), -1, 1)))
        assert np.median(error) < bound, (method, np.median(error))
        assert 60 < height.max() < 75, (method, height.max())


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a binary little-endian PLY, parsed by hand."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    assert header[1] == "format binary_little_endian 1.0"
    count = {line.split()[1]: int(line.split()[2]) for line in header
             if line.startswith("element")}
    vertices = np.frombuffer(data, "<f4", count["vertex"] * 3, end).reshape(-1, 3)
    faces = np.frombuffer(data, [("n", "u1"), ("i", "<i4", (3,))], count["face"],
                          end + count["vertex"] * 12)
    assert (faces["n"] == 3).all()
    return vertices, faces["i"]


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [line.split() for line in path.read_text().splitlines() if line[:2] in ("v ", "f ")]
    vertices = np.array([r[1:] for r in rows if r[0] == "v"], dtype=np.float64)
    faces = np.array([r[1:] for r in rows if r[0] == "f"], dtype=np.int64) - 1
    return vertices, faces


def test_mesh_round_trip(tmp_path):
    z, normal = surface()
    files, info = ht.write_height(normal, tmp_path, pixel_mm=0.25, mesh=True, step=2)
    png = cv2.imread(str(files["height"]), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png.shape == z.shape and png.min() == 0
    assert png.max() == 65535
    assert json.loads(files["json"].read_text())["range_mm"] == pytest.approx(
        np.ptp(z) * 0.25, rel=2e-3)
    for reader, path in ((read_ply, files["ply"]), (read_obj, files["obj"])):
        vertices, faces = reader(path)
        assert len(vertices) == 48 * 64 and len(faces) == 2 * 47 * 63
        assert faces.min() == 0 and faces.max() == len(vertices) - 1
        assert np.ptp(vertices[:, 0]) == pytest.approx(126 * 0.25, abs=1e-3)  # mm
        assert np.ptp(vertices[:, 2]) == pytest.approx(np.ptp(z[::2, ::2]) * 0.25, rel=3e-3)
        a, b, c = (vertices[faces[:, k]] for k in range(3))
        assert (np.cross(b - a, c - a)[:, 2] > 0).all()  # counter-clockwise from the camera
    assert info["vertices"] == 48 * 64


H, W = 24, 32


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """A far-light store with the surface model: a Lambertian relief of known height
    (:func:`surface` shrunk 4 times: 2.24 px), 24 lights."""
    root = tmp_path_factory.mktemp("height")
    _, normal = surface(H, W, scale=4.0)
    rng = np.random.default_rng(3)
    azimuth, elevation = rng.uniform(0, 2 * np.pi, 24), np.radians(rng.uniform(25, 85, 24))
    dirs = np.column_stack([np.cos(elevation) * np.cos(azimuth),
                            np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    (root / "cap").mkdir()
    lines = [str(len(dirs))]
    for i, d in enumerate(dirs):
        linear = 0.6 * np.clip(normal @ d, 0, None)[..., None] * [1.0, 0.9, 0.8] + 0.02
        assert cv2.imwrite(str(root / "cap" / f"im{i:02d}.png"),
                           np.round(linear_to_srgb(linear) * 255).astype(np.uint8)[..., ::-1])
        lines.append(f"im{i:02d}.png {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}")
    (root / "cap" / "dirs.lp").write_text("\n".join(lines) + "\n")
    ingest_rti(root / "cap" / "dirs.lp", root / "s.zarr", progress=False)
    reconstruct(root / "s.zarr", method="physical", progress=False)
    return root / "s.zarr"


def test_maps_writes_height_and_meshes_in_mm(store, tmp_path, capsys):
    """Measured: height range 2.226 px (fc; poisson 2.197) from the fitted normals against
    2.239 px true."""
    z = surface(H, W, scale=4.0)[0]
    out = tmp_path / "maps"
    assert main(["maps", str(store), str(out), "--mesh", "--object-width", "64",
                 "--integration", "fc"]) == 0
    said = capsys.readouterr().out
    assert "height.ply" in said and "height range" in said and "mm (fc)" in said
    info = json.loads((out / "height.json").read_text())
    assert info["pixel_mm"] == 2.0 and info["mesh_step_px"] == 1
    vertices, faces = read_ply(out / "height.ply")
    assert len(vertices) == H * W and len(faces) == 2 * (H - 1) * (W - 1)
    assert np.ptp(vertices[:, 2]) == pytest.approx(np.ptp(z) * 2.0, rel=0.015)
    assert len(read_obj(out / "height.obj")[0]) == H * W


@pytest.mark.parametrize("extra, match", [
    (["--mesh"], "--mesh writes millimetres: give the scale with --pixel-size"),
    (["--pixel-size", "0.1"], "scale the height map: add --height or --mesh"),
    (["--height", "--pixel-size", "-1"], "--pixel-size -1.0 must be a length in mm > 0"),
    (["--height", "--mesh-step", "0"], "--mesh-step 0 must be a whole number"),
])
def test_bad_height_options(store, tmp_path, capsys, extra, match):
    assert main(["maps", str(store), str(tmp_path / "m"), *extra]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1
    assert not (tmp_path / "m").exists()


def test_cli_choices_copy_the_library():
    sub = next(a for a in build_parser()._subparsers._group_actions)
    maps = sub.choices["maps"]
    option = next(a for a in maps._actions if "--integration" in a.option_strings)
    assert tuple(option.choices) == hi.INTEGRATIONS and option.default == hi.DEFAULT_INTEGRATION
