"""Polynomial texture maps: a biquadratic in the projected light direction per pixel.

Malzbender, Gelb and Wolters, "Polynomial texture maps", SIGGRAPH 2001. Each LTF is fitted by
least squares with ``a0 lu^2 + a1 lv^2 + a2 lu lv + a3 lu + a4 lv + a5``, where ``(lu, lv)`` are
the first two components of the unit direction from the object centre to the light, then
evaluated at every cell. Pixels sharing a mask share one pseudo-inverse (see
:mod:`ltmstore.solve.basis`); a 6-D lattice gets one PTM per view ``(p, q)``.

Where it fails: six coefficients cannot hold specular highlights, hard shadows or the
inverse-square fall-off of a near light (the fit lives in direction space, not on the plane), so
it smooths them away (the paper's Section II); it approximates rather than interpolates the
observed cells. With fewer than six observed cells it returns the minimum-norm fit.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.solve.basis import fit_light_basis

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def ptm_basis(directions: np.ndarray) -> np.ndarray:
    """The six PTM terms ``(lu^2, lv^2, lu lv, lu, lv, 1)`` of unit directions ``(M, 3)``."""
    lu, lv = directions[:, 0], directions[:, 1]
    return np.column_stack([lu * lu, lv * lv, lu * lv, lu, lv, np.ones_like(lu)])


def solve(samples: np.ndarray, geometry: Geometry, *, rcond: float | None = None) -> np.ndarray:
    """Fit a PTM to every LTF of a batch ``(n, *lattice)`` (NaN = unobserved).

    Parameters
    ----------
    rcond : float or None
        Cut-off for small singular values of the design (:func:`numpy.linalg.lstsq`).

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    return fit_light_basis(samples, geometry, ptm_basis, rcond=rcond)
