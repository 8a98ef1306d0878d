"""Normal maps of the SynthRTI scenes: the surface model of ``ltm reconstruct`` against classic
Lambertian photometric stereo, the baseline that a physical model (issue 15) must beat.

Run: ``python bench/normals_baseline.py [--data ../shared/data/synthrti] [--out bench/results]``.
For each scene, the 49 ``dome/`` photographs (sRGB decoded to linear, luminance) and their
``dirs.lp`` directions give per pixel the least-squares ``g = rho n`` of ``I = L g``
(Woodham 1980), ``plain`` over every light and ``trimmed`` without each pixel's darkest 25 %
(shadows) and brightest 10 % (highlights) of its lights. The angle to ``normals.png`` (16-bit
RGB, ``n = 2 v / 65535 - 1``) is reported per scene, mean and median in degrees, over the pixels
whose truth is a unit normal, beside ``flat``: the constant normal ``(0, 0, 1)``, the trivial
answer (the SynthRTI surfaces tilt by at most a few degrees, so it is the bar to beat), and
``surface``: the normals of :mod:`ltmstore.stages.surface` (the per-pixel reflectance model
that ``ltm reconstruct`` fits to a far-light capture and stores as ``normal``) fitted to the
same photographs and directions. Writes ``normals_baseline.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.lp import read_lp
from ltmstore.core.transfer import srgb_to_linear
from ltmstore.solve.physical import unit_normal
from ltmstore.stages.surface import fit_image

LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
KINDS = ("flat", "plain", "trimmed", "surface")
TRIM = (0.25, 0.10)  # darkest and brightest fractions of each pixel's lights left out


def linear_rgb(path: Path) -> np.ndarray:
    """Linear RGB of an sRGB image file, ``(H, W, 3)`` float32."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    return srgb_to_linear(bgr[..., ::-1].astype(np.float32) / np.iinfo(bgr.dtype).max)


def surface_normals(rgb: np.ndarray, lights: np.ndarray) -> np.ndarray:
    """Unit normals ``(H * W, 3)`` of the surface model fitted to ``rgb (K, H, W, 3)``."""
    theta = fit_image(rgb, lights, workers=os.cpu_count() or 1).reshape(-1, 3, 6)
    return unit_normal(theta[:, 0, 0], theta[:, 0, 1])


def truth_normals(path: Path) -> np.ndarray:
    """``normals.png`` as unit vectors ``(H, W, 3)`` (x right, y up, z towards the camera)."""
    bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return bgr[..., ::-1].astype(np.float64) / np.iinfo(bgr.dtype).max * 2 - 1


def photometric_stereo(images: np.ndarray, lights: np.ndarray, trim: tuple[float, float] | None
                       ) -> np.ndarray:
    """Unit normals ``(P, 3)`` from ``images (K, P)`` under unit ``lights (K, 3)``."""
    if trim is None:
        g = np.linalg.lstsq(lights, images, rcond=None)[0].T
    else:
        k = len(lights)
        order = np.argsort(images, axis=0)
        keep = order[int(trim[0] * k): k - int(trim[1] * k)]  # (k', P) light indices
        lk = lights[keep]  # (k', P, 3)
        ik = np.take_along_axis(images, keep, axis=0)
        ata = np.einsum("kpi,kpj->pij", lk, lk)
        atb = np.einsum("kpi,kp->pi", lk, ik)
        g = np.linalg.solve(ata + 1e-9 * np.eye(3), atb[..., None])[..., 0]
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def angles(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    cos = np.clip(np.sum(estimate * truth, axis=1), -1, 1)
    return np.degrees(np.arccos(cos))


def scene_row(folder: Path) -> dict:
    names, lights = read_lp(folder / "dome" / "dirs.lp")
    rgb = np.stack([linear_rgb(folder / "dome" / n) for n in names])
    images = (rgb @ LUMA).reshape(len(names), -1)
    truth = truth_normals(folder / "normals.png").reshape(-1, 3)
    valid = np.abs(np.linalg.norm(truth, axis=1) - 1) < 0.05
    lights = lights / np.linalg.norm(lights, axis=1, keepdims=True)
    row = {"scene": folder.name, "lights": len(names), "pixels": int(valid.sum())}
    for name, trim in (("flat", None), ("plain", None), ("trimmed", TRIM), ("surface", None)):
        if name == "flat":
            estimate = np.broadcast_to([0.0, 0.0, 1.0], (int(valid.sum()), 3))
        elif name == "surface":
            estimate = surface_normals(rgb, lights)[valid]
        else:
            estimate = photometric_stereo(images[:, valid], lights, trim)
        err = angles(estimate, truth[valid])
        row[f"{name}_mean_deg"], row[f"{name}_median_deg"] = float(err.mean()), float(
            np.median(err))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=Path("../shared/data/synthrti"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    args = parser.parse_args()
    rows = []
    for folder in sorted(p for p in args.data.iterdir() if (p / "normals.png").exists()):
        rows.append(scene_row(folder))
        print(json.dumps(rows[-1]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "normals_baseline.json").write_text(json.dumps({
        "command": "python bench/normals_baseline.py", "trim": TRIM,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()}, "rows": rows},
        indent=1))
    kinds = KINDS
    print("| scene | " + " | ".join(f"{k} mean / median" for k in kinds) + " |\n| --- |"
          + " --- |" * len(kinds))
    for r in rows:
        print(f"| {r['scene']} | " + " | ".join(
            f"{r[k + '_mean_deg']:.1f} / {r[k + '_median_deg']:.1f}" for k in kinds) + " |")
    print("| mean | " + " | ".join(f"{np.mean([r[k + '_mean_deg'] for r in rows]):.1f}"
                                   for k in kinds) + " |")


if __name__ == "__main__":
    main()
