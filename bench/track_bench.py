"""Issue-7 benchmark: two ordinary phones, from raw videos to an LTM.

Simulates a raw two-phone capture (``ltm simulate --raw``: phone A at 1280 x 720 filming a
ChArUco board, video B of the painting, an unknown clock offset), then

1. calibrates phone A from its calibration video (reprojection error, focal error);
2. tracks phone A's video with the calibrated intrinsics (and, for reference, the true ones):
   RMS LED position error in mm against the true trajectory over the 40 cm plane;
3. synchronises: the estimated clock offset against the truth, in frames, for the capture's own
   offset and for six more captures (video B of other seeds, offsets of 0.17-0.48 s either
   way, poses with the measured tracking noise);
4. ingests and reconstructs the tracked acquisition and the same acquisition with the true
   poses, and compares SNR_Y against the ground truth.

Run: ``python bench/track_bench.py [--out bench/results] [--path-density 27] [--size 64]``.
Writes ``track.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from ltmstore import __version__
from ltmstore.capture.acquisition import Poses, load_poses
from ltmstore.capture.board import load_board
from ltmstore.capture.calibrate import calibrate_video, load_intrinsics
from ltmstore.capture.sync import block_brightness, estimate_offset, sync_acquisition
from ltmstore.capture.track import TrackConfig, track
from ltmstore.judge.evaluate import compare_stores
from ltmstore.stages.ingest import ingest
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.synthetic import writer
from ltmstore.synthetic.raw import simulate_raw
from ltmstore.synthetic.render import render_frames
from ltmstore.synthetic.simulate import plan_simulation, video_frames

SYNC_OFFSETS = (-0.48, -0.33, -0.21, 0.17, 0.29, 0.44)  # s


def led_errors(poses_csv: Path, truth_csv: Path, offset: float) -> dict:
    """Tracked LED positions against the truth at the same phone-A frames, in mm."""
    got = load_poses(poses_csv)
    true = load_poses(truth_csv)
    t_true = true.t - offset  # phone A's clock
    idx = np.searchsorted(t_true, got.t).clip(1, len(t_true) - 1)
    idx = np.where(np.abs(t_true[idx - 1] - got.t) < np.abs(t_true[idx] - got.t), idx - 1, idx)
    assert np.abs(t_true[idx] - got.t).max() < 1e-3
    err = np.column_stack([got.r - true.r[idx], got.s - true.s[idx], got.z - true.z[idx]]) * 1e3
    d3 = np.linalg.norm(err, axis=1)
    return {"rms_mm": float(np.sqrt(np.mean(d3**2))),
            "rms_rs_mm": float(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1)))),
            "rms_r_mm": float(np.sqrt(np.mean(err[:, 0] ** 2))),
            "rms_s_mm": float(np.sqrt(np.mean(err[:, 1] ** 2))),
            "rms_z_mm": float(np.sqrt(np.mean(err[:, 2] ** 2))),
            "p95_mm": float(np.percentile(d3, 95)), "max_mm": float(d3.max()),
            "frames": len(got.t)}


def link_or_copy(src: Path, dst: Path) -> None:
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def reconstruct_snr(acq: Path, truth: Path, lattice: tuple[int, int]) -> dict:
    store = acq.with_name(acq.name + ".zarr")  # beside the acquisition, never inside it
    start = time.perf_counter()
    ing = ingest(acq, store, progress=False, overwrite=True)
    info = reconstruct(store, lattice=lattice, progress=False, overwrite=True)
    cmp = compare_stores(store, truth)
    return {"snr_y_db": cmp["snr_y_db"], "psnr_db_median": cmp["psnr_db_median"],
            "n_valid": ing["n_valid"], "n_frames": ing["n_frames"],
            "sampling_ratio": info["sampling_ratio"], "seconds": time.perf_counter() - start}


def sync_trials(work: Path, scene: str, noise_m: float) -> list[dict]:
    """Sync alone on more captures: video B of other seeds, poses = the true LED at phone A's
    frame times (30 fps, clock shifted by the offset) plus the tracking noise measured above."""
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for seed, offset in zip(range(1, 7), SYNC_OFFSETS, strict=True):
        plan = plan_simulation(scene=scene, path_density=15.0, seed=seed, size=32)
        peak = float(render_frames(plan.scene, plan.frame_lights()[::10]).max())
        exposure = 0.9 / max(peak, 1e-9)
        writer.write_video(work / "b.mkv", video_frames(plan, exposure=exposure))
        brightness, fps = block_brightness(work / "b.mkv", "srgb", progress=False)
        t_a = np.arange(plan.frame_count) / writer.FPS
        hand = plan.video_start + offset + t_a
        rng = np.random.default_rng(seed)
        r, s, z = (c + rng.normal(0, noise_m, len(t_a)) for c in plan.trajectory.at(hand)[:3])
        est = estimate_offset(brightness, fps, Poses(t_a, r, s, z))
        rows.append({"seed": seed, "true_s": offset, "estimated_s": est["time_offset"],
                     "error_frames": fps * (est["time_offset"] - offset),
                     "stderr_ms": 1e3 * est["stderr_s"], "contrast": est["contrast"]})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--path-density", type=float, default=27.0)
    parser.add_argument("--size", type=int, default=64, help="video B side, pixels")
    parser.add_argument("--scene", default="canvas")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", help="keep the simulated capture here (default: a temp dir)")
    parser.add_argument("--reuse", action="store_true",
                        help="reuse the capture already simulated in --work")
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix="ltm-track-bench-"))
    acq = work / "raw"
    t0 = time.perf_counter()
    reused = args.reuse and (acq / "truth" / "raw.json").is_file()
    if reused:
        sim = json.loads((acq / "truth" / "raw.json").read_text())
        timings = {}
    else:
        sim = simulate_raw(acq, scene=args.scene, path_density=args.path_density,
                           seed=args.seed, size=args.size, overwrite=True, progress=False,
                           board=True, effects="none")  # issue 7's ideal phones
        timings = {"simulate_s": time.perf_counter() - t0}
    meta_path = acq / "acquisition.json"
    meta = json.loads(meta_path.read_text())
    for key in ("time_offset", "time_offset_estimate"):
        meta.pop(key, None)
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    true_offset = sim["time_offset"]
    spec = load_board(acq / "board.json")

    t0 = time.perf_counter()
    intr, calib = calibrate_video(acq / "calibration.mkv", spec, progress=False)
    intr.write(acq / "intrinsics.json")
    timings["calibrate_s"] = time.perf_counter() - t0
    focal = sim["camera"]["focal_px"]
    calib["focal_error_percent"] = float(100 * (np.mean(calib["focal_px"]) - focal) / focal)

    config = TrackConfig(led_offset=tuple(sim["led_offset"]))
    t0 = time.perf_counter()
    summary = track(acq / "phone_a.mkv", spec, intr, acq / "poses.csv", config=config,
                    overwrite=True, progress=False)
    timings["track_s"] = time.perf_counter() - t0
    truth_csv = acq / "truth" / "poses_true.csv"
    tracking = {"calibrated": {**led_errors(acq / "poses.csv", truth_csv, true_offset),
                               "status": summary["status"],
                               "reprojection_px": summary["reprojection_px"],
                               "corners_median": summary["corners"]}}
    ref = work / "poses_true_intrinsics.csv"
    track(acq / "phone_a.mkv", spec, load_intrinsics(acq / "truth" / "intrinsics.json"), ref,
          config=config, overwrite=True, progress=False)
    tracking["true_intrinsics"] = led_errors(ref, truth_csv, true_offset)

    t0 = time.perf_counter()
    synced = sync_acquisition(acq, progress=False)
    timings["sync_s"] = time.perf_counter() - t0
    fps = sim["fps"]
    sync = {"true_s": true_offset, "estimated_s": synced["time_offset"],
            "error_ms": 1e3 * (synced["time_offset"] - true_offset),
            "error_frames": fps * (synced["time_offset"] - true_offset),
            "stderr_ms": 1e3 * synced["stderr_s"], "r2": synced["r2"],
            "contrast": synced["contrast"]}
    sync["trials"] = sync_trials(work / "sync_trials", args.scene,
                                 tracking["calibrated"]["rms_mm"] / 1e3)
    sync["max_abs_error_frames"] = max(abs(sync["error_frames"]),
                                       *(abs(s["error_frames"]) for s in sync["trials"]))

    true_acq = work / "true_poses"
    true_acq.mkdir(exist_ok=True)
    link_or_copy(acq / "video.mkv", true_acq / "video.mkv")
    shutil.copy2(truth_csv, true_acq / "poses.csv")
    meta = json.loads((acq / "acquisition.json").read_text())
    for key in ("time_offset", "time_offset_estimate", "phone_a"):
        meta.pop(key, None)
    (true_acq / "acquisition.json").write_text(json.dumps(meta, indent=2))
    lattice = tuple(sim["lattice"])
    t0 = time.perf_counter()
    snr = {"tracked": reconstruct_snr(acq, acq / "truth.zarr", lattice),
           "true_poses": reconstruct_snr(true_acq, acq / "truth.zarr", lattice)}
    timings["reconstruct_both_s"] = time.perf_counter() - t0
    snr["difference_db"] = snr["true_poses"]["snr_y_db"] - snr["tracked"]["snr_y_db"]

    result = {
        "issue": 7, "version": __version__, "python": platform.python_version(),
        "machine": platform.machine(), "cpus": os.cpu_count(),
        "command": "python bench/track_bench.py " + " ".join(
            f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()
            if k not in ("out", "work", "reuse") and v is not None),
        "capture": {k: sim[k] for k in ("frames", "camera", "led_offset", "scene", "seed",
                                        "sampling_ratio", "lattice")},
        "capture_reused": bool(reused), "plane_m": 0.4, "paper_ptam_rms_mm": 0.31,
        "calibration": calib, "tracking": tracking, "sync": sync, "snr": snr,
        "timings": timings,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "track.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({"rms_led_mm": tracking["calibrated"]["rms_mm"],
                      "rms_led_mm_true_intrinsics": tracking["true_intrinsics"]["rms_mm"],
                      "calibration_rms_px": calib["reprojection_rms_px"],
                      "sync_error_frames": sync["max_abs_error_frames"],
                      "snr_true_db": snr["true_poses"]["snr_y_db"],
                      "snr_tracked_db": snr["tracked"]["snr_y_db"]}, indent=2))
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
