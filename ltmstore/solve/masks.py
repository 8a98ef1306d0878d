"""Batching helpers shared by the baseline methods: group pixels by mask, fold views into rows.

All pixels of an acquisition usually share one sampling mask, so a method that builds something
per mask (a triangulation, a pseudo-inverse, a weight matrix, a Gram matrix) builds it once and
applies it to every pixel of the group as one matrix product. :func:`solve_by_mask` does that
bookkeeping: a method supplies only ``fit(cells, values) -> estimate`` for one mask.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.dims import Lattice
from ltmstore.core.errors import LtmError

if TYPE_CHECKING:
    from ltmstore.solve import Geometry

#: ``fit(cells, values) -> estimate``: ``cells`` the observed-cell mask ``(M,)`` of a group,
#: ``values`` its observations ``(K, g)`` (one column per pixel), ``estimate`` ``(M, g)``.
GroupFit = Callable[[np.ndarray, np.ndarray], np.ndarray]


def group_by_mask(mask: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Rows that share the same observed cells.

    Parameters
    ----------
    mask : ndarray of bool, shape ``(n, ...)``
        Observed cells per row (trailing axes are flattened in C order).

    Yields
    ------
    cells : ndarray of bool, shape ``(M,)``
        The mask of the group (possibly all False).
    rows : ndarray of int
        Indices of the rows with exactly that mask, ascending.
    """
    mask = np.asarray(mask, dtype=bool)
    if len(mask) == 0:
        return
    flat = mask.reshape(len(mask), -1)
    if (flat == flat[0]).all():  # a handheld capture's tile: one mask, no sort of the rows
        yield flat[0], np.arange(len(flat))
        return
    packed = np.packbits(flat, axis=1)
    _, first, inverse = np.unique(packed, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.cumsum(np.bincount(inverse))[:-1]
    for group, rows in zip(first, np.split(order, bounds), strict=True):
        yield flat[group], rows


def solve_by_mask(samples: np.ndarray, fit: GroupFit, *,
                  at: np.ndarray | None = None) -> np.ndarray:
    """Apply a per-mask ``fit`` to every group of rows of a batch ``(n, *lattice)``.

    Rows with no observed cell come back as zeros. NaN (or any non-finite value) marks an
    unobserved cell. ``at``: flat indices of the only cells wanted (``fit`` then returns
    ``(len(at), g)``).

    Returns
    -------
    ndarray of float32, same shape as ``samples`` (``(n, len(at))`` with ``at``).
    """
    samples = np.asarray(samples)
    flat = samples.reshape(len(samples), -1)
    observed = np.isfinite(flat)
    # the fit sees the observed values in float64 and its estimate is stored as float32; only
    # those values are converted, not the whole (n, M) batch (a handheld tile: one group)
    out = np.zeros((len(flat), flat.shape[1] if at is None else len(at)), dtype=np.float32)
    for cells, rows in group_by_mask(observed):
        if cells.any():
            group = slice(None) if len(rows) == len(flat) else rows  # one group: no gather
            values = np.take(flat[group], np.flatnonzero(cells), axis=1).astype(np.float64)
            out[group] = fit(cells, values.T).T
    return out.reshape(samples.shape if at is None else out.shape)


def light_geometry(geometry: Geometry) -> Geometry:
    """The geometry of the light axes ``(r, s)`` alone (the first two lattice axes)."""
    if geometry.ndim < 2:
        raise LtmError(f"this method needs the light axes (r, s); got a lattice of shape "
                       f"{geometry.shape}")
    lat = geometry.lattice
    return dataclasses.replace(
        geometry, lattice=Lattice(bounds=lat.bounds[:2], shape=lat.shape[:2], dims=lat.dims[:2])
    )


def per_view(samples: np.ndarray, geometry: Geometry,
             solve2d: Callable[[np.ndarray, Geometry], np.ndarray]) -> np.ndarray:
    """Run a method of the light axes ``(r, s)`` separately for every view ``(p, q, ...)``.

    A batch ``(n, R, S, P, Q)`` becomes ``(n * P * Q, R, S)`` rows for ``solve2d``; 2-D lattices
    pass through unchanged.
    """
    geometry2d = light_geometry(geometry)
    if geometry.ndim == 2:
        return solve2d(samples, geometry2d)
    samples = np.asarray(samples)
    n, light, views = len(samples), samples.shape[1:3], samples.shape[3:]
    rows = np.moveaxis(samples, (1, 2), (-2, -1)).reshape(-1, *light)
    out = solve2d(rows, geometry2d).reshape(n, *views, *light)
    return np.ascontiguousarray(np.moveaxis(out, (-2, -1), (1, 2)))


def nearest_fill(points: np.ndarray, sources: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Nearest-neighbour values ``(len(points), g)`` from ``values (K, g)`` at ``sources``."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(sources).query(points)
    return values[idx]
