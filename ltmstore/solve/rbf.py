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

from math import comb
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.masks import nearest_fill, per_view, solve_by_mask

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


def _spacing(points: np.ndarray) -> float:
    """Median distance between neighbouring points (the natural RBF length scale)."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    dist, _ = cKDTree(points).query(points, k=2)
    return float(np.median(dist[:, 1])) or 1.0


def _solve_in(points: np.ndarray, samples: np.ndarray, params: dict) -> np.ndarray:
    if params["epsilon"] is None:
        params = {**params, "epsilon": 1 / _spacing(points)}
    return solve_by_mask(
        samples, lambda cells, values: interpolate(points, points[cells], values, **params)
    )


def solve(samples: np.ndarray, geometry: Geometry, *, kernel: str = "thin_plate_spline",
          smoothing: float = 0.0, epsilon: float | None = None, degree: int | None = None,
          neighbors: int | None = None, space: str = "directions") -> np.ndarray:
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

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
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
        return _solve_in(geometry.positions(), samples, params)
    return per_view(samples, geometry,
                    lambda rows, geom2d: _solve_in(geom2d.directions()[:, :2], rows, params))
