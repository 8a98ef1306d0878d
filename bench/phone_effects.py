"""Issue-29 benchmark: the two-phone chain on phones as they are, one effect at a time.

For each scene, each tracking target (phone A films the ChArUco board, ``--board``; or the
painting alone, boardless) and each set of phone effects (none, every effect of
:mod:`ltmstore.synthetic.phone_effects` alone, all together), simulate a raw capture
(``simulate_raw``) and run the product's own commands on it, as a user would::

    ltm calibrate calibration.mkv --board board.json -o intrinsics.json        (phone A)
    ltm calibrate calibration_b.mkv --board board_b.json -o intrinsics_b.json  (camera B, when
                                                                                 distorted)
    ltm track phone_a.* --board board.json | --painting video.* --painting-width W ...
    ltm sync .
    ltm ingest . store.zarr ; ltm reconstruct store.zarr --lattice RxS

then measure against the truth: LED position error (RMS and 95th percentile, mm; tracked frames
matched by time to ``truth/poses_true.csv`` as in ``bench/track_bench.py``), the fraction of
phone A's frames placed, the sync error (frames) and SNR_Y of the LTM against ``truth.zarr``
beside the same capture ingested with the true poses. A step that fails is recorded with its
one-line error and the row goes on without it where it can.

Run: ``python bench/phone_effects.py --quick`` (one scene, small, effects none and all) or
``python bench/phone_effects.py`` (two scenes, every effect alone). Writes
``phone_effects.json`` and ``phone_effects.png`` into ``--out`` (default bench/results).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from track_bench import led_errors, link_or_copy  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.judge.evaluate import compare_stores  # noqa: E402
from ltmstore.synthetic.phone_effects import EFFECTS, READOUT_S  # noqa: E402
from ltmstore.synthetic.raw import PhoneCamera, simulate_raw  # noqa: E402

LTM = [str(Path(sys.executable).parent / "ltm")]
LENSES = {"main": 1000.0, "ultrawide": 540.0}  # phone A's focal length, pixels at 1280 wide
TARGETS = {"led_rms_mm": 1.0, "placed_fraction": 0.9, "snr_gap_db": 1.0}  # issue 29, item 4


def ltm(*args, cwd: Path | None = None) -> tuple[bool, str, str]:
    """Run an ``ltm`` command; ``(ok, stdout, last stderr line)``."""
    proc = subprocess.run([*LTM, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    lines = proc.stderr.strip().splitlines()
    return proc.returncode == 0, proc.stdout, lines[-1] if lines else ""


def painting_option() -> bool:
    """Whether ``ltm track`` offers boardless tracking (``--painting``)."""
    ok, out, _ = ltm("track", "--help")
    return ok and "--painting" in out


def simulate(acq: Path, scene: str, tracking: str, effects: str, args) -> dict:
    w, h = args.phone_size
    camera = PhoneCamera(size=(w, h), focal_px=LENSES[args.lens] * w / 1280)
    return simulate_raw(acq, scene=scene, path_density=args.path_density, seed=args.seed,
                        size=args.size, lattice=tuple(args.lattice), camera=camera,
                        calibration_views=args.calibration_views, overwrite=True,
                        progress=False, board=tracking == "board", effects=effects)


def calibrate(acq: Path, sim: dict) -> dict:
    """Phone A (and camera B when its lens is distorted) through ``ltm calibrate``."""
    out = {}
    ok, text, err = ltm("calibrate", acq / "calibration.mkv", "--board", acq / "board.json",
                        "-o", acq / "intrinsics.json", "--overwrite")
    out["phone_a"] = _calibration(ok, acq / "intrinsics.json", err, sim["camera"]["focal_px"],
                                  sim["camera"]["dist_coeffs"][0])
    if (acq / "calibration_b.mkv").exists():
        ok, text, err = ltm("calibrate", acq / "calibration_b.mkv", "--board",
                            acq / "board_b.json", "-o", acq / "intrinsics_b.json", "--overwrite")
        truth = json.loads((acq / "truth" / "intrinsics_b.json").read_text())
        out["camera_b"] = _calibration(ok, acq / "intrinsics_b.json", err,
                                       truth["camera_matrix"][0][0], truth["dist_coeffs"][0])
        if not ok:  # ingest cannot undistort: go on without it, and say so
            meta = json.loads((acq / "acquisition.json").read_text())
            meta.pop("camera_calibration", None)
            (acq / "acquisition.json").write_text(json.dumps(meta, indent=2))
    return out


def _calibration(ok: bool, path: Path, err: str, focal: float, k1: float) -> dict:
    if not ok:
        return {"ok": False, "error": err}
    d = json.loads(path.read_text())
    return {"ok": True, "rms_px": d["reprojection_rms_px"],
            "focal_error_percent": 100 * (d["camera_matrix"][0][0] - focal) / focal,
            "k1": d["dist_coeffs"][0], "k1_true": k1}


def track(acq: Path, sim: dict, tracking: str, has_painting: bool,
          painting_map: str = "photograph") -> dict:
    video_a = Path(sim["paths"]["phone_a"])
    if tracking == "board":
        target = ["--board", acq / "board.json"]
    elif has_painting:
        target = ["--painting", Path(sim["paths"][painting_map]), "--painting-width",
                  sim["painting_width_m"]]
        if sim["effects"].get("rolling-shutter"):  # the readout time, as the phone's spec gives
            target += ["--readout-ms", 1000 * READOUT_S]
    else:
        return {"ok": False, "error": "not available (ltm track has no --painting)"}
    start = time.perf_counter()
    ok, text, err = ltm("track", video_a, *target, "--intrinsics", acq / "intrinsics.json",
                        "--led-offset", ",".join(map(str, sim["led_offset"])), "-o",
                        acq / "poses.csv", "--overwrite")
    if not ok:
        return {"ok": False, "error": err}
    summary = json.loads(text)
    errors = led_errors(acq / "poses.csv", acq / "truth" / "poses_true.csv", sim["time_offset"])
    return {"ok": True, "seconds": time.perf_counter() - start, **errors,
            "placed_fraction": summary["rows"] / summary["frames"],
            "frames": summary["frames"], "status": summary.get("status"),
            "shutter_ms": summary.get("shutter_ms")}


def sync(acq: Path, sim: dict) -> dict:
    # a capture reused from an earlier run (--reuse) already holds that run's offset
    ok, _, err = ltm("sync", acq, *(["--overwrite"] if sim.get("reused") else []))
    if not ok:
        return {"ok": False, "error": err}
    meta = json.loads((acq / "acquisition.json").read_text())
    return {"ok": True, "estimated_s": meta["time_offset"], "true_s": sim["time_offset"],
            "error_frames": sim["fps"] * (meta["time_offset"] - sim["time_offset"])}


def reconstruct_snr(acq: Path, truth: Path, lattice: tuple[int, int]) -> dict:
    store = acq.with_name(acq.name + ".zarr")  # beside the acquisition, never inside it
    start = time.perf_counter()
    ok, text, err = ltm("ingest", acq, store, "--overwrite")
    if ok:
        ingest = json.loads(text)
        ok, _, err = ltm("reconstruct", store, "--lattice", f"{lattice[0]}x{lattice[1]}",
                         "--overwrite")
    if not ok:
        return {"ok": False, "error": err}
    cmp = compare_stores(store, truth)
    return {"ok": True, "snr_y_db": cmp["snr_y_db"], "n_valid": ingest.get("n_valid"),
            "n_frames": ingest.get("n_frames"), "seconds": time.perf_counter() - start}


def true_pose_copy(acq: Path, sim: dict, name: str = "true_poses") -> Path:
    """The same capture with the true poses (and the same camera B calibration, where it was
    written), in the folder ``name`` beside it (video hard-linked)."""
    true_acq = acq.parent / name
    shutil.rmtree(true_acq, ignore_errors=True)
    true_acq.mkdir()
    video = Path(sim["paths"]["video"]).name
    link_or_copy(acq / video, true_acq / video)
    shutil.copy2(acq / "truth" / "poses_true.csv", true_acq / "poses.csv")
    meta = json.loads((acq / "acquisition.json").read_text())
    for key in ("time_offset", "time_offset_estimate", "phone_a", "camera_b"):
        meta.pop(key, None)
    if "camera_calibration" in meta:
        if (acq / meta["camera_calibration"]).exists():
            shutil.copy2(acq / meta["camera_calibration"], true_acq / meta["camera_calibration"])
        else:  # the calibration failed: the copy goes without it, as the capture did
            meta.pop("camera_calibration")
    (true_acq / "acquisition.json").write_text(json.dumps(meta, indent=2))
    return true_acq


def run_case(work: Path, scene: str, tracking: str, effects: str, args,
             has_painting: bool) -> dict:
    acq = work / f"{scene}_{tracking}_{effects.replace(',', '+')}" / "raw"
    start = time.perf_counter()
    sim = simulate(acq, scene, tracking, effects, args)
    row = {"scene": scene, "tracking": tracking, "effects": effects,
           "simulate_s": time.perf_counter() - start, "phone_a_frames": sim["frames"]}
    row["calibration"] = calibrate(acq, sim)
    row["track"] = track(acq, sim, tracking, has_painting, args.map)
    lattice = tuple(sim["lattice"])
    truth = acq / "truth.zarr"
    row["true_poses"] = reconstruct_snr(true_pose_copy(acq, sim), truth, lattice)
    if row["track"]["ok"]:
        row["sync"] = sync(acq, sim)
        if row["sync"]["ok"]:
            row["tracked"] = reconstruct_snr(acq, truth, lattice)
    if row.get("tracked", {}).get("ok") and row["true_poses"]["ok"]:
        row["snr_gap_db"] = row["true_poses"]["snr_y_db"] - row["tracked"]["snr_y_db"]
    if not args.keep:
        shutil.rmtree(acq.parent, ignore_errors=True)
    return row


def table_line(row: dict) -> str:
    t, s = row["track"], row.get("sync", {})
    cells = [row["scene"], row["tracking"], row["effects"],
             f"{t['rms_mm']:.2f}" if t.get("ok") else "-",
             f"{t['p95_mm']:.2f}" if t.get("ok") else "-",
             f"{100 * t['placed_fraction']:.0f} %" if t.get("ok") else t.get("error", "-"),
             f"{s['error_frames']:+.2f}" if s.get("ok") else "-",
             f"{row['tracked']['snr_y_db']:.2f}" if row.get("tracked", {}).get("ok") else "-",
             f"{row['true_poses']['snr_y_db']:.2f}" if row["true_poses"]["ok"] else "-"]
    return "| " + " | ".join(cells) + " |"


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    groups = sorted({(r["scene"], r["tracking"]) for r in rows})
    effects = list(dict.fromkeys(r["effects"] for r in rows))
    width = 0.8 / max(len(groups), 1)
    for g, (scene, tracking) in enumerate(groups):
        sel = {r["effects"]: r for r in rows if (r["scene"], r["tracking"]) == (scene, tracking)}
        x = np.arange(len(effects)) + g * width
        rms = [sel[e]["track"].get("rms_mm", np.nan) if e in sel else np.nan for e in effects]
        placed = [100 * sel[e]["track"].get("placed_fraction", np.nan) if e in sel else np.nan
                  for e in effects]
        gap = [sel[e].get("snr_gap_db", np.nan) if e in sel else np.nan for e in effects]
        for ax, values in zip(axes, (rms, placed, gap), strict=True):
            ax.bar(x, values, width, label=f"{scene}, {tracking}")
    for ax, title, target in zip(axes, ("LED error RMS (mm)", "frames placed (%)",
                                        "SNR_Y gap to true poses (dB)"), (1.0, 90.0, 1.0),
                                 strict=True):
        ax.axhline(target, color="k", ls="--", lw=0.8)
        ax.set_title(title)
        ax.set_xticks(np.arange(len(effects)) + 0.4 - width / 2, effects, rotation=45,
                      ha="right")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="one scene, small, effects none and all only")
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--work", help="work folder (default: a temp dir, removed)")
    parser.add_argument("--keep", action="store_true", help="keep each simulated capture")
    parser.add_argument("--scenes", nargs="+", default=None)
    parser.add_argument("--effects", nargs="+", default=None,
                        help="effect sets to run (default: none, each alone, all)")
    parser.add_argument("--trackings", nargs="+", default=["board", "painting"])
    parser.add_argument("--map", choices=["photograph", "video"], default="photograph",
                        help="boardless tracking's map: the user's front-on photograph "
                        "(painting.jpg) or camera B's video (default: %(default)s)")
    parser.add_argument("--size", type=int, default=None, help="video B side, pixels")
    parser.add_argument("--phone-size", type=int, nargs=2, default=None, metavar=("W", "H"))
    parser.add_argument("--lens", choices=list(LENSES), default="main",
                        help="phone A's lens: main (65 degrees across) or ultrawide (100 "
                        "degrees, a phone's 0.5x camera); default: %(default)s")
    parser.add_argument("--path-density", type=float, default=None)
    parser.add_argument("--lattice", type=int, nargs=2, default=None)
    parser.add_argument("--calibration-views", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    quick = args.quick
    args.scenes = args.scenes or (["canvas"] if quick else ["canvas", "relief"])
    args.effects = args.effects or (["none", "all"] if quick else ["none", *EFFECTS, "all"])
    args.size = args.size or 128
    args.phone_size = args.phone_size or ((640, 360) if quick else (1280, 720))
    args.path_density = args.path_density or (8.0 if quick else 15.0)
    args.lattice = args.lattice or ([16, 16] if quick else [24, 24])
    work = Path(args.work or tempfile.mkdtemp(prefix="ltm-phone-effects-"))
    has_painting = painting_option()
    rows = []
    start = time.perf_counter()
    for scene in args.scenes:
        for effects in args.effects:
            for tracking in args.trackings:
                row = run_case(work, scene, tracking, effects, args, has_painting)
                rows.append(row)
                print(table_line(row), flush=True)
    result = {
        "issue": 29, "version": __version__, "python": platform.python_version(),
        "machine": platform.machine(), "cpus": os.cpu_count(),
        "command": "python bench/phone_effects.py " + " ".join(sys.argv[1:]),
        "settings": {k: v for k, v in vars(args).items() if k not in ("out", "work")},
        "painting_tracking": "available" if has_painting else "not available",
        "targets": TARGETS, "rows": rows, "seconds": time.perf_counter() - start,
        "table_header": "| scene | tracking | effects | LED RMS mm | LED p95 mm | placed | "
                        "sync err frames | SNR_Y tracked dB | SNR_Y true poses dB |",
        "table": [table_line(r) for r in rows],
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "phone_effects.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, out / "phone_effects.png")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
