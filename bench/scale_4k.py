"""4K benchmark (issue 25, point 1): a phone's 3840 x 2160 video of a painting, whole.

Run: ``python bench/scale_4k.py --work /tmp/ltm-4k`` (about 30 GB of scratch disk; about two
hours on 2 cores, a third of it making the capture).

The capture is made as the issue allows. The canvas scene is rendered at ``--size`` (384)
pixels square at a slow hand (``--speed`` 0.095 m/s: the default path density over the 40 cm
plane then gives at least 1,300 frames at 30 fps). Each frame's linear luminance is scaled to
3840 x 2160 by nearest neighbour and given the simulator's sensor noise anew at that size (a
4K sensor's pixels are noisy one by one), then written grey (a monochrome painting: its
colour is illumination invariant, so the store keeps no per-frame chroma) as a phone writes it
(:func:`ltmstore.synthetic.writer.write_h264`, H.264 High at 50 Mbit/s, x264's ``veryfast``
preset; ``--bitrate`` sets another rate for both). The same at the rendered size makes the
reference capture. ``--target`` scales to another size: ``--target 1152x1152 --bitrate 8`` gives
each pixel the bits of 50 Mbit/s at 4K, and a high ``--bitrate`` nearly none of its loss.
``--colour`` writes the painting in colour instead (each linear RGB channel scaled and noisy as
above): its chroma changes with the light (a white highlight on coloured paint), so ingest keeps
each frame's chroma and ``ltm reconstruct`` adds the Cb and Cr LTMs; the result then also holds
SNR_RGB (linear RGB of the three LTMs against the rendered RGB truth, the same pixel subset).

The product's own commands then run on both, as a user runs them: ``ltm ingest
--exposure-locked`` (the simulator's camera is locked), ``ltm reconstruct`` (every default:
method, lattice, form) and ``ltm compact`` (drops the decoded frames). Each is timed as a whole
process, with the peak resident memory of its whole process tree (sampled every 0.2 s).
Written to ``scale_4k.json`` in ``--out`` (``bench/results/scale_4k``): each command's wall
time, peak memory and stage record, the store's bytes per variable before and after ``ltm
compact``, one point light's relighting time
(median of 5, each on a freshly opened store; and warm, median of 10 on a store opened once,
after a first light) and SNR_Y against the simulation's truth on the pixels ``[4::8, 4::8]``
(the truth of a 4K pixel is that of the rendered pixel it was scaled from), beside the
reference capture's.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import psutil

from ltmstore.capture.video import VideoReader
from ltmstore.core import store as st
from ltmstore.core.dims import CHROMA_LTM, LTM, LUMA, rgb_from_ycbcr
from ltmstore.core.store import open_store
from ltmstore.core.transfer import encode, linearise, transfer_lut
from ltmstore.judge.benchmark import random_lights, relight_cost, warm_relight_cost
from ltmstore.judge.evaluate import snr_db
from ltmstore.stages.compact import store_bytes
from ltmstore.synthetic.render import iter_frames
from ltmstore.synthetic.simulate import (
    PLANE,
    READ_NOISE,
    SHOT_NOISE,
    plan_simulation,
    simulate_acquisition,
)
from ltmstore.synthetic.writer import write_h264

sys.path.insert(0, str(Path(__file__).parent))
from scale_bench import SNR_STEP, PeakMemory  # noqa: E402

BITRATE = 50.0  # Mbit/s: a phone's 4K H.264


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--work", default="/tmp/ltm-4k", help="scratch folder (about 30 GB)")
    parser.add_argument("--out", default="bench/results/scale_4k")
    parser.add_argument("--size", type=int, default=384, help="rendered side (pixels)")
    parser.add_argument("--speed", type=float, default=0.095, help="hand speed (m/s)")
    parser.add_argument("--target", default="2160x3840", help="the video's ROWSxCOLUMNS")
    parser.add_argument("--bitrate", type=float, default=BITRATE,
                        help="H.264 bit rate of both captures (Mbit/s)")
    parser.add_argument("--reuse", action="store_true",
                        help="keep the captures in --work and reuse them when made alike (the "
                             "render alone when only --target or --bitrate differs)")
    parser.add_argument("--form", choices=("auto", "dense", "factored"), default="auto",
                        help="ltm reconstruct --form (default: its own default)")
    parser.add_argument("--colour", action="store_true",
                        help="a colour painting (default: grey); writes scale_4k_colour.json")
    parser.add_argument("--only", choices=("reference", "4k"),
                        help="run one capture's commands only")
    args = parser.parse_args()
    work = Path(args.work)
    plan_args = dict(scene="canvas", seed=0, size=args.size, speed=args.speed, plane=PLANE)
    target = tuple(int(n) for n in args.target.split("x"))
    made = _captures(work, plan_args, target, args.bitrate, reuse=args.reuse,
                     colour=args.colour)
    result = {"command": "python bench/" + " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
              "machine": _machine(),
              "render_size": args.size, "speed_m_s": args.speed, "bitrate_mbit_s": args.bitrate,
              "colour": args.colour,
              "captures": made,
              "runs": {}}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    json_name = "scale_4k_colour.json" if args.colour else "scale_4k.json"
    for name in ("reference", "4k"):
        if args.only in (None, name):
            run = result["runs"][name] = {}
            _run(work / name, plan_args, made["exposure"], run, args.form,
                 save=lambda: (out / json_name).write_text(json.dumps(result, indent=2)
                                                           + "\n"))
    print(json.dumps(result, indent=2))


def _machine() -> dict:
    return {"platform": platform.platform(), "cpus": os.cpu_count(),
            "memory_gib": psutil.virtual_memory().total / 2**30,
            "load_average_1min_start": os.getloadavg()[0]}


def _captures(work: Path, plan_args: dict, target: tuple[int, int], bitrate: float, *,
              reuse: bool, colour: bool) -> dict:
    """The rendered capture, and from it the reference and 4K captures, grey or in
    ``colour`` (kept in ``work`` with ``reuse``)."""
    facts = work / "captures.json"
    made = json.loads(facts.read_text()) if reuse and facts.exists() else {}
    if [made.get(k) for k in ("render_size", "target", "bitrate_mbit_s", "colour")] == [
            plan_args["size"], list(target), bitrate, colour]:
        return made
    if made.get("render_size") == plan_args["size"]:  # the same render, written anew
        sim, rendered = made, made["render_s"]
        for name in ("reference", "4k"):
            shutil.rmtree(work / name, ignore_errors=True)
    else:
        shutil.rmtree(work, ignore_errors=True)
        start = time.perf_counter()
        sim = simulate_acquisition(work / "rendered", truth=False, progress=True, **plan_args)
        rendered = time.perf_counter() - start
    start = time.perf_counter()
    rows, cols = (np.arange(n) * plan_args["size"] // n for n in target)
    scaled = {"reference": lambda y: y, "4k": lambda y: y[rows][:, cols]}
    for seed, (name, scale) in enumerate(scaled.items()):
        acq = _folder(work / "rendered", work / name / "acq")
        noise = np.random.default_rng(seed)
        frames = (_noisy(scale(y), noise) for y in _linear(work / "rendered" / "video.mkv",
                                                           colour=colour))
        write_h264(acq / "video.mp4", frames, bitrate=int(bitrate * 1e6), preset="veryfast")
    made = {"frames": sim["frames"], "exposure": sim["exposure"],
            "render_size": plan_args["size"], "target": list(target), "bitrate_mbit_s": bitrate,
            "colour": colour,
            "render_s": round(rendered, 1), "encode_s": round(time.perf_counter() - start, 1),
            "video_bytes": {n: (work / n / "acq" / "video.mp4").stat().st_size for n in scaled}}
    facts.write_text(json.dumps(made, indent=2))
    return made


def _linear(video: Path, *, colour: bool) -> Iterator[np.ndarray]:
    """Each of the video's frames in linear light: RGB in ``colour``, else its luminance."""
    lut = transfer_lut("srgb", bits=8)
    with VideoReader(video) as reader:
        for _, rgb in reader.frames():
            linear = linearise(rgb, lut)
            yield linear if colour else linear @ LUMA.astype(np.float32)


def _noisy(linear: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """An sRGB frame of linear light (luminance: grey; or RGB) with the simulator's sensor
    noise drawn anew at this frame's own resolution (a 4K sensor's pixels are noisy one by
    one)."""
    sigma = np.sqrt(READ_NOISE**2 + SHOT_NOISE * np.clip(linear, 0, None))
    code = encode(linear + sigma * rng.standard_normal(linear.shape, dtype=np.float32), "srgb")
    return code if code.ndim == 3 else np.repeat(code[..., None], 3, axis=-1)


def _folder(rendered: Path, acq: Path) -> Path:
    """``acq`` with the rendered capture's poses and acquisition.json, naming ``video.mp4``."""
    acq.mkdir(parents=True)
    shutil.copy(rendered / "poses.csv", acq / "poses.csv")
    meta = json.loads((rendered / "acquisition.json").read_text())
    meta["video"] = "video.mp4"
    (acq / "acquisition.json").write_text(json.dumps(meta, indent=2) + "\n")
    return acq


def _command(args: list[str]) -> dict:
    """Run one ``ltm`` command as a user would; its wall time and peak memory (process tree)."""
    with PeakMemory() as memory:
        start = time.perf_counter()
        proc = subprocess.run([str(Path(sys.executable).with_name("ltm")), *args],
                              capture_output=True, text=True)
        wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"ltm {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return {"command": "ltm " + " ".join(args), "wall_s": round(wall, 1),
            "peak_memory_gib": round(memory.peak / 2**30, 3)}


def _variable_bytes(store: Path) -> dict[str, int]:
    return {v.name: store_bytes(v) for v in sorted(store.iterdir()) if v.is_dir()}


def _run(folder: Path, plan_args: dict, exposure: float, run: dict, form: str,
         save) -> None:
    """The three commands on ``folder``'s capture, then the measures of their store, into
    ``run`` (``save()`` after each step, so that a failure keeps what was measured)."""
    store = folder / "store.zarr"
    shutil.rmtree(store, ignore_errors=True)
    for step, args in (("ingest", ["ingest", str(folder / "acq"), str(store),
                                   "--exposure-locked"]),
                       ("reconstruct", ["reconstruct", str(store), "--form", form]),
                       ("compact", ["compact", str(store)])):
        if step == "compact":
            run["before_compact"] = {"store_bytes": store_bytes(store),
                                     "variable_bytes": _variable_bytes(store)}
        run[step] = _command(args)
        save()
    run["both_wall_s"] = round(run["ingest"]["wall_s"] + run["reconstruct"]["wall_s"], 1)
    record = st.stages(st.open_group(store, mode="r"))
    run.update({"stage_records": {k: record.get(k) for k in ("ingest", "resample",
                                                            "reconstruct", "compact")},
                "store_bytes": store_bytes(store), "variable_bytes": _variable_bytes(store),
                **score(store, plan_args, exposure)})
    save()
    run["relight_point_light"] = relight_cost(store, random_lights(PLANE.to_json(), 5))
    run["relight_point_light_warm"] = warm_relight_cost(store,
                                                        random_lights(PLANE.to_json(), 11))
    run["load_average_1min_end"] = os.getloadavg()[0]
    save()


def score(store: Path, plan_args: dict, exposure: float) -> dict:
    """SNR_Y of the store's LTM against the simulation's truth on the pixels ``[4::8, 4::8]``
    (and SNR_RGB of a colour LTM), with the image and lattice shapes."""
    ds = open_store(store)
    ltm = ds[LTM]
    lights = [(r, s, PLANE.height) for r in ltm["r"].values for s in ltm["s"].values]
    sub = slice(SNR_STEP // 2, None, SNR_STEP)
    rows, cols = (np.arange(n)[sub] * plan_args["size"] // n for n in ltm.shape[:2])

    def subset(name: str) -> np.ndarray:  # the LTM ``name`` at the scored pixels
        return np.concatenate([ds[name].isel(y=band, x=np.arange(ltm.shape[1])[sub]).values
                               for band in np.array_split(np.arange(ltm.shape[0])[sub], 9)])

    estimate = subset(LTM)
    plan = plan_simulation(**plan_args)
    truth_rgb = np.stack([frame[rows][:, cols] for frame in iter_frames(plan.scene, lights)],
                         axis=-2) * exposure  # (y, x, cell, colour)
    truth = (truth_rgb @ LUMA.astype(np.float32)).reshape(estimate.shape)
    out = {"image": list(ltm.shape[:2]), "lattice": list(ltm.shape[2:]),
           "snr_y_db_pixel_subset": snr_db(truth, estimate)}
    if CHROMA_LTM["cb"] in ds:  # a colour LTM: its linear RGB against the rendered RGB
        rgb = np.stack(rgb_from_ycbcr(estimate, subset(CHROMA_LTM["cb"]),
                                      subset(CHROMA_LTM["cr"])), axis=-1)
        out["snr_rgb_db_pixel_subset"] = snr_db(truth_rgb.reshape(rgb.shape), rgb)
    return out


if __name__ == "__main__":
    main()
