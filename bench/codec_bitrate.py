"""What camera B's codec costs by its bitrate: one uncompressed phone-size capture re-encoded as
H.264 (a phone's encoder settings: High profile, a key frame every second) at several bits per
pixel, each through ``ltm ingest`` and ``ltm reconstruct`` as a user runs them, SNR_Y against
the simulation's truth beside the uncompressed video's.

The capture is one that ``bench/phone_effects_phone_size.py`` simulated without effects (its
``SCENE_none`` folder: ``product/`` holds the acquisition folder with the lossless video,
``raw/truth.zarr`` the truth), so every row sees the same frames before the codec::

    OMP_NUM_THREADS=1 python bench/phone_effects_phone_size.py --work /tmp/pe32 \\
        --scenes canvas --captures none --path-density 32
    OMP_NUM_THREADS=1 python bench/codec_bitrate.py --capture /tmp/pe32/canvas_none \\
        --work /tmp/codec

Writes ``codec_bitrate.json`` and ``.png`` into ``--out`` (default ``bench/results``).
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from phone_effects_phone_size import git_diff_stat, measure, read_frames  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.capture.video import VideoReader  # noqa: E402
from ltmstore.synthetic import writer  # noqa: E402

BITS_PER_PIXEL = (0.27, 0.5, 1.0, 2.0, 4.0)  # 0.27: a phone's default H.264 (phone_effects)


def encode(capture: Path, folder: Path, bits_per_pixel: float) -> dict:
    """``capture``'s acquisition folder with its video re-encoded at ``bits_per_pixel``."""
    src = capture / "product"
    meta = json.loads((src / "acquisition.json").read_text())
    video = src / meta["video"]
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src / meta["poses"], folder / meta["poses"])
    with VideoReader(video) as reader:
        fps = reader.fps
    first = next(read_frames(video))
    bitrate = bits_per_pixel * first.shape[0] * first.shape[1] * fps
    start = time.perf_counter()
    n = writer.write_h264(folder / "video.mp4", read_frames(video), fps=fps,
                          bitrate=int(bitrate))
    (folder / "acquisition.json").write_text(json.dumps({**meta, "video": "video.mp4"},
                                                        indent=2))
    return {"frames": n, "bitrate_bit_s": int(bitrate), "encode_s": time.perf_counter() - start,
            "bytes": (folder / "video.mp4").stat().st_size}


def chart(rows: list[dict], reference: dict, path: Path) -> None:
    """SNR_Y against bits per pixel, the uncompressed video as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    xs = [r["bits_per_pixel"] for r in rows]
    ax.plot(xs, [r["product"]["snr_y_db"] for r in rows], "o-", label="H.264")
    ax.axhline(reference["snr_y_db"], color="k", ls="--", label="uncompressed (FFV1)")
    ax.axhline(reference["snr_y_db"] - 1, color="grey", ls=":", label="1 dB below")
    ax.set_xscale("log")
    ax.set_xticks(xs, [f"{x:g}" for x in xs])
    ax.minorticks_off()
    ax.set_xlabel("bits per pixel (bitrate / (width x height x fps))")
    ax.set_ylabel("LTM SNR_Y against the truth (dB)")
    ax.set_title("Camera B's codec by its bitrate (720 px canvas)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", required=True,
                        help="a phone_effects_phone_size SCENE_none folder (product/, raw/)")
    parser.add_argument("--work", required=True, help="work folder (the re-encoded folders)")
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--bits-per-pixel", type=float, nargs="+", default=list(BITS_PER_PIXEL))
    parser.add_argument("--lattice", type=int, nargs=2, default=[16, 16])
    args = parser.parse_args()
    capture, work = Path(args.capture), Path(args.work)
    truth = capture / "raw" / "truth.zarr"
    lattice = tuple(args.lattice)
    reference = measure(capture / "product", truth, lattice, "off")
    print(f"uncompressed: {reference.get('snr_y_db')}", flush=True)
    rows = []
    for bpp in args.bits_per_pixel:
        folder = work / f"bpp_{bpp:g}"
        row = {"bits_per_pixel": bpp, **encode(capture, folder, bpp)}
        row["product"] = measure(folder, truth, lattice, "off")
        print(f"{bpp:g} bits per pixel: {row['product'].get('snr_y_db')}", flush=True)
        rows.append(row)
    result = {"version": __version__, "python": platform.python_version(),
              "cpus": os.cpu_count(), "load": os.getloadavg(), "git_diff_stat": git_diff_stat(),
              "command": "python bench/codec_bitrate.py " + " ".join(sys.argv[1:]),
              "capture": str(capture), "uncompressed": reference, "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "codec_bitrate.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, reference, out / "codec_bitrate.png")


if __name__ == "__main__":
    main()
