"""What an export loses against the store: its images at a capture's held-out lights (or, when
none were held out, at the capture's own lights), beside ``ltm relight``'s.

The RTI literature's measure: 8-bit images the size of the photograph, PSNR = 10 log10(255^2 /
MSE) over every pixel and channel, averaged over the lights. The store's images are
``ltm relight``'s (capture exposure, the capture's transfer); an export's are its coefficients
evaluated with its basis at the same light directions, as its viewer draws them.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from ltmstore.core.lights import FAR, disk_to_direction, light_kind, plane_to_direction
from ltmstore.core.store import open_store

MAX_LIGHTS = 16  # at most this many of the capture's lights are scored (evenly picked)
BAND_PIXELS = 2**18  # an export's images at the checkpoints are evaluated this many pixels at once


@dataclass(frozen=True)
class Checkpoints:
    """Light directions an export is scored at, with what the store and the camera saw there.

    Attributes
    ----------
    directions : ndarray, shape (n, 3)
        Unit directions towards the lights.
    store : ndarray of uint8, shape (n, y, x, 3)
        ``ltm relight`` at those lights.
    photos : ndarray of uint8, shape (n, y, x, 3), or None
        The held-out photographs, where the capture recorded and still has them.
    held_out : bool
        True for held-out lights, False for the capture's own lights.
    """

    directions: np.ndarray
    store: np.ndarray
    photos: np.ndarray | None
    held_out: bool


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over the lights of each 8-bit image pair's PSNR (dB), ``(n, y, x, 3)`` each
    (exact: integer squared differences, a light at a time)."""
    mse = []
    for x, y in zip(a, b, strict=True):
        d = x.astype(np.int32) - y.astype(np.int32)
        mse.append(max(float(np.square(d, out=d).sum(dtype=np.int64)) / d.size, 1e-12))
    return float(np.mean(10 * np.log10(255.0 ** 2 / np.array(mse))))


def banded(render: Callable[[slice], np.ndarray], shape: tuple[int, int], n: int
           ) -> np.ndarray:
    """8-bit images ``(n, y, x, 3)`` of ``shape (y, x)`` from ``render(rows)``, display values
    ``(n, rows, x, 3)`` in ``[0, 1]``, a band of rows at a time (:data:`BAND_PIXELS`): an
    export's images at the checkpoints without its float values whole."""
    images = np.empty((n, *shape, 3), np.uint8)
    step = max(1, BAND_PIXELS // shape[1])
    for y0 in range(0, shape[0], step):
        rows = slice(y0, min(y0 + step, shape[0]))
        images[:, rows] = display_images(render(rows))
    return images


def _photos(ds, records: list[dict]) -> np.ndarray | None:
    """The held-out photographs (8-bit RGB), or None if any is missing or of another size."""
    folder = Path(ds.attrs.get("acquisition", {}).get("lp_path", "")).parent
    try:
        photos = np.stack([np.asarray(Image.open(folder / r["image"]).convert("RGB"))
                           for r in records])
    except (OSError, KeyError, ValueError):
        return None
    return photos if photos.shape[1:3] == (ds.sizes["y"], ds.sizes["x"]) else None


def checkpoints(store: str | os.PathLike) -> Checkpoints | None:
    """The held-out lights the ingest recorded, else up to :data:`MAX_LIGHTS` of the capture's
    own lights, with ``ltm relight``'s images there (and the held-out photographs); None for a
    store that records neither (an old one)."""
    from ltmstore.stages.relight import encoded_images, relight  # share sits above stages

    ds = open_store(store)
    records = ds.attrs.get("stages", {}).get("ingest", {}).get("held_out") or []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if records:
            directions = np.array([r["direction"] for r in records], float)
            linear = relight(ds, directions=directions)
            photos = _photos(ds, records)
        elif not all(name in ds for name in ("pose_r", "pose_s", "pose_valid")):
            return None
        else:
            valid = np.asarray(ds["pose_valid"].values, bool)
            lights = np.column_stack([ds["pose_r"].values, ds["pose_s"].values])[valid]
            if len(lights) == 0:
                return None
            lights = lights[np.unique(np.linspace(0, len(lights) - 1, MAX_LIGHTS).round()
                                      .astype(int))]
            if light_kind(ds.attrs.get("acquisition", {})) == FAR:
                directions = disk_to_direction(lights[:, 0], lights[:, 1])
            else:
                height = float(ds.attrs["acquisition"]["plane"]["height"])
                directions = plane_to_direction(lights[:, 0], lights[:, 1], height)
            linear = relight(ds, lights)
            photos = None
        transfer = ds.attrs.get("acquisition", {}).get("transfer", "srgb")
        store_images = np.stack(list(encoded_images(linear, transfer)))  # a band at a time
    return Checkpoints(directions=np.asarray(directions, float), store=store_images,
                       photos=photos, held_out=bool(records))


def central_window(shape: tuple[int, int], side: int, block: int = 1
                   ) -> tuple[slice, slice]:
    """Rows and columns of the central window, at most ``side`` pixels a side, of an image of
    ``shape (y, x)``, starting on a multiple of ``block``: where a choice is judged at the same
    cost at 24 MP as at 1 MP."""
    def span(n: int) -> slice:
        size = min(n, side)
        start = (n - size) // 2 // block * block
        return slice(start, start + size)
    return span(shape[0]), span(shape[1])


def display_images(values: np.ndarray) -> np.ndarray:
    """Display values in ``[0, 1]`` (any shape) as a viewer writes them: 8-bit, rounded."""
    return np.clip(np.round(255 * np.asarray(values, np.float64)), 0, 255).astype(np.uint8)


def summary(name: str, images: np.ndarray, check: Checkpoints) -> dict:
    """The export's PSNRs at the checkpoints: against the photographs and ``ltm relight``'s
    (where there are photographs) and against ``ltm relight``; with a one-line ``text``."""
    n = len(check.directions)
    against_store = psnr(images, check.store)
    out = {"lights": n, "held_out": check.held_out, "db_vs_store": round(against_store, 2)}
    if check.photos is not None:
        out["db_vs_photos"] = round(psnr(images, check.photos), 2)
        out["store_db_vs_photos"] = round(psnr(check.store, check.photos), 2)
        out["text"] = (f"{name}: {out['db_vs_photos']:.1f} dB against the {n} held-out "
                       f"photographs (ltm relight {out['store_db_vs_photos']:.1f} dB); "
                       f"{against_store:.1f} dB against ltm relight there")
    else:
        where = "held-out lights" if check.held_out else "capture's lights"
        out["text"] = (f"{name}: {against_store:.1f} dB against ltm relight at {n} of the "
                       f"{where}")
    return out
