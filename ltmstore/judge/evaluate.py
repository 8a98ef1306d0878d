"""Accuracy against a ground truth: the paper's SNR_Y, PSNR of relit images, error maps.

* :func:`snr_db`: ``SNR_Y = 20 log10(||T|| / ||T - T_hat||)`` over the whole LTM (section IV-B);
* :func:`psnr_db`: PSNR of relit images;
* :func:`error_maps`: per-pixel mean and variance of the absolute error over the lattice (the
  paper's Fig. 7: ``||t - t_hat||_1 / M`` and the variance of ``|t - t_hat|``);
* :func:`compare_stores`: all of the above for a reconstructed store against a truth store.

For captures without a ground truth, see :mod:`ltmstore.judge.heldout` (held-out-light error).
"""

from __future__ import annotations

import os
from functools import partial

import numpy as np
import xarray as xr

from ltmstore.core.dims import LIGHT_DIMS, LTM, X, Y
from ltmstore.core.errors import LtmError
from ltmstore.core.paths import check_output
from ltmstore.core.store import open_store
from ltmstore.stages.relight import linear_position

MEAN_ABS_ERROR, VAR_ABS_ERROR = "mean_abs_error", "var_abs_error"
BLOCK_VALUES = 2**21  # lattice values of one pixel block (16 MB per float64 copy)


def _data(x):
    return x.data if isinstance(x, xr.DataArray) else x


def _compute(*values):
    """Compute Dask values together (one pass over the inputs); NumPy values pass through."""
    if any(hasattr(v, "compute") for v in values):
        import dask

        return dask.compute(*values)
    return values


def snr_db(truth, estimate) -> float:
    """``20 log10(||T|| / ||T - T_hat||)`` over the whole array (the paper's SNR_Y).

    Works on NumPy, Dask or xarray inputs of the same shape; Dask inputs are reduced lazily
    and computed once.
    """
    truth, estimate = _data(truth), _data(estimate)
    num, den = _compute(*_energies(truth, estimate))
    return _db(num, den)


def _energies(truth, estimate):
    diff = truth - estimate
    return (truth.astype(np.float64) ** 2).sum(), (diff.astype(np.float64) ** 2).sum()


def _db(num, den) -> float:
    return float(10 * np.log10(float(num) / max(float(den), 1e-300)))


def psnr_db(truth, estimate, *, peak: float | None = None) -> float:
    """PSNR of an image (or a stack) against the truth; ``peak`` defaults to ``max(truth)``."""
    truth, estimate = np.asarray(truth, np.float64), np.asarray(estimate, np.float64)
    peak = float(truth.max()) if peak is None else peak
    mse = float(np.mean((truth - estimate) ** 2))
    return float(10 * np.log10(peak**2 / max(mse, 1e-300)))


def _abs_error_moments(truth, estimate):
    """Lazy (for Dask) per-pixel mean and variance of ``|truth - estimate|`` over axes 2..."""
    axes = tuple(range(2, truth.ndim))
    err = abs(truth.astype(np.float64) - estimate.astype(np.float64))
    return err.mean(axis=axes), err.var(axis=axes)


def _maps_dataset(mean, var, like) -> xr.Dataset:
    coords = {}
    if isinstance(like, xr.DataArray):
        coords = {d: like[d].values for d in like.dims[:2] if d in like.coords}
    dims = like.dims[:2] if isinstance(like, xr.DataArray) else (Y, X)
    attrs = {"definition": "over the lattice cells of each pixel: mean |T - T_hat| "
                           "(= ||T - T_hat||_1 / M) and the variance of |T - T_hat|"}
    return xr.Dataset({MEAN_ABS_ERROR: (dims, np.asarray(mean)),
                       VAR_ABS_ERROR: (dims, np.asarray(var))}, coords=coords, attrs=attrs)


def _check_shapes(truth, estimate) -> None:
    if np.shape(truth) != np.shape(estimate):
        raise LtmError(f"truth shape {np.shape(truth)} and estimate shape "
                       f"{np.shape(estimate)} must be equal")
    if len(np.shape(truth)) < 3:
        raise LtmError(f"error maps need (y, x, *lattice) arrays, got shape {np.shape(truth)}")


def error_maps(truth, estimate) -> xr.Dataset:
    """Per-pixel mean and variance of the absolute error over the lattice (the paper's Fig. 7).

    Parameters
    ----------
    truth, estimate : array_like, shape ``(y, x, *lattice)``
        NumPy, Dask or xarray; Dask inputs are reduced in one pass.

    Returns
    -------
    xarray.Dataset
        ``mean_abs_error (y, x)``: ``||t - t_hat||_1 / M`` per pixel; ``var_abs_error (y, x)``:
        the variance (over the ``M`` cells, ``ddof=0``) of ``|t - t_hat|``. Float64; pixel
        coordinates are kept from an xarray ``truth``.

    Raises
    ------
    LtmError
        Shapes differ, or fewer than three dimensions.
    """
    _check_shapes(truth, estimate)
    mean, var = _compute(*_abs_error_moments(_data(truth), _data(estimate)))
    return _maps_dataset(mean, var, truth)


def summarise_maps(maps: xr.Dataset) -> dict[str, float]:
    """Median and maximum of each error map (NaN-aware), as plain floats."""
    out = {}
    for name in (MEAN_ABS_ERROR, VAR_ABS_ERROR):
        values = maps[name].values
        out[f"{name}_median"] = float(np.nanmedian(values))
        out[f"{name}_max"] = float(np.nanmax(values))
    return out


def plot_error_maps(maps: xr.Dataset, path: str | os.PathLike, *, title: str | None = None) -> None:
    """Write the two error maps side by side as a PNG (Matplotlib's Agg canvas, no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4), layout="constrained")
    FigureCanvasAgg(fig)
    labels = {MEAN_ABS_ERROR: "mean of |T - T_hat| over the lattice",
              VAR_ABS_ERROR: "variance of |T - T_hat| over the lattice"}
    for ax, (name, label) in zip(fig.subplots(1, 2), labels.items(), strict=True):
        image = ax.imshow(maps[name].values, cmap="magma", interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        fig.colorbar(image, ax=ax, shrink=0.85)
    if title:
        fig.suptitle(title)
    try:
        fig.savefig(os.fspath(path), dpi=100)
    except OSError as exc:
        raise LtmError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from exc


def _open_pair(store, truth) -> tuple[xr.DataArray, xr.DataArray]:
    est, ref = open_store(store), open_store(truth)
    for name, path, ds in (("store", store, est), ("truth", truth, ref)):
        if LTM not in ds:
            raise LtmError(f"{name} {str(path)!r} has no complete ltm")
    a, b = est[LTM], ref[LTM]
    if set(a.dims) != set(b.dims) or any(a.sizes[d] != b.sizes[d] for d in b.dims[:2]):
        raise LtmError(f"store ltm {dict(a.sizes)} and truth ltm {dict(b.sizes)} must have the "
                       "same axes and the same image size")
    return a, b


def _same_cells(a: xr.DataArray, b: xr.DataArray, dim: str) -> bool:
    return a.sizes[dim] == b.sizes[dim] and bool(np.allclose(a[dim], b[dim]))


def interpolation_weights(centres: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(len(points), len(centres))`` weights of linear interpolation between cell centres,
    clamped at the first and last centre (:func:`ltmstore.stages.relight.linear_position`, as
    relight places a light)."""
    weights = np.zeros((len(points), len(centres)))
    for k, point in enumerate(points):
        i0, i1, w = linear_position(centres, point)
        weights[k, i0] += 1 - w
        weights[k, i1] += w
    return weights


def _operators(estimate: xr.DataArray, truth: xr.DataArray) -> list[np.ndarray | None]:
    """Per lattice axis of ``truth``: the ``(truth cells, estimate cells)`` interpolation matrix
    (:func:`interpolation_weights`), or None where both have the same cells."""
    return [None if _same_cells(estimate, truth, dim) else
            interpolation_weights(estimate[dim].values, truth[dim].values)
            for dim in truth.dims[2:]]


def _interpolate(block: np.ndarray, operators: list[np.ndarray | None]) -> np.ndarray:
    """A ``(y, x, *lattice)`` block at the truth's cells: each operator applied along its axis
    (in float64, as ``xr.dot`` with float64 weights), the result in float32."""
    out = block
    for axis, weights in enumerate(operators, start=2):
        if weights is not None:
            out = np.moveaxis(np.tensordot(out, weights, axes=([axis], [1])), -1, axis)
    return out.astype(np.float32)


def _pixel_chunks(array, values_per_pixel: int) -> dict[int, int]:
    """Chunks of whole lattices: the array's own pixel chunk (a whole tile), halved along its
    longer side while one block would hold more than :data:`BLOCK_VALUES` values."""
    by, bx = (array.chunksize[:2] if hasattr(array, "chunksize") else array.shape[:2])
    while by * bx * values_per_pixel > BLOCK_VALUES and max(by, bx) > 1:
        by, bx = (-(-by // 2), bx) if by >= bx else (by, -(-bx // 2))
    return {0: by, 1: bx, **{axis: -1 for axis in range(2, array.ndim)}}


def _by_pixel_blocks(estimate: xr.DataArray, truth: xr.DataArray):
    """The Dask arrays of ``truth`` and ``estimate`` (in the truth's dim order) in the same
    pixel blocks of whole lattices: one block per tile, so a graph over them has a few tasks
    per chunk read, whatever the number of cells."""
    import dask.array as da

    lattice = int(np.prod([max(truth.sizes[d], estimate.sizes[d]) for d in truth.dims[2:]]))
    chunks = _pixel_chunks(_data(estimate), lattice)
    return tuple(da.asarray(_data(x)).rechunk(chunks)
                 for x in (truth, estimate.transpose(*truth.dims)))


def at_cells(estimate: xr.DataArray, truth: xr.DataArray) -> xr.DataArray:
    """``estimate`` at the lattice cells of ``truth``: linear along every lattice axis that
    differs (bilinear in ``(r, s)`` and in ``(p, q)``, as relight interpolates); float32, lazy
    for a Dask-backed ``estimate`` (one task per pixel block of whole lattices)."""
    operators = _operators(estimate, truth)
    coords = {d: truth[d].values for d in truth.dims[2:]}
    coords.update({d: estimate[d].values for d in truth.dims[:2] if d in estimate.coords})
    if not hasattr(_data(estimate), "dask"):
        values = _interpolate(estimate.transpose(*truth.dims).values, operators)
        return xr.DataArray(values, dims=truth.dims, coords=coords)
    _, data = _by_pixel_blocks(estimate, truth)
    values = data.map_blocks(_interpolate, operators, dtype=np.float32,
                             chunks=(*data.chunks[:2], *((n,) for n in truth.shape[2:])))
    return xr.DataArray(values, dims=truth.dims, coords=coords)


def _block_stats(truth: np.ndarray, estimate: np.ndarray, *, operators: list,
                 cells: list[tuple[int, ...]]) -> np.ndarray:
    """Per pixel of a block (``(y, x, *lattice)`` each), float64 ``(y, x, 4 + 2 len(cells))``:
    mean and variance of ``|T - T_hat|`` over the lattice, ``sum T^2``, ``sum (T - T_hat)^2``,
    then for each cell (an index tuple into the lattice) the mean of ``(T - T_hat)^2`` and
    the maximum of ``T`` over the lattice axes left (``(p, q)`` in 6D)."""
    estimate = _interpolate(estimate, operators)
    axes = tuple(range(2, truth.ndim))
    diff = truth - estimate  # in float32, as snr_db
    truth64 = truth.astype(np.float64)
    err = truth64 - estimate.astype(np.float64)
    abs_err = np.abs(err)
    out = [abs_err.mean(axis=axes), abs_err.var(axis=axes), (truth64**2).sum(axis=axes),
           (diff.astype(np.float64) ** 2).sum(axis=axes)]
    rest = tuple(range(2, truth.ndim - len(cells[0])))
    for cell in cells:
        at = (slice(None), slice(None), *cell)
        out += [(err[at] ** 2).mean(axis=rest), truth64[at].max(axis=rest)]
    return np.stack(out, axis=-1)


def _pixel_stats(estimate: xr.DataArray, truth: xr.DataArray,
                 cells: list[tuple[int, int]]):
    """Lazy ``(y, x, 4 + 2 len(cells))`` :func:`_block_stats` of ``estimate`` at the truth's
    cells, one task per pixel block (the truth's ``r, s`` must lead its lattice axes)."""
    import dask.array as da

    ref, est = _by_pixel_blocks(estimate, truth)
    n = ref.ndim
    return da.blockwise(partial(_block_stats, operators=_operators(estimate, truth), cells=cells),
                        (0, 1, n + n), ref, tuple(range(n)), est, (0, 1, *range(n, 2 * n - 2)),
                        new_axes={n + n: 4 + 2 * len(cells)}, concatenate=True,
                        dtype=np.float64)


def compare_stores(store, truth, *, maps_png: str | os.PathLike | None = None) -> dict:
    """A reconstructed store against a ground-truth store, at the truth's lattice cells.

    A store reconstructed on another lattice (the automatic one, say) is interpolated at the
    truth's cell centres (as :func:`at_cells`), as relight would render those lights. Everything
    is computed in one pass, one task per pixel block of whole lattices (a tile of the store):
    the graph grows with the chunks read, not with the number of cells.

    Parameters
    ----------
    store, truth : path-like
        The reconstructed store and the truth store (``truth.zarr`` of a simulation).
    maps_png : path-like, optional
        Also write the two error maps as a PNG there (see :func:`plot_error_maps`); never one
        of the stores, a path inside one or a folder holding one
        (:func:`ltmstore.core.paths.check_output`).

    Returns
    -------
    dict
        ``snr_y_db`` (the whole LTM), ``psnr_db`` of images relit at five lattice cells (centre
        and near the corners) with their ``cells`` and ``psnr_db_median``, and the median and
        maximum of the error maps: ``mean_abs_error_median``, ``mean_abs_error_max``,
        ``var_abs_error_median``, ``var_abs_error_max`` (plus ``maps_png`` when written);
        ``interpolated_from``: the store's lattice shape, when it was not the truth's.
    """
    if maps_png is not None:
        check_output(maps_png, (store, truth))
    a, b = _open_pair(store, truth)
    interpolated = not all(_same_cells(a, b, dim) for dim in b.dims[2:])
    lattice = [a.sizes[dim] for dim in b.dims[2:]]
    b = b.transpose(Y, X, *LIGHT_DIMS, ...)
    n, m = (b.sizes[d] for d in LIGHT_DIMS)
    cells = [(n // 2, m // 2), (n // 4, m // 4), (3 * n // 4, m // 4), (n // 4, 3 * m // 4),
             (3 * n // 4, 3 * m // 4)]
    stats = _pixel_stats(a, b, cells)
    mean, var, sums, per_cell, peaks = _compute(
        stats[..., 0], stats[..., 1], stats[..., 2:4].sum(axis=(0, 1)),
        stats[..., 4::2].mean(axis=(0, 1)), stats[..., 5::2].max(axis=(0, 1)))
    num, den = sums
    psnr = [_db(peak**2, mse) for peak, mse in zip(peaks, per_cell, strict=True)]
    maps = _maps_dataset(mean, var, b)
    out = {"snr_y_db": _db(num, den), "psnr_db_median": float(np.median(psnr)),
           "psnr_db": psnr, "cells": cells, **summarise_maps(maps)}
    if interpolated:
        out["interpolated_from"] = lattice
    if maps_png is not None:
        plot_error_maps(maps, maps_png, title=f"absolute error, SNR_Y {out['snr_y_db']:.2f} dB")
        out["maps_png"] = os.fspath(maps_png)
    return out
