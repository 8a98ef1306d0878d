"""Where the codec's loss lands: camera B's H.264 frames against the uncompressed ones, and the
two captures' LTMs against the truth, split by the lattice cells the path observed and the ones
the surface model fills.

Run on the two stores and videos of ``bench/phone_effects_phone_size.py`` (``--captures none
h264``; stores by ``ltm ingest FOLDER STORE`` and ``ltm reconstruct STORE --lattice 16x16 --color
off`` of ``WORK/canvas_none/product`` and ``WORK/canvas_h264/product``)::

    python bench/codec_split.py --work /tmp/pe --ideal-store none.zarr --codec-store h264.zarr

It writes ``codec_split.json`` and ``.png`` into ``--out``:

* the codec's error per frame of linear luminance (the product's own decoding,
  :func:`ltmstore.capture.yuv.frame_to_rgb`, and sRGB linearised), relative to the frames' RMS,
  by frame type (I, P, B), and its part that stays the same through the whole video;
* SNR_Y of each store against the truth on the observed cells and on the unobserved ones, and
  each part's share of the error;
* the fitted surface (normal, roughness) against the scene's own (``--scene`` rebuilt at the
  frame size).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import av
import numpy as np

from ltmstore import __version__
from ltmstore.capture.yuv import frame_to_rgb
from ltmstore.core.dims import LTM, LUMA
from ltmstore.core.store import open_store
from ltmstore.core.transfer import transfer_lut
from ltmstore.synthetic.scenes import make_scene

TYPES = {1: "I", 2: "P", 3: "B"}


def decoded(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Linear luminance ``(t, h, w)`` of every frame, and each frame's picture type."""
    lut = transfer_lut("srgb", bits=8)
    with av.open(str(path)) as container:
        pairs = [((lut[frame_to_rgb(f)] @ LUMA).astype(np.float32), int(f.pict_type))
                 for f in container.decode(video=0)]
    return np.stack([p for p, _ in pairs]), np.array([t for _, t in pairs])


def frame_error(codec: Path, ideal: Path, valid: np.ndarray) -> dict:
    """The codec's error per frame, relative to the ideal frames' RMS (the ``valid`` frames)."""
    y_codec, types = decoded(codec)
    y_ideal, _ = decoded(ideal)
    y_codec, y_ideal, types = y_codec[valid], y_ideal[valid], types[valid]
    error = y_codec - y_ideal
    scale = float(np.sqrt(np.mean(y_ideal**2)))
    static = error.mean(axis=0)
    out = {"relative_rms": float(error.std() / scale),
           "static_relative_rms": float(static.std() / scale),
           "changing_relative_rms": float((error - static).std() / scale), "by_type": {}}
    for code, name in TYPES.items():
        mine = types == code
        if mine.any():
            out["by_type"][name] = {"frames": int(mine.sum()), "snr_db": float(
                20 * np.log10(scale / np.sqrt(np.mean(error[mine] ** 2))))}
    return out


def ltm_split(store: Path, truth: np.ndarray, observed: np.ndarray) -> dict:
    """SNR_Y of ``store`` against ``truth`` on the observed and the unobserved cells."""
    ltm = open_store(store)[LTM].transpose("y", "x", "r", "s").values.astype(np.float64)
    error = ltm - truth
    total = float(np.sum(error**2))
    out = {"snr_y_db": _snr(truth, error), "per_cell_error_db": _per_cell(truth, error)}
    for name, cells in (("observed", observed), ("unobserved", ~observed)):
        out[name] = {"cells": int(cells.sum()), "snr_y_db": _snr(truth[..., cells],
                                                                 error[..., cells]),
                     "error_share": float(np.sum(error[..., cells] ** 2) / total)}
    return out


def _snr(truth: np.ndarray, error: np.ndarray) -> float:
    return float(10 * np.log10(np.mean(truth**2) / np.mean(error**2)))


def _per_cell(truth: np.ndarray, error: np.ndarray) -> list:
    return (10 * np.log10(np.mean(error**2, axis=(0, 1)) / np.mean(truth**2))).round(2).tolist()


def surface_error(store: Path, scene: str, size: int) -> dict:
    """The fitted normal's angle to the scene's (median, degrees) and the fitted roughness's
    correlation with the scene's."""
    truth = make_scene(scene, size=size)
    dy, dx = np.gradient(truth.height, truth.pixel_size)
    normal = np.stack([-dx, dy, np.ones_like(dx)], -1)  # the store's y axis runs up the plane
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    ds = open_store(store)
    cosine = np.clip(np.sum(ds["normal"].values * normal, axis=-1), -1, 1)
    roughness = ds["roughness"].values.ravel()
    return {"normal_error_deg_median": float(np.degrees(np.median(np.arccos(cosine)))),
            "roughness_correlation": float(np.corrcoef(roughness,
                                                       truth.roughness.ravel())[0, 1])}


def chart(result: dict, path: Path) -> None:
    """Each store's error per lattice cell, observed cells outlined."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    observed = np.array(result["observed_cells"])
    both = [np.array(result[name]["ltm"]["per_cell_error_db"]) for name in ("ideal", "codec")]
    low, high = np.floor(min(map(np.min, both))), np.ceil(max(map(np.max, both)))
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2), constrained_layout=True)
    for ax, name, cells in zip(axes, ("ideal", "codec"), both, strict=True):
        im = ax.imshow(cells.T, origin="lower", vmin=low, vmax=high, cmap="magma")
        for r, s in zip(*np.nonzero(observed), strict=True):
            ax.add_patch(plt.Rectangle((r - 0.5, s - 0.5), 1, 1, fill=False, ec="c", lw=0.8))
        ax.set_title(f"{name}: SNR_Y {result[name]['ltm']['snr_y_db']:.2f} dB")
        ax.set_xlabel("r cell")
        ax.set_ylabel("s cell")
    fig.colorbar(im, ax=axes, label="error power per cell, dB of the LTM's power")
    fig.suptitle("LTM error per lattice cell (cyan: observed cells)")
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True,
                        help="phone_effects_phone_size.py's work folder")
    parser.add_argument("--ideal-store", type=Path, required=True)
    parser.add_argument("--codec-store", type=Path, required=True)
    parser.add_argument("--scene", default="canvas")
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    raw = {name: args.work / f"{args.scene}_{name}" / "raw" for name in ("none", "h264")}
    truth_ds = open_store(raw["none"] / "truth.zarr")
    truth = truth_ds[LTM].transpose("y", "x", "r", "s").values.astype(np.float64)
    ideal = open_store(args.ideal_store)
    observed = np.isfinite(ideal["samples"].values).mean(axis=(0, 1)) > 0.5
    result = {"version": __version__, "machine": platform.platform(),
              "command": " ".join(sys.argv), "observed_cells": observed.tolist(),
              "frames": frame_error(raw["h264"] / "video.mp4", raw["none"] / "video.mkv",
                                    ideal["pose_valid"].values)}
    size = truth.shape[0]
    for name, store in (("ideal", args.ideal_store), ("codec", args.codec_store)):
        result[name] = {"ltm": ltm_split(store, truth, observed),
                        "surface": surface_error(store, args.scene, size)}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "codec_split.json").write_text(json.dumps(result, indent=1))
    chart(result, args.out / "codec_split.png")
    print(json.dumps({k: v for k, v in result.items() if k != "observed_cells"}, indent=1)[:3000])


if __name__ == "__main__":
    main()
