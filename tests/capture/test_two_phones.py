"""Issue 7 end to end: two plain videos -> calibrate, track, sync, ingest, reconstruct.

The raw capture is simulated at 640 x 360 with a 500 px focal length (the same field of view as
the 1280 x 720 default, a quarter of the pixels, so the test stays fast); the full-resolution
accuracy is measured by ``bench/track_bench.py``.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest
from pipeline_helpers import one_line_error, run_ltm

from ltmstore.capture.acquisition import load_poses

SEED = 3
OFFSET = -0.27  # s: phone A's clock starts 0.27 s before video B's


@pytest.fixture(scope="module")
def raw_capture(tmp_path_factory):
    from ltmstore.synthetic.raw import PhoneCamera, simulate_raw

    out = tmp_path_factory.mktemp("raw") / "capture"
    info = simulate_raw(out, scene="canvas", path_density=5.0, seed=SEED, size=24,
                        lattice=(12, 12), camera=PhoneCamera(size=(640, 360), focal_px=500.0),
                        time_offset=OFFSET, calibration_views=10, progress=False,
                        board=True, effects="none")  # the ideal phones of issue 7
    return out, info


@pytest.fixture(scope="module")
def tracked(raw_capture):
    """calibrate + track + sync through the CLI, as a user runs them."""
    acq, info = raw_capture
    proc = run_ltm("calibrate", acq / "calibration.mkv", "--board", acq / "board.json", "-o",
                   acq / "intrinsics.json")
    assert proc.returncode == 0, proc.stderr
    proc = run_ltm("track", acq / "phone_a.mkv", "--board", acq / "board.json", "--intrinsics",
                   acq / "intrinsics.json", "--led-offset",
                   ",".join(map(str, info["led_offset"])), "-o", acq / "poses.csv")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    before = (acq / "acquisition.json").read_bytes()
    proc = run_ltm("sync", acq)
    assert proc.returncode == 0, proc.stderr
    return acq, info, summary, before


def test_calibration_recovers_the_focal_length(tracked):
    acq, info, _, _ = tracked
    intr = json.loads((acq / "intrinsics.json").read_text())
    assert intr["reprojection_rms_px"] < 0.3
    assert abs(intr["camera_matrix"][0][0] - 500.0) < 2.5  # 0.5 %


def test_tracking_beats_the_paper(tracked):
    """RMS LED error below the paper's PTAM (0.31 mm) on the 40 cm plane."""
    acq, info, summary, _ = tracked
    # every frame posed; the hand's short excursions off the plane are flagged, and kept
    assert summary["rows"] == summary["frames"] == summary["status"]["ok"] + \
        summary["status"]["out_of_plane"]
    got = load_poses(acq / "poses.csv")
    true = load_poses(acq / "truth" / "poses_true.csv")
    assert len(got) == len(true)
    np.testing.assert_allclose(got.t, true.t - OFFSET, atol=1e-3)
    err = np.column_stack([got.r - true.r, got.s - true.s, got.z - true.z])
    rms_mm = 1e3 * np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms_mm < 0.31, rms_mm


def test_sync_within_a_frame_and_backup_kept(tracked):
    acq, _, _, before = tracked
    meta = json.loads((acq / "acquisition.json").read_text())
    assert abs(meta["time_offset"] - OFFSET) < 1 / 30
    assert meta["time_offset_estimate"]["stderr_s"] < 1 / 30
    assert (acq / "acquisition.json.bak").read_bytes() == before
    proc = run_ltm("sync", acq)
    one_line_error(proc, "already declares time_offset")


def test_end_to_end_snr_close_to_true_poses(tracked, tmp_path, dask_cluster):
    from distributed import Client

    from ltmstore.judge.evaluate import compare_stores
    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct

    acq, _, _, _ = tracked
    truth_acq = tmp_path / "true"
    truth_acq.mkdir()
    try:
        os.link(acq / "video.mkv", truth_acq / "video.mkv")
    except OSError:
        shutil.copy2(acq / "video.mkv", truth_acq / "video.mkv")
    shutil.copy2(acq / "truth" / "poses_true.csv", truth_acq / "poses.csv")
    meta = json.loads((acq / "acquisition.json").read_text())
    meta.pop("time_offset")
    (truth_acq / "acquisition.json").write_text(json.dumps(meta))
    snr = {}
    with Client(dask_cluster) as client:
        for name, folder in (("tracked", acq), ("true", truth_acq)):
            store = tmp_path / f"{name}.zarr"
            ingest(folder, store, progress=False)
            reconstruct(store, client=client, lattice=(12, 12), progress=False)
            snr[name] = compare_stores(store, acq / "truth.zarr")["snr_y_db"]
    # Issue 29's target: within 1 dB. At 24 px and 12 x 12 cells the gap is a lottery of the
    # few samples near cell edges: true poses plus 0.13 mm noise per axis (the tracker's level)
    # gave 16.21-16.91 dB over three noise seeds; this capture's tracked poses (0.21 mm RMS)
    # measured 0.67-0.92 dB below the true ones.
    assert abs(snr["true"] - snr["tracked"]) < 1.0, snr


@pytest.mark.parametrize(("case", "pattern"), [
    ("missing_intrinsics", "does not exist; expected the JSON written by `ltm calibrate`"),
    ("wrong_board", "wrong --board spec, or board not in view"),
    ("wrong_resolution", "expected intrinsics calibrated for this camera"),
    ("bad_led_offset", "must look like DX,DY,DZ"),
])
def test_track_bad_input_one_line_errors(raw_capture, tmp_path, case, pattern):
    from ltmstore.capture.board import board_spec, write_board

    acq, _ = raw_capture
    args = {"board": acq / "board.json", "intrinsics": acq / "truth" / "intrinsics.json",
            "led": "0.012,0,0"}
    if case == "missing_intrinsics":
        args["intrinsics"] = tmp_path / "nope.json"
    elif case == "wrong_board":
        write_board(tmp_path / "a4.png", board_spec("A4"))
        args["board"] = tmp_path / "a4.json"
    elif case == "wrong_resolution":
        intr = json.loads((acq / "truth" / "intrinsics.json").read_text())
        intr["image_size"] = [1280, 720]
        (tmp_path / "i.json").write_text(json.dumps(intr))
        args["intrinsics"] = tmp_path / "i.json"
    else:
        args["led"] = "1,2"
    proc = run_ltm("track", acq / "phone_a.mkv", "--board", args["board"], "--intrinsics",
                   args["intrinsics"], "--led-offset", args["led"], "-o", tmp_path / "p.csv")
    one_line_error(proc, pattern)
    assert not (tmp_path / "p.csv").exists()
