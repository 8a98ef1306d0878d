"""Accuracy measures: the paper's SNR_Y and PSNR of relit images."""

from __future__ import annotations

import numpy as np
import xarray as xr

from ltmstore.dims import LTM
from ltmstore.errors import LtmError
from ltmstore.store import open_store


def snr_db(truth, estimate) -> float:
    """``20 log10(||T|| / ||T - T_hat||)`` over the whole array (the paper's SNR_Y).

    Works on NumPy, Dask or xarray inputs of the same shape; Dask inputs are reduced lazily
    and computed once.
    """
    truth, estimate = (x.data if isinstance(x, xr.DataArray) else x for x in (truth, estimate))
    diff = truth - estimate
    num = (truth.astype(np.float64) ** 2).sum()
    den = (diff.astype(np.float64) ** 2).sum()
    if hasattr(num, "compute"):
        import dask

        num, den = dask.compute(num, den)
    return float(10 * np.log10(float(num) / max(float(den), 1e-300)))


def psnr_db(truth, estimate, *, peak: float | None = None) -> float:
    """PSNR of an image (or a stack) against the truth; ``peak`` defaults to ``max(truth)``."""
    truth, estimate = np.asarray(truth, np.float64), np.asarray(estimate, np.float64)
    peak = float(truth.max()) if peak is None else peak
    mse = float(np.mean((truth - estimate) ** 2))
    return float(10 * np.log10(peak**2 / max(mse, 1e-300)))


def compare_stores(store, truth) -> dict:
    """SNR_Y of a reconstructed store against a ground-truth store on the same lattice,
    and the PSNR of images relit at five lattice cells (centre and near the corners)."""
    est, ref = open_store(store), open_store(truth)
    for name, path, ds in (("store", store, est), ("truth", truth, ref)):
        if LTM not in ds:
            raise LtmError(f"{name} {str(path)!r} has no complete ltm")
    a, b = est[LTM], ref[LTM]
    for dim in b.dims:
        if a.sizes.get(dim) != b.sizes[dim] or not np.allclose(a[dim], b[dim]):
            raise LtmError(f"lattices differ along {dim!r}: store {a.sizes.get(dim)} cells, "
                           f"truth {b.sizes[dim]}; reconstruct with the truth's --lattice")
    n, m = a.sizes["r"], a.sizes["s"]
    cells = [(n // 2, m // 2), (n // 4, m // 4), (3 * n // 4, m // 4), (n // 4, 3 * m // 4),
             (3 * n // 4, 3 * m // 4)]
    psnr = [psnr_db(b.isel(r=i, s=j).values, a.isel(r=i, s=j).values) for i, j in cells]
    return {"snr_y_db": snr_db(b, a), "psnr_db_median": float(np.median(psnr)),
            "psnr_db": psnr, "cells": cells}
