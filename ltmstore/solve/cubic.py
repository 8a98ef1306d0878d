"""Scattered piecewise-cubic interpolation over the observed cell centres (Clough-Tocher).

The paper's "bicubic interpolation used in unstructured light fields" (its reference [19]),
realised as :class:`scipy.interpolate.CloughTocher2DInterpolator`: a C1 piecewise-cubic
interpolant on the Delaunay triangulation of the observed cell centres, with gradients estimated
by curvature minimisation. It reproduces affine functions exactly and keeps the observed cells.
Cells outside the convex hull of the observed ones take the value of the nearest observed cell.
Pixels sharing a mask share one triangulation and are interpolated together.

Where it fails: a sparse trajectory leaves long thin triangles and large unobserved regions, where
it invents hard, misplaced shadow edges (the paper's Fig. 11) and flat nearest-neighbour plateaus
outside the hull. Fewer than three observed cells, or collinear ones, fall back to nearest
neighbour. Only 2-D lattices ``(r, s)``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.masks import nearest_fill, solve_by_mask

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def interpolate(points: np.ndarray, sources: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Clough-Tocher interpolation of ``values (K, g)`` at ``sources`` onto ``points``.

    Points outside the convex hull of ``sources`` (or all points, when the sources cannot be
    triangulated) take their nearest source's value.
    """
    from scipy.interpolate import CloughTocher2DInterpolator  # imported here: 0.2 s
    from scipy.spatial import QhullError

    try:
        out = CloughTocher2DInterpolator(sources, values, fill_value=np.nan)(points)
    except QhullError:  # fewer than 3 points, or collinear: no triangulation
        out = np.full((len(points), values.shape[1]), np.nan)
    out = out.reshape(len(points), values.shape[1])
    outside = np.isnan(out).any(axis=1)
    if outside.any():
        out[outside] = nearest_fill(points[outside], sources, values)
    return out


def solve(samples: np.ndarray, geometry: Geometry) -> np.ndarray:
    """Interpolate every LTF of a batch ``(n, R, S)`` (NaN = unobserved).

    Returns
    -------
    ndarray of float32, same shape as ``samples``.

    Raises
    ------
    LtmError
        If the lattice is not 2-D.
    """
    if geometry.ndim != 2:
        raise LtmError(f"method 'cubic' needs a 2-D lattice (r, s); got shape {geometry.shape}")
    points = geometry.positions()
    return solve_by_mask(samples, lambda cells, values: interpolate(points, points[cells], values))
