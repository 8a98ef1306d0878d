"""Simulated acquisitions: the folder, the ground truth and their round trip."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import xarray as xr

from ltmstore.core.dims import LUMA, Plane
from ltmstore.core.errors import LtmError
from ltmstore.core.store import stages
from ltmstore.core.transfer import decode
from ltmstore.synthetic.render import render_ltm
from ltmstore.synthetic.simulate import (
    EXPOSURE_PEAK,
    TRACKER_NOISE,
    simulate_acquisition,
    video_frames,
)
from ltmstore.synthetic.trajectory import sampling_ratio

from .conftest import SIM_ARGS


def _decode(path: str) -> list[np.ndarray]:
    cap = cv2.VideoCapture(path)
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame[..., ::-1])
    cap.release()
    return frames


def _poses(path: str) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1)


def test_folder_contract(simulation):
    folder = Path(simulation["paths"]["folder"])
    assert sorted(p.name for p in folder.iterdir()) == \
        ["acquisition.json", "poses.csv", "truth.zarr", "video.mkv"]
    meta = json.loads((folder / "acquisition.json").read_text())
    assert meta["format"] == "ltm-acquisition/1" and meta["transfer"] == "srgb"
    assert meta["video"] == "video.mkv" and meta["poses"] == "poses.csv"
    assert Plane.from_json(meta["plane"]).area == pytest.approx(0.16)
    assert meta["simulation"]["scene"] == "relief" and meta["simulation"]["seed"] == 3
    assert (folder / "poses.csv").read_text().startswith("t,r,s,z\n")


def test_summary(simulation, simulation_plan):
    assert simulation["frames"] == simulation_plan.frame_count
    assert simulation["duration_s"] == pytest.approx(simulation["frames"] / 30)
    assert simulation["path_density"] == pytest.approx(SIM_ARGS["path_density"], rel=0.1)
    lights = simulation_plan.frame_lights()
    assert simulation["sampling_ratio"] == sampling_ratio(lights[:, 0], lights[:, 1],
                                                          simulation_plan.lattice)


def test_truth_store(simulation, simulation_plan):
    ds = xr.open_zarr(simulation["paths"]["truth"], consolidated=False)
    assert ds["ltm"].dims == ("y", "x", "r", "s") and ds["ltm"].shape == (32, 32, 8, 8)
    assert ds["ltm_rgb"].dims == ("y", "x", "r", "s", "color")
    assert list(ds["color"].values) == ["R", "G", "B"]
    np.testing.assert_allclose(ds["r"], simulation_plan.lattice.centres(0))
    rgb = ds["ltm_rgb"].values
    np.testing.assert_allclose(ds["ltm"].values, rgb @ LUMA, rtol=1e-5, atol=1e-7)
    assert rgb.max() == pytest.approx(EXPOSURE_PEAK, rel=1e-5)
    exposure = ds.attrs["exposure"]
    plan = simulation_plan
    expected = render_ltm(plan.scene, plan.lattice, plan.plane.height) * np.float32(exposure)
    np.testing.assert_allclose(rgb, expected, rtol=1e-6)
    assert ds.attrs["plane"] == plan.plane.to_json()
    assert ds.attrs["lattice"]["shape"] == [8, 8]
    assert stages(_group(simulation["paths"]["truth"]))["truth"]["complete"] is True


def _group(path):
    from ltmstore.core.store import open_group

    return open_group(path)


def test_lossless_video_round_trip(simulation, simulation_plan):
    decoded = _decode(simulation["paths"]["video"])
    written = list(video_frames(simulation_plan, exposure=simulation["exposure"]))
    assert len(decoded) == len(written) == simulation["frames"]
    diff = np.abs(np.stack(decoded).astype(int) - np.stack(written))
    assert diff.max() <= 1


def test_frames_show_the_truth_through_srgb(simulation, simulation_plan):
    """A frame whose light sits near a lattice centre, linearised, matches that truth column."""
    plan = simulation_plan
    lights = plan.frame_lights()
    r, s = plan.lattice.centres(0), plan.lattice.centres(1)
    rr, ss = np.meshgrid(r, s, indexing="ij")
    dist = np.hypot(lights[:, :1, None] - rr, lights[:, 1:2, None] - ss)
    k, i, j = np.unravel_index(np.argmin(dist), dist.shape)
    linear = decode(_decode(simulation["paths"]["video"])[k], "srgb")
    ds = xr.open_zarr(simulation["paths"]["truth"], consolidated=False)
    truth = ds["ltm_rgb"].values[:, :, i, j]
    lit = truth > 0.05
    assert np.median(np.abs(linear[lit] / truth[lit] - 1)) < 0.05


def test_poses_match_the_true_path(simulation, simulation_plan):
    poses = _poses(simulation["paths"]["poses"])
    t = poses[:, 0]
    assert np.all(np.diff(t) > 0) and np.std(np.diff(t)) > 0
    assert abs(t[0]) <= 0.11 and abs(t[-1] - (simulation["frames"] - 1) / 30) <= 0.11
    frame_t = np.arange(simulation["frames"]) / 30
    inside = (frame_t >= t[0]) & (frame_t <= t[-1])
    true = simulation_plan.frame_lights()[inside]
    for col in (1, 2):
        est = np.interp(frame_t[inside], t, poses[:, col])
        rms = np.sqrt(np.mean((est - true[:, col - 1]) ** 2))
        assert rms < 3 * TRACKER_NOISE


def test_refuses_a_non_empty_folder_then_overwrites(tmp_path):
    out = tmp_path / "acq"
    out.mkdir()
    (out / "video.mkv").write_text("old")
    (out / "acquisition.json").write_text('{"simulation": {}}')  # an earlier simulation's
    args = {"scene": "canvas", "path_density": 2.0, "size": 16, "lattice": (4, 4),
            "progress": False}
    with pytest.raises(LtmError, match="is not empty; pass --overwrite"):
        simulate_acquisition(out, **args)
    summary = simulate_acquisition(out, overwrite=True, lossy=True, **args)
    assert not (out / "video.mkv").exists() and summary["paths"]["video"].endswith("video.mp4")
    assert len(_decode(summary["paths"]["video"])) == summary["frames"]


def test_delta_rs_sets_the_truth_lattice(tmp_path):
    summary = simulate_acquisition(tmp_path / "acq", path_density=2.0, size=16, delta_rs=0.1,
                                   progress=False)
    assert summary["lattice"] == [4, 4]
    assert xr.open_zarr(summary["paths"]["truth"], consolidated=False)["ltm"].shape[2:] == (4, 4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"scene": "fresco"}, "unknown scene 'fresco'"),
     ({"path_density": -1.0}, r"--path-density -1.0 must be a positive number"),
     ({"path_density": 0.0}, r"--path-density 0.0 must be a positive number"),
     ({"lattice": (8,)}, r"lattice \(8,\) must be two cell counts"),
     ({"delta_rs": -0.1}, r"--delta-rs -0.1 must be a positive number")],
)
def test_bad_arguments(tmp_path, kwargs, message):
    out = tmp_path / "acq"
    with pytest.raises(LtmError, match=message):
        simulate_acquisition(out, size=16, progress=False, **kwargs)
    assert not out.exists()


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(LtmError, match="cannot create output folder .*file.txt/acq"):
        simulate_acquisition(blocker / "acq", size=16, progress=False)
    with pytest.raises(LtmError, match="exists and is not a folder"):
        simulate_acquisition(blocker, size=16, progress=False)
