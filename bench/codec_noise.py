"""Why camera B's codec costs the LTM what it does: its errors rearranged between frames.

The H.264 capture of ``bench/phone_effects_phone_size.py`` carries the uncompressed capture's
frames exactly, plus the codec's error ``e_k = h264_k - none_k`` (8-bit sRGB code values). The
same error is put back on the uncompressed frames in other arrangements, each video written
losslessly (FFV1) and run through ``ltm ingest`` and ``ltm reconstruct`` as a user runs them,
SNR_Y against the truth:

``codec``
    ``none_k + e_k``: the H.264 frames themselves (re-encoded losslessly, a check of the rest);
``scattered``
    ``none_k + e_pi(k)``, ``pi`` a random permutation of the frames: the same error fields, no
    longer alike within a key-frame interval (a second of video);
``per-second``
    ``none_k + e_key(k)``, every frame the error of its interval's key frame: one error per
    second, wholly shared by its frames.

If ``scattered`` loses little and ``per-second`` as much as ``codec``, the codec's loss is its
error being shared by the frames of each second: a pixel then has about as many independent
error draws as the video has seconds, whatever the estimator. Run::

    OMP_NUM_THREADS=1 python bench/phone_effects_phone_size.py --work /tmp/pe \\
        --scenes canvas --captures none h264
    OMP_NUM_THREADS=1 python bench/codec_noise.py --work /tmp/pe --scene canvas

Writes ``codec_noise.json`` and ``.png`` into ``--out`` (default ``bench/results``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import av
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from phone_effects_phone_size import git_diff_stat, measure  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.synthetic import writer  # noqa: E402

ARRANGEMENTS = ("codec", "scattered", "per-second")


def decode(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every frame of a video as RGB uint8 ``(t, h, w, 3)``, and which are key frames."""
    with av.open(str(path)) as container:
        pairs = [(f.to_ndarray(format="rgb24"), bool(f.key_frame))
                 for f in container.decode(video=0)]
    return np.stack([p for p, _ in pairs]), np.array([k for _, k in pairs])


def arranged(clean: np.ndarray, error: np.ndarray, keys: np.ndarray, how: str,
             rng: np.random.Generator) -> np.ndarray:
    """The clean frames plus the codec's ``error`` in arrangement ``how`` (uint8)."""
    if how == "codec":
        source = np.arange(len(error))
    elif how == "scattered":
        source = rng.permutation(len(error))
    else:  # per-second: each frame takes its key frame's error
        source = np.maximum.accumulate(np.where(keys, np.arange(len(keys)), 0))
    return np.clip(clean.astype(np.int16) + error[source], 0, 255).astype(np.uint8)


def folder_with(video_frames: np.ndarray, src: Path, folder: Path, fps: float) -> Path:
    """An acquisition folder: ``src``'s poses and acquisition.json, these frames (FFV1)."""
    meta = json.loads((src / "acquisition.json").read_text())
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    shutil.copy2(src / meta["poses"], folder / meta["poses"])
    writer.write_video(folder / "video.mkv", iter(video_frames), fps=fps)
    (folder / "acquisition.json").write_text(json.dumps({**meta, "video": "video.mkv"},
                                                        indent=2))
    return folder


def chart(result: dict, path: Path) -> None:
    """SNR_Y of each arrangement beside the uncompressed capture's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["uncompressed", *ARRANGEMENTS]
    values = [result["uncompressed_snr_y_db"], *(result["rows"][n]["snr_y_db"]
                                                  for n in ARRANGEMENTS)]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.bar(names, values, color=["0.6", "C3", "C0", "C1"])
    for i, v in enumerate(values):
        ax.text(i, v + 0.2, f"{v:.2f}", ha="center")
    ax.set_ylabel("LTM SNR_Y (dB)")
    ax.set_ylim(min(values) - 3, max(values) + 1.5)
    ax.set_title(f"{result['scene']}: the H.264 error rearranged between frames")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--work", type=Path, required=True,
                        help="the phone-size bench's work folder")
    parser.add_argument("--scene", default="canvas")
    parser.add_argument("--lattice", type=int, nargs=2, default=[16, 16])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument("--name", default="codec_noise")
    args = parser.parse_args()
    ideal, codec = (args.work / f"{args.scene}_{c}" for c in ("none", "h264"))
    acq = ideal / "product"
    meta = json.loads((acq / "acquisition.json").read_text())
    codec_meta = json.loads((codec / "product" / "acquisition.json").read_text())
    clean, _ = decode(acq / meta["video"])
    coded, keys = decode(codec / "product" / codec_meta["video"])
    if clean.shape != coded.shape:
        raise SystemExit(f"the two videos differ in shape: {clean.shape} and {coded.shape}")
    error = coded.astype(np.int16) - clean.astype(np.int16)
    with av.open(str(acq / meta["video"])) as container:
        fps = float(container.streams.video[0].average_rate)
    truth = ideal / "raw" / "truth.zarr"
    result = {"scene": args.scene, "frames": len(clean), "key_frames": int(keys.sum()),
              "error_rms_code_values": float(np.sqrt(np.mean(error.astype(np.float64) ** 2))),
              "rows": {}, "version": __version__, "started": time.strftime("%Y-%m-%d %H:%M"),
              "machine": {"platform": platform.platform(), "cores": os.cpu_count()},
              "load_before": os.getloadavg(), "git_diff_stat": git_diff_stat()}
    result["uncompressed_snr_y_db"] = measure(acq, truth, tuple(args.lattice), "off")["snr_y_db"]
    rng = np.random.default_rng(args.seed)
    for how in ARRANGEMENTS:
        folder = folder_with(arranged(clean, error, keys, how, rng), acq,
                             args.work / f"codec_noise_{args.scene}_{how}", fps)
        result["rows"][how] = measure(folder, truth, tuple(args.lattice), "off")
        print(how, f"{result['rows'][how].get('snr_y_db', float('nan')):.2f} dB", flush=True)
    result["load_after"] = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.name}.json").write_text(json.dumps(result, indent=2))
    chart(result, args.out / f"{args.name}.png")


if __name__ == "__main__":
    main()
