"""Held-out error of a store: cross-validation on the binned samples of a resampled store.

The array-level test lives in :mod:`ltmstore.solve.validate` (solvers use it to choose their
parameters); this module reads a store, picks pixels from whole tiles and reports the result.
"""

from __future__ import annotations

import os
import time
from itertools import product

import numpy as np

from ltmstore.core.dims import SAMPLES, Lattice, object_extent, object_pixels
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store, stages
from ltmstore.solve import Geometry
from ltmstore.solve.select import AUTO, solve_auto
from ltmstore.solve.validate import as_method, check_split, heldout_error, observed_range


def store_geometry(ds) -> Geometry:
    """The lattice and plane height of a resampled store (from its provenance)."""
    entry = stages(ds).get("resample", {})
    try:
        lat = entry["lattice"]
        lattice = Lattice(bounds=tuple(tuple(float(v) for v in b) for b in lat["bounds"]),
                          shape=tuple(int(v) for v in lat["shape"]), dims=tuple(lat["dims"]))
        height = float(ds.attrs["acquisition"]["plane"]["height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise LtmError(f"store has no usable resample record ({exc}); run ltm reconstruct") \
            from exc
    return Geometry(lattice=lattice, height=height)


def _pick_pixels(arr, max_pixels: int, rng: np.random.Generator, extent: dict | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """Up to ``max_pixels`` random pixels ``(n, *lattice)``, read from random whole tiles only,
    and with ``extent`` (the acquisition's ``object``) their object-plane positions ``(n, 2)``."""
    import dask

    starts = [np.cumsum((0, *c)) for c in arr.chunks[:2]]
    tiles = list(product(*(range(len(c)) for c in arr.chunks[:2])))
    picked, where, total = [], [], 0
    for index in rng.permutation(len(tiles)):
        i, j = tiles[index]
        picked.append(arr.blocks[i, j])
        if extent is not None:
            rows, cols = (slice(s[k], s[k + 1]) for s, k in zip(starts, (i, j), strict=True))
            where.append(object_pixels(extent, arr.shape[:2], rows, cols))
        total += arr.chunks[0][i] * arr.chunks[1][j]
        if total >= max_pixels:
            break
    data = np.concatenate([b.reshape(-1, *arr.shape[2:]) for b in dask.compute(*picked)])
    pixels = np.concatenate(where) if where else None
    if len(data) > max_pixels:
        keep = np.sort(rng.choice(len(data), max_pixels, replace=False))
        data, pixels = data[keep], None if pixels is None else pixels[keep]
    return data, pixels


def heldout_store(store: str | os.PathLike, *, method: str = "cs", folds: int = 5,
                  max_pixels: int = 4096, seed: int = 0, params: dict | None = None,
                  fraction: float | None = None, block: int = 1) -> dict:
    """Held-out error of ``method`` on the binned samples of a resampled store.

    Reads ``samples`` (written by ``ltm reconstruct``) from a random subset of whole pixel
    tiles, up to ``max_pixels`` pixels, and runs :func:`heldout_error` on them.

    Returns
    -------
    dict
        ``method``, ``params``, ``folds``, ``fraction``, ``block``, ``pixels``, ``K`` (mean
        observed cells per pixel), ``M``, ``relative_error``, ``heldout_snr_db``,
        ``rms_median``, ``rms_p90``, ``relative_rms_median`` (RMS over the pixel's observed
        range), ``cells_per_fold``, ``shared_mask``, ``seconds``.

    Raises
    ------
    LtmError
        The store has no complete ``samples``, or bad arguments.
    """
    if int(max_pixels) != max_pixels or max_pixels < 1:
        raise LtmError(f"max_pixels {max_pixels!r} must be a positive integer")
    solver = solve_auto if method == AUTO else as_method(method)
    ds = open_store(store)
    if SAMPLES not in ds:
        raise LtmError(f"store {str(store)!r} has no complete samples; run ltm reconstruct first")
    start = time.perf_counter()
    samples, pixels = _pick_pixels(ds[SAMPLES].data, int(max_pixels),
                                   np.random.default_rng([seed, 707]),
                                   object_extent(ds.attrs))
    geometry = store_geometry(ds).with_pixels(pixels)
    result = heldout_error(samples, geometry, solver, folds=folds, seed=seed, params=params,
                           fraction=fraction, block=block)
    observed = np.isfinite(samples).reshape(len(samples), -1)
    spread = observed_range(samples)
    with np.errstate(invalid="ignore", divide="ignore"):
        relative = result.rms / np.where(spread > 0, spread, np.nan)
    return {"method": method, "params": dict(params or {}), "folds": result.folds,
            "fraction": check_split(folds, fraction, block), "block": int(block),
            "pixels": len(samples), "K": float(observed.sum(axis=1).mean()),
            "M": int(observed.shape[1]), "relative_error": result.relative_error,
            "heldout_snr_db": result.snr_db, "rms_median": _nan_stat(np.nanmedian, result.rms),
            "rms_p90": _nan_stat(lambda v: np.nanpercentile(v, 90), result.rms),
            "relative_rms_median": _nan_stat(np.nanmedian, relative),
            "cells_per_fold": list(result.cells_per_fold), "shared_mask": result.shared_mask,
            "seconds": time.perf_counter() - start}


def _nan_stat(func, values: np.ndarray) -> float:
    return float(func(values)) if np.isfinite(values).any() else float("nan")
