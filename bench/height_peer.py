"""The height of given normals: ``ltm maps --height``'s integrations beside Relight's own
(``relight-normals -i bni|fft``), on SynthRTI's bas-relief, whose normals are given.

Run: ``python bench/height_peer.py --relight-normals PATH [--data ../shared/data]
[--out bench/results] [--repeats 3]``.

SynthRTI gives normals, not depth, so each height is scored by the normals it gives back
(:func:`ltmstore.solve.height.normals_of`) against the given ones: the median and 90th
percentile angle (an integrable field would give 0; the relief's occluding edges are not one).
Beside it, each height against ``poisson``'s (mean and best-fitting plane removed from both: the
integrations leave the offset and tilt free) as an RMS in pixels of height, and the wall time
(this code's integration alone, in process; relight-normals as a whole command, reading the
16-bit PNG, which it reads at 8 bits). Writes ``height_peer.json`` and ``height_peer.png`` (the
four heights side by side) to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from ltmstore.core.provenance import commit
from ltmstore.solve.height import INTEGRATIONS, integrate, normals_of

sys.path.insert(0, str(Path(__file__).parent))
from normals_baseline import truth_normals  # noqa: E402
from rti_speed import load  # noqa: E402

SCENE = "synthrti/multi-obj2-material1"
RELIGHT = ("bni", "fft")


def angles(height: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Degrees between the normals of ``height`` and ``truth (H, W, 3)``, every pixel."""
    cos = np.clip((normals_of(height) * truth).sum(axis=-1), -1, 1)
    return np.degrees(np.arccos(cos)).ravel()


def detrended(height: np.ndarray) -> np.ndarray:
    """``height`` less its least-squares plane (offset and tilt)."""
    rows, cols = np.indices(height.shape)
    design = np.column_stack([np.ones(height.size), rows.ravel(), cols.ravel()])
    coef = np.linalg.lstsq(design, height.ravel(), rcond=None)[0]
    return height - (design @ coef).reshape(height.shape)


def relight_height(tool: str, normals_png: Path, method: str, tmp: Path) -> tuple[np.ndarray,
                                                                                  float]:
    """Relight's height of ``normals_png`` by ``method`` (its ``heightmap.tiff``, in pixels,
    higher towards the camera) and the command's wall seconds."""
    out = tmp / method  # relight-normals' -o: the folder of its outputs
    start = time.perf_counter()
    subprocess.run([tool, str(normals_png), "-i", method, "-o", str(out)], check=True,
                   capture_output=True)
    seconds = time.perf_counter() - start
    return tifffile.imread(out / "heightmap.tiff").astype(np.float64), seconds


def chart(heights: dict[str, np.ndarray], scores: dict, path: Path) -> None:
    """The heights side by side, each with its median angle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(heights), figsize=(3.2 * len(heights), 3.4))
    for ax, (name, height) in zip(axes, heights.items(), strict=True):
        ax.imshow(detrended(height), cmap="viridis")
        ax.set_title(f"{name}: {scores[name]['median_deg']:.1f} deg median", fontsize=9)
        ax.axis("off")
    fig.suptitle("SynthRTI bas-relief: its given normals integrated", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--relight-normals", required=True)
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--repeats", default=3, type=int)
    args = parser.parse_args()
    normals_png = args.data / SCENE / "normals.png"
    truth = truth_normals(normals_png)
    truth /= np.linalg.norm(truth, axis=-1, keepdims=True)
    heights, times = {}, {}
    before = load()
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):  # alternating: this code's, then Relight's
            for method in INTEGRATIONS:
                start = time.perf_counter()
                heights[f"ltm {method}"] = integrate(truth, method)
                times.setdefault(f"ltm {method}", []).append(time.perf_counter() - start)
            for method in RELIGHT:
                name = f"relight-normals {method}"
                heights[name], seconds = relight_height(args.relight_normals, normals_png,
                                                        method, Path(tmp))
                times.setdefault(name, []).append(seconds)
    reference = detrended(heights["ltm poisson"])
    scores = {}
    for name, height in heights.items():
        error = angles(height, truth)
        scores[name] = {"median_deg": float(np.median(error)),
                        "p90_deg": float(np.percentile(error, 90)),
                        "range_px": float(height.max() - height.min()),
                        "rms_to_poisson_px": float(np.sqrt(np.mean(
                            (detrended(height) - reference) ** 2))),
                        "seconds": statistics.median(times[name])}
        print(f"{name}: {scores[name]}", flush=True)
    result = {"command": " ".join(sys.argv), "commit": commit(), "scene": SCENE,
              "shape": list(truth.shape[:2]), "repeats": args.repeats, "scores": scores,
              "load_before": before, "load_after": load()}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "height_peer.json").write_text(json.dumps(result, indent=1))
    chart(heights, scores, args.out / "height_peer.png")


if __name__ == "__main__":
    main()
