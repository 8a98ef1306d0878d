"""Radial basis function interpolation over light directions or cell positions.

Scattered-data interpolation with :class:`scipy.interpolate.RBFInterpolator`, the usual
alternative to PTM/HSH in reflectance transformation imaging (Giachetti et al., "A novel
framework for highlight reflectance transformation imaging", CVIU 168, 2018). By default a
thin-plate spline with a linear polynomial tail over the projected light directions ``(lu, lv)``:
it interpolates the observed cells exactly (``smoothing=0``) and reproduces affine functions of
the coordinates. ``space="positions"`` interpolates over the cell centres instead (all lattice
axes, so a 6-D lattice is one 4-D interpolation); in direction space a 6-D lattice gets one
interpolant per view ``(p, q)``. Pixels sharing a mask share one RBF system, solved for all of
them at once.

Where it fails: exact interpolation of a sparse trajectory overshoots near shadow edges and
highlights, and the linear tail extrapolates into large unobserved corners. The dense system is
``O(K^3)`` per mask (use ``neighbors`` for large K). With fewer observed cells than polynomial
terms, or a singular system (e.g. collinear cells), it falls back to nearest neighbour.
"""

from __future__ import annotations

import hashlib
from functools import partial
from math import comb
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.cache import Recent
from ltmstore.solve.masks import light_geometry, nearest_fill, per_view, solve_by_mask

if TYPE_CHECKING:
    from ltmstore.solve import Geometry

#: Kernels of :class:`~scipy.interpolate.RBFInterpolator` and their minimal polynomial degree.
KERNELS = {"linear": 0, "thin_plate_spline": 1, "cubic": 1, "quintic": 2, "multiquadric": 0,
           "inverse_multiquadric": -1, "inverse_quadratic": -1, "gaussian": -1}
SPACES = ("directions", "positions")


def interpolate(points: np.ndarray, sources: np.ndarray, values: np.ndarray,
                **params) -> np.ndarray:
    """RBF interpolation of ``values (K, g)`` at ``sources`` onto ``points``; nearest neighbour
    when there are too few sources for the polynomial tail or the system is singular."""
    from scipy.interpolate import RBFInterpolator  # imported here: 0.2 s

    degree = params.get("degree")
    degree = KERNELS[params["kernel"]] if degree is None else degree
    n_poly = comb(degree + sources.shape[1], degree) if degree >= 0 else 0
    if len(sources) > n_poly:
        try:
            return RBFInterpolator(sources, values, **params)(points)
        except np.linalg.LinAlgError:
            pass
    return nearest_fill(points, sources, values)


CACHED_OPERATORS = 8  # masks whose operator a process keeps (each M x K float32)
_OPERATORS = Recent(CACHED_OPERATORS)
_SPACINGS = Recent(CACHED_OPERATORS)  # lattices' spacings (a float each)


def _digest(points: np.ndarray) -> str:
    """A key of a set of points (the lattice's cells) for the caches above."""
    return hashlib.sha1(np.ascontiguousarray(points).tobytes()).hexdigest()


def _spacing(points: np.ndarray) -> float:
    """Median distance between neighbouring points (the natural RBF length scale), kept per
    set of points (every fold and tile of a capture interpolates over the same lattice)."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    key = _digest(points)
    found = _SPACINGS.get(key)
    if found is None:
        dist, _ = cKDTree(points).query(points, k=2)
        found = float(np.median(dist[:, 1])) or 1.0
        _SPACINGS.put(key, found)
    return found


def _solve_in(points: np.ndarray, samples: np.ndarray, params: dict,
              at: np.ndarray | None = None) -> np.ndarray:
    if params["epsilon"] is None:
        params = {**params, "epsilon": 1 / _spacing(points)}
    return solve_by_mask(samples, partial(_fit, points, params, at), at=at)


def _fit(points: np.ndarray, params: dict, at: np.ndarray | None, cells: np.ndarray,
         values: np.ndarray) -> np.ndarray:
    """The interpolant of ``values (K, g)`` at the observed ``cells`` onto ``points`` (its
    rows ``at`` only, where given): through the mask's :func:`operator` (cached: every tile of
    a handheld capture shares its mask, and each tile re-solved the same ``K x K`` system)
    where the batch is large enough to pay for building it (``g`` at least ``K / 2``), else
    solved directly."""
    if 2 * values.shape[1] >= values.shape[0]:  # by shape alone: the same call, the same path
        rows = operator(points, cells, params)
        return (rows if at is None else rows[at]) @ values.astype(np.float32)
    return interpolate(points if at is None else points[at], points[cells], values, **params)


def _key(points: np.ndarray, cells: np.ndarray, params: dict) -> tuple:
    return (_digest(points), hashlib.sha1(np.packbits(cells).tobytes()).hexdigest(), len(cells),
            tuple(sorted((k, repr(v)) for k, v in params.items())))


def operator(points: np.ndarray, cells: np.ndarray, params: dict, *,
             key: tuple | None = None) -> np.ndarray:
    """The linear map ``(len(points), K)`` (float32) from values at the observed ``cells``
    (a boolean mask over ``points``) to their interpolant at ``points`` (:func:`interpolate`
    of the identity: the interpolant is linear in the values), cached per mask."""
    key = _key(points, cells, params) if key is None else key
    found = _OPERATORS.get(key)
    if found is None:
        k = int(np.count_nonzero(cells))
        found = interpolate(points, points[cells], np.eye(k), **params).astype(np.float32)
        _OPERATORS.put(key, found)
    return found


def solve(samples: np.ndarray, geometry: Geometry, *, kernel: str = "thin_plate_spline",
          smoothing: float = 0.0, epsilon: float | None = None, degree: int | None = None,
          neighbors: int | None = None, space: str = "directions",
          at: np.ndarray | None = None) -> np.ndarray:
    """RBF-interpolate every LTF of a batch ``(n, *lattice)`` (NaN = unobserved).

    Parameters
    ----------
    kernel : str
        An :class:`~scipy.interpolate.RBFInterpolator` kernel (see :data:`KERNELS`).
    smoothing : float
        0 interpolates; larger values trade data fit for smoothness.
    epsilon : float or None
        Shape parameter; default the inverse of the median spacing between neighbouring cells
        (it matters only for the scale-dependent kernels, e.g. ``gaussian``).
    degree : int or None
        Degree of the polynomial tail; default the kernel's minimum (1 for the thin-plate spline).
    neighbors : int or None
        Use only this many nearest observed cells per evaluation point (for large K).
    space : {"directions", "positions"}
        Interpolate over the projected light directions ``(lu, lv)`` or over the cell centres.
    at : ndarray of int, optional
        Flat indices of the only cells wanted (a held-out fold's hidden cells:
        :func:`ltmstore.solve.validate.heldout_error`).

    Returns
    -------
    ndarray of float32, same shape as ``samples`` (``(n, len(at))`` with ``at``).
    """
    if kernel not in KERNELS:
        raise LtmError(f"rbf kernel {kernel!r} is unknown; expected one of {', '.join(KERNELS)}")
    if space not in SPACES:
        raise LtmError(f"rbf space {space!r} is unknown; expected one of {', '.join(SPACES)}")
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise LtmError(f"rbf smoothing {smoothing!r} must be a non-negative number")
    params = {"kernel": kernel, "smoothing": smoothing, "epsilon": epsilon, "degree": degree,
              "neighbors": neighbors}
    if space == "positions":
        return _solve_in(geometry.positions(), samples, params, at)
    if geometry.ndim == 2:  # one view
        return _solve_in(light_geometry(geometry).directions()[:, :2], samples, params, at)
    out = per_view(samples, geometry,
                   lambda rows, geom2d: _solve_in(geom2d.directions()[:, :2], rows, params))
    return out if at is None else out.reshape(len(out), -1)[:, at]
