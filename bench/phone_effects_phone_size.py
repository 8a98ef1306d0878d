"""Issue-63 benchmark, item 1: the phone effects measured at a phone's size, each split into
what the capture destroys and what the product fails to undo.

Camera B films the painting at ``--size`` pixels (720: a phone's 720p short side; the issue-29
bench used 128). For each scene and each capture (effects ``none``, ``distortion``,
``led-falloff``, ``h264`` and ``all-locked``: every effect but camera B's auto exposure and white
balance, which the guide says to lock), the raw capture is simulated (``simulate_raw``, as
``ltm simulate --raw``) and measured two ways, both with the **true** light positions
(``truth/poses_true.csv``) so that tracking is not the cause:

``product``
    what a user gets: ``ltm calibrate calibration_b.mkv`` where camera B is distorted, then
    ``ltm ingest`` and ``ltm reconstruct``; SNR_Y against the capture's own ``truth.zarr``.
``oracle``
    the same capture post-processed with what the simulator knows exactly, then the same
    ``ltm ingest`` and ``ltm reconstruct``:

    - distortion: camera B's **true** intrinsics (``truth/intrinsics_b.json``) instead of
      ``ltm calibrate``'s; against the capture's own truth;
    - led-falloff: every frame of video B decoded, the room light's true image (ambient only)
      subtracted, the **true** beam of that frame (``cos^2`` about phone A's actual axis,
      remapped through the true distortion where it is on) divided out and the exposure put back
      to the ideal capture's, re-encoded losslessly (FFV1); against the **ideal** capture's truth
      (the LED as an isotropic point, as in ``none``);
    - h264: the uncompressed frames are the ``none`` capture's exactly (same sensor-noise seed):
      its oracle is the ``none`` row, and the codec's own frame PSNR is recorded;
    - all-locked: the true intrinsics, the true ambient subtracted and the true beam divided out
      as above, the H.264 frames kept (nothing can restore what the codec discarded).

``tracked`` (``--tracked``): the product with phone A's poses from ``ltm track --painting`` and
``ltm sync`` (as ``bench/phone_effects.py``).

Each (scene, capture) can run as its own process (``--scenes canvas --captures none``) writing a
part file into ``--work``; ``--merge`` gathers the parts into
``bench/results/phone_effects_phone_size.json`` and ``.png``. Every step is the product's own
command (``ltm calibrate``, ``ltm ingest``, ``ltm reconstruct``); SNR_Y is
:func:`ltmstore.judge.evaluate.compare_stores`, as ``ltm evaluate --truth``.

Run (one row at a time, 2 cores)::

    OMP_NUM_THREADS=1 nice -n 15 python bench/phone_effects_phone_size.py --scenes canvas \\
        --captures none --work /tmp/pe720
    python bench/phone_effects_phone_size.py --merge --work /tmp/pe720
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
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from phone_effects import LENSES, calibrate, ltm, sync, track, true_pose_copy  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.judge.evaluate import compare_stores  # noqa: E402

LOCKED = "distortion,rolling-shutter,motion-blur,ambient,led-falloff,h264"
CAPTURES = {"none": "none", "distortion": "distortion", "led-falloff": "led-falloff",
            "h264": "h264", "all-locked": LOCKED}
ORACLE = {"distortion": "true intrinsics", "led-falloff": "true beam divided out",
          "h264": "uncompressed frames (= none)",
          "all-locked": "true intrinsics, true ambient subtracted, true beam divided out; "
                        "H.264 frames kept"}


def git_diff_stat() -> str:
    """``git diff --stat`` of the checkout (others' work in progress while the bench ran)."""
    proc = subprocess.run(["git", "diff", "--stat"], capture_output=True, text=True,
                          cwd=Path(__file__).parent.parent)
    return proc.stdout.strip()


def cache_truth_renders(cache: Path) -> None:
    """Keep the simulator's truth LTM render on disk: it is the same for every capture of a
    scene with the same LED shading (``none``, ``distortion``, ``h264``; ``led-falloff``,
    ``all-locked``), and at 720 px it is minutes. The simulator only, never the product."""
    import ltmstore.synthetic.raw as raw

    render = raw.render_ltm

    def cached(scene, lattice, height, *, progress=True, shading=None):
        import hashlib

        tag = hashlib.sha1(repr(shading).encode()).hexdigest()[:10]
        key = (f"{scene.name}_{scene.shape[0]}x{scene.shape[1]}_{'x'.join(map(str, lattice.shape))}"
               f"_{height:.4f}_{tag}.npy")
        path = cache / key
        if path.exists():
            return np.load(path)
        ltm = render(scene, lattice, height, progress=progress, shading=shading)
        cache.mkdir(parents=True, exist_ok=True)
        np.save(path.with_suffix(".tmp.npy"), ltm)
        os.replace(path.with_suffix(".tmp.npy"), path)
        return ltm

    raw.render_ltm = cached


def reuse(acq: Path, capture: str) -> dict | None:
    """An earlier simulation of the same capture in ``acq`` (``--reuse``), as simulate_raw's
    return value."""
    path = acq / "truth" / "raw.json"
    if not path.exists():
        return None
    from ltmstore.synthetic.phone_effects import parse_effects

    info = json.loads(path.read_text())
    if info["effects"] != parse_effects(CAPTURES[capture]).to_json():
        return None
    ext = ".mp4" if info["effects"]["h264"] else ".mkv"
    paths = {"video": acq / f"video{ext}", "phone_a": acq / f"phone_a{ext}",
             "photograph": acq / "painting.jpg"}
    return {**info, "paths": {k: str(v) for k, v in paths.items()}, "simulate_s": None,
            "reused": True}


def scene_and_shading(label: str) -> tuple[str, str]:
    """``canvas`` -> ``("canvas", "ggx")``; ``canvas-mismatched`` -> ``("canvas",
    "mismatched")``: a scene label of ``--scenes`` and the physics it is rendered with."""
    scene, _, shading = label.partition("-")
    return scene, shading or "ggx"


def simulate(acq: Path, label: str, capture: str, args) -> dict:
    """The raw capture (camera B ``args.size`` px) and the seconds it took."""
    from ltmstore.synthetic.raw import PhoneCamera, simulate_raw

    if args.reuse and (sim := reuse(acq, capture)) is not None:
        return sim
    cache_truth_renders(Path(args.work) / "render_cache")
    start = time.perf_counter()
    w, h = args.phone_size
    camera = PhoneCamera(size=(w, h), focal_px=LENSES[args.lens] * w / 1280)
    scene, shading = scene_and_shading(label)
    sim = simulate_raw(acq, scene=scene, path_density=args.path_density, seed=args.seed,
                       size=args.size, lattice=tuple(args.lattice), camera=camera,
                       calibration_views=args.calibration_views, overwrite=True,
                       progress=False, board=False, effects=CAPTURES[capture], shading=shading)
    sim["simulate_s"] = time.perf_counter() - start
    return sim


def use_true_intrinsics(folder: Path, acq: Path) -> None:
    """Point the folder's ``camera_calibration`` at camera B's true intrinsics."""
    meta = json.loads((folder / "acquisition.json").read_text())
    shutil.copy2(acq / "truth" / "intrinsics_b.json", folder / "intrinsics_b_true.json")
    meta["camera_calibration"] = "intrinsics_b_true.json"
    (folder / "acquisition.json").write_text(json.dumps(meta, indent=2))


def read_frames(path: Path):
    """Decode a video's frames as RGB uint8 (PyAV)."""
    import av

    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            yield frame.to_ndarray(format="rgb24")


def beam_oracle(folder: Path, acq: Path, scene: str, ideal_exposure: float, args,
                level: bool = False) -> dict:
    """Rewrite the folder's video B with the true ambient subtracted and the true LED beam
    divided out (exposure put back to the ideal capture's), FFV1; ``level``: only the beam's
    wobble divided out (the true beam over the beam of the LED held level, what the truth
    shows), the exposure kept."""
    import cv2

    from ltmstore.core.transfer import decode, encode
    from ltmstore.synthetic import writer
    from ltmstore.synthetic.camera_b import ambient_term
    from ltmstore.synthetic.phone_effects import (
        DISTORTION_B,
        LED_EXPONENT,
        camera_b_matrix,
        distortion_maps,
        led_profile,
    )
    from ltmstore.synthetic.raw import PhoneCamera, RawSetup, parse_effects
    from ltmstore.synthetic.render import _Renderer
    from ltmstore.synthetic.simulate import PLANE, plan_simulation

    info = json.loads((acq / "truth" / "raw.json").read_text())
    fx = parse_effects(CAPTURES[args.capture_now])
    plan = plan_simulation(scene=scene, path_density=args.path_density, seed=args.seed,
                           size=args.size, lattice=tuple(args.lattice), plane=PLANE)
    w, h = args.phone_size
    setup = RawSetup(plan, PhoneCamera(size=(w, h), focal_px=LENSES[args.lens] * w / 1280), fx,
                     False, info["time_offset"], args.calibration_views, False)
    _, line = setup.timeline()
    hh, ww = plan.scene.shape
    maps = (distortion_maps(camera_b_matrix((ww, hh)), DISTORTION_B, (ww, hh))
            if "distortion" in fx else None)

    def warp(img: np.ndarray) -> np.ndarray:
        return img if maps is None else cv2.remap(img, *maps, cv2.INTER_LINEAR,
                                                  borderMode=cv2.BORDER_REPLICATE)

    ambient = (warp(ambient_term(plan, info["exposure"]).astype(np.float32))
               if "ambient" in fx else 0.0)
    points = np.asarray(_Renderer(plan.scene).pos)
    scale = 1.0 if level else ideal_exposure / info["exposure"]
    down = np.array([0.0, 0.0, -1.0])
    meta = json.loads((folder / "acquisition.json").read_text())
    src = folder / meta["video"]

    def frames():
        for k, code in enumerate(read_frames(src)):
            lin = decode(code, "srgb") - ambient
            if line.led_on[k] and "led-falloff" in fx:
                beam = led_profile(line.axes[k], line.lights[k], points, LED_EXPONENT)
                if level:
                    beam = beam / np.maximum(led_profile(down, line.lights[k], points,
                                                         LED_EXPONENT), 1e-3)
                lin = lin / np.maximum(warp(beam.astype(np.float32)), 1e-3)[..., None]
            yield encode(np.clip(lin * scale, 0, 1), "srgb")

    tmp = folder / "video_oracle.mkv"
    n = writer.write_video(tmp, frames(), fps=info["fps"])
    src.unlink()
    meta["video"] = tmp.name
    (folder / "acquisition.json").write_text(json.dumps(meta, indent=2))
    return {"frames_rewritten": n, "exposure_scale": scale}


def codec_psnr(h264_video: Path, ideal_video: Path) -> float:
    """PSNR (dB, 8-bit code values) of the H.264 frames against the same frames uncompressed."""
    se, n = 0.0, 0
    for a, b in zip(read_frames(h264_video), read_frames(ideal_video), strict=False):
        se += float(np.sum((a.astype(np.float64) - b) ** 2))
        n += a.size
    return 10 * np.log10(255**2 / (se / n))


def measure(folder: Path, truth: Path, lattice: tuple[int, int],
            args_color: str | None) -> dict:
    """``ltm ingest`` (again with ``--exposure-locked`` when refused as drifting) and ``ltm
    reconstruct`` (``--color args_color`` when given), then SNR_Y against ``truth``; the store
    is removed afterwards."""
    store = folder.with_name(folder.name + ".zarr")
    out: dict = {}
    start = time.perf_counter()
    ok, text, err = ltm("ingest", folder, store, "--overwrite")
    if not ok and "drift" in err:
        out["ingest_refused"] = err
        ok, text, err = ltm("ingest", folder, store, "--overwrite", "--exposure-locked")
        out["exposure_locked"] = True
    out["ingest_s"] = time.perf_counter() - start
    if not ok:
        return {**out, "ok": False, "error": err}
    ingest = json.loads(text)
    start = time.perf_counter()
    ok, text, err = ltm("reconstruct", store, "--lattice", f"{lattice[0]}x{lattice[1]}",
                        "--overwrite", *(["--color", args_color] if args_color else []))
    out["reconstruct_s"] = time.perf_counter() - start
    if not ok:
        return {**out, "ok": False, "error": err}
    cmp = compare_stores(store, truth)
    attrs = _ltm_attrs(store)
    shutil.rmtree(store, ignore_errors=True)
    return {**out, "ok": True, "snr_y_db": cmp["snr_y_db"], "psnr_db_median":
            cmp["psnr_db_median"], "n_frames": ingest.get("n_frames"),
            "n_valid": ingest.get("n_valid"), "truth": str(truth), **attrs}


def _ltm_attrs(store: Path) -> dict:
    """The reconstruct's method summary, where the store records it, and what it chose: the
    LED's exponent, the tiles' methods and parameters, how often the path came back."""
    try:
        import xarray as xr
        import zarr

        from ltmstore.core.store import stages

        ds = xr.open_zarr(store, consolidated=False)
        keep = {k: ds.attrs[k] for k in ("method", "methods") if k in ds.attrs}
        record = stages(zarr.open_group(store, mode="r")).get("reconstruct", {})
        chosen = {k: record[k] for k in ("led_beam", "chosen_per_tile", "revisited")
                  if k in record}
        return {"store_attrs": json.loads(json.dumps(keep, default=str)),
                "reconstruct": json.loads(json.dumps(chosen, default=str))}
    except Exception as exc:  # noqa: BLE001 - a summary only
        return {"store_attrs_error": str(exc)}


def run_capture(work: Path, scene: str, capture: str, args) -> dict:
    """Simulate one capture and measure its product and oracle rows (and tracked)."""
    acq = work / f"{scene}_{capture}" / "raw"
    row = {"scene": scene, "capture": capture, "effects": CAPTURES[capture],
           "size": args.size, "git_diff_stat": git_diff_stat(), "started": time.time()}
    sim = simulate(acq, scene, capture, args)
    row.update(simulate_s=sim["simulate_s"], frames_b=sim["frames"],
               exposure=sim["exposure"], lattice=sim["lattice"])
    lattice = tuple(sim["lattice"])
    truth = acq / "truth.zarr"
    ideal = work / f"{scene}_none" / "raw"
    if (acq / "calibration_b.mkv").exists() or args.tracked:  # tracking needs phone A's
        row["calibration"] = calibrate(acq, sim)
    row["product"] = measure(true_pose_copy(acq, sim, "product"), truth, lattice, args.color)
    _save(work, row)
    args.capture_now = capture
    if capture in ("distortion", "all-locked", "led-falloff"):
        folder = true_pose_copy(acq, sim, "oracle")
        if "distortion" in CAPTURES[capture]:
            use_true_intrinsics(folder, acq)
        oracle_truth = truth
        if capture != "distortion":
            ideal_info = json.loads((ideal / "truth" / "raw.json").read_text())
            row["oracle_rewrite"] = beam_oracle(folder, acq, scene_and_shading(scene)[0],
                                                ideal_info["exposure"], args)
            oracle_truth = ideal / "truth.zarr"
        row["oracle"] = {"what": ORACLE[capture],
                         **measure(folder, oracle_truth, lattice, args.color)}
    elif capture == "h264":
        row["codec_psnr_db"] = codec_psnr(acq / "video.mp4", ideal / "video.mkv")
        row["oracle"] = {"what": ORACLE[capture], "same_as": "none"}
    _save(work, row)
    if args.tracked:
        row["track"] = track(acq, sim, "painting", True, "photograph")
        if row["track"]["ok"]:
            row["sync"] = sync(acq, sim)
            if row["sync"]["ok"]:
                row["tracked"] = measure(acq, truth, lattice, args.color)
    row["seconds"] = time.time() - row["started"]
    _save(work, row)
    return row


def _save(work: Path, row: dict) -> None:
    part = work / "parts" / f"{row['scene']}_{row['capture']}.json"
    part.parent.mkdir(parents=True, exist_ok=True)
    part.write_text(json.dumps(row, indent=2, default=str) + "\n")


def table(rows: list[dict]) -> list[str]:
    """Markdown rows: SNR_Y of product and oracle, and the loss split against ``none``."""
    lines = ["| scene | capture | product at 128 px dB | SNR_Y product dB | SNR_Y oracle dB | "
             "loss dB | destroyed by the capture dB | left by the product dB | oracle, the "
             "beam's wobble only, own truth dB | tracked dB |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    ideal = {r["scene"]: _snr(r, "product") for r in rows if r["capture"] == "none"}
    for r in rows:
        p, o, base = _snr(r, "product"), _snr(r, "oracle"), ideal.get(r["scene"])
        if r["capture"] == "none":
            o = p
        destroyed, left = _f(_sub(base, o)), _f(_sub(o, p))
        if r["capture"] == "h264":  # no oracle can know the frames the codec discarded
            o, destroyed = base, f"codec: frames {r.get('codec_psnr_db', float('nan')):.1f} dB"
            left = "<= " + _f(_sub(base, p))
        cells = [r["scene"], r["capture"], REFERENCE_128.get((r["scene"], r["capture"]), "-"),
                 _f(p), _f(o), _f(_sub(base, p)), destroyed, left,
                 _f(_snr(r, "oracle_level")), _f(_snr(r, "tracked"))]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _snr(row: dict, key: str) -> float | None:
    return row.get(key, {}).get("snr_y_db") if row.get(key, {}).get("ok") else None


def _sub(a, b):
    return None if a is None or b is None else a - b


def _f(v) -> str:
    return "-" if v is None else f"{v:.2f}"


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 4.5), squeeze=False)
    for ax, scene in zip(axes[0], scenes, strict=True):
        sel = [r for r in rows if r["scene"] == scene]
        x = np.arange(len(sel))
        for k, (key, label) in enumerate((("product", "product"),
                                          ("oracle", "oracle (effect known exactly)"),
                                          ("oracle_level", "oracle, beam's wobble only"),
                                          ("tracked", "product, tracked poses"))):
            vals = [_snr(r, key) if not (key == "oracle" and r["capture"] in ("none", "h264"))
                    else (_snr(r, "product") if r["capture"] == "none" else
                          next((_snr(q, "product") for q in sel if q["capture"] == "none"), None))
                    for r in sel]
            ax.bar(x + 0.2 * (k - 1.5), [np.nan if v is None else v for v in vals], 0.2,
                   label=label)
        ax.set_xticks(x, [r["capture"] for r in sel], rotation=30, ha="right")
        ax.set_ylabel("SNR_Y (dB), true poses")
        ax.set_title(f"{scene}: camera B {sel[0]['size']} px")
        ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


ORDER = list(CAPTURES)
# the same rows at camera B 128 px, true poses (docs/two-phones.md, "Where it stands":
# bench/results/phone_effects_ultrawide_sync6.json and phone_effects_ultrawide_each.json)
REFERENCE_128 = {("canvas", "none"): "22.58", ("canvas", "distortion"): "17.01",
                 ("canvas", "led-falloff"): "17.60", ("canvas", "h264"): "19.79",
                 ("canvas", "all-locked"): "15.00", ("relief", "none"): "25.82",
                 ("relief", "all-locked"): "14.11"}


def distortion_round_trip(work: Path, scene: str, every: int = 15, margin: int = 24) -> dict:
    """Camera B's distortion at frame level: an ideal frame of the ``none`` capture distorted as
    the simulator does (bilinear; cubic for comparison) and undistorted as ``ltm ingest`` does
    (cubic) with the true and with ``ltm calibrate``'s intrinsics; SNR (dB, linear light) against
    the ideal frame, ``margin`` pixels in from the border, every ``every``-th frame."""
    import cv2

    from ltmstore.capture.undistort import Undistorter
    from ltmstore.core.transfer import decode
    from ltmstore.synthetic.phone_effects import DISTORTION_B, camera_b_matrix, distortion_maps

    acq = work / f"{scene}_distortion" / "raw"
    ideal = work / f"{scene}_none" / "raw" / "video.mkv"
    undo = {"true": Undistorter.from_file(acq / "truth" / "intrinsics_b.json"),
            "calibrated": Undistorter.from_file(acq / "intrinsics_b.json")}
    out, maps = {}, None
    for name, flag in (("bilinear", cv2.INTER_LINEAR), ("cubic", cv2.INTER_CUBIC)):
        sums = {k: [0.0, 0.0] for k in undo}
        for i, code in enumerate(read_frames(ideal)):
            if i % every:
                continue
            lin = decode(code, "srgb").astype(np.float32)
            if maps is None:
                h, w = lin.shape[:2]
                maps = distortion_maps(camera_b_matrix((w, h)), DISTORTION_B, (w, h))
            dist = cv2.remap(lin, *maps, flag, borderMode=cv2.BORDER_REPLICATE)
            m = np.s_[margin:-margin, margin:-margin]
            for k, u in undo.items():
                sums[k][0] += float(np.sum(lin[m] ** 2))
                sums[k][1] += float(np.sum((u.apply(dist) - lin)[m] ** 2))
        out[f"simulator_{name}"] = {f"undistorted_{k}_snr_db": 10 * np.log10(a / e)
                                    for k, (a, e) in sums.items()}
    return out


def merge(args) -> None:
    work = Path(args.work)
    rows = [json.loads(p.read_text()) for p in sorted((work / "parts").glob("*.json"))]
    for row in rows:  # the true poses' columns: with the LED axis, ingest divides the beam out
        poses = work / f"{row['scene']}_{row['capture']}" / "raw" / "truth" / "poses_true.csv"
        if poses.exists():
            row["true_poses_header"] = poses.read_text().splitlines()[0]
        calibrated = poses.parent.parent / "intrinsics_b.json"
        if calibrated.exists():  # what ltm calibrate made of camera B, beside the truth
            row["camera_b_intrinsics"] = {
                name: {k: json.loads(path.read_text())[k] for k in ("camera_matrix",
                                                                    "dist_coeffs")}
                for name, path in (("calibrated", calibrated),
                                   ("true", poses.parent / "intrinsics_b.json"))}
        level = work / "parts" / f"{row['scene']}_{row['capture']}.level.txt"
        if level.exists():  # the beam's wobble only divided out, against the capture's truth
            row["oracle_level"] = json.loads(level.read_text())
        rerun = work / "parts" / f"{row['scene']}_{row['capture']}.rerun.txt"
        if rerun.exists():  # a step measured again after a failure outside the bench
            again = json.loads(rerun.read_text())
            row["product_first_attempt"] = row["product"]
            row["product"] = {**again["product"], "git_diff_stat": again["git_diff_stat"]}
    rows.sort(key=lambda r: (r["scene"] != "canvas", r["scene"], ORDER.index(r["capture"])))
    result = {"issue": 63, "item": 1, "version": __version__,
              "python": platform.python_version(), "cpus": os.cpu_count(),
              "command": "python bench/phone_effects_phone_size.py " + " ".join(sys.argv[1:]),
              "settings": {k: v for k, v in vars(args).items()
                           if k not in ("out", "work", "name")},
              "oracles": ORACLE, "rows": rows, "table": table(rows)}
    if args.frame_check:
        result["distortion_round_trip"] = {
            scene: distortion_round_trip(work, scene) for scene in args.scenes
            if (work / f"{scene}_distortion" / "raw" / "intrinsics_b.json").exists()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.name}.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, out / f"{args.name}.png")
    print("\n".join(result["table"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", required=True, help="work folder (kept: captures, parts)")
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--merge", action="store_true", help="gather the parts, write JSON+PNG")
    parser.add_argument("--name", default="phone_effects_phone_size",
                        help="the merged results' file name, without .json / .png")
    parser.add_argument("--scenes", nargs="+", default=["canvas"],
                        help="scenes; SCENE-mismatched renders it with physics the product does "
                        "not assume (ltmstore.synthetic.render.MISMATCHED)")
    parser.add_argument("--captures", nargs="+", default=ORDER, choices=ORDER)
    parser.add_argument("--size", type=int, default=720, help="camera B side, pixels")
    parser.add_argument("--phone-size", type=int, nargs=2, default=[1280, 720])
    parser.add_argument("--lens", choices=list(LENSES), default="ultrawide")
    parser.add_argument("--path-density", type=float, default=8.0)
    parser.add_argument("--lattice", type=int, nargs=2, default=[16, 16])
    parser.add_argument("--calibration-views", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tracked", action="store_true", help="also ltm track + sync")
    parser.add_argument("--color", choices=["auto", "on", "off"], default="off",
                        help="ltm reconstruct --color (default off: SNR_Y reads only the "
                        "luminance LTM, and a colour LTM triples a 720 px reconstruct)")
    parser.add_argument("--frame-check", action="store_true",
                        help="with --merge: camera B's distortion round trip at frame level")
    parser.add_argument("--reuse", action="store_true",
                        help="reuse a capture already simulated in --work")
    args = parser.parse_args()
    if args.merge:
        merge(args)
        return
    for scene in args.scenes:
        for capture in args.captures:
            row = run_capture(Path(args.work), scene, capture, args)
            print(json.dumps({k: row.get(k) for k in ("scene", "capture", "product", "oracle",
                                                      "tracked")}, default=str), flush=True)


if __name__ == "__main__":
    main()
