"""Least-squares fits in a small basis of light-direction functions (PTM, HSH).

Per view and per mask group the observed rows of the basis matrix are pseudo-inverted once
(LAPACK ``gelsd`` with all pixels of the group as right-hand sides), then the coefficients are
evaluated at every cell. With fewer observations than basis functions, or a rank-deficient
design, the minimum-norm least-squares solution is returned.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.solve.masks import per_view, solve_by_mask

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def fit_light_basis(samples: np.ndarray, geometry: Geometry,
                    make_basis: Callable[[np.ndarray], np.ndarray], *,
                    rcond: float | None = None) -> np.ndarray:
    """Fit ``make_basis(directions) -> (M, B)`` to every LTF by least squares.

    Parameters
    ----------
    samples : ndarray, shape ``(n, R, S[, P, Q])``
        Binned LTFs, NaN where unobserved.
    geometry : Geometry
        Lattice and plane height; directions come from the light axes ``(r, s)``.
    make_basis : callable
        Unit light directions ``(M, 3)`` to basis values ``(M, B)``.
    rcond : float or None
        Cut-off for small singular values, as in :func:`numpy.linalg.lstsq`.

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """

    def solve2d(rows: np.ndarray, geometry2d: Geometry) -> np.ndarray:
        basis = make_basis(geometry2d.directions())

        def fit(cells: np.ndarray, values: np.ndarray) -> np.ndarray:
            coef, *_ = np.linalg.lstsq(basis[cells], values, rcond=rcond)
            return basis @ coef

        return solve_by_mask(rows, fit)

    return per_view(samples, geometry, solve2d)
