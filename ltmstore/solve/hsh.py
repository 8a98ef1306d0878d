"""Hemispherical harmonics: a low-order orthonormal basis on the hemisphere of light directions.

Gautron, Krivanek, Pattanaik and Bouatouch, "A novel hemispherical basis for accurate and
efficient rendering", EGSR 2004. The basis of order ``L`` holds ``(L + 1)^2`` functions::

    H_l^m(theta, phi) = K_l^m P_l^|m|(2 cos theta - 1) {sqrt(2) cos(m phi), 1, sqrt(2) sin(|m| phi)}

for ``m > 0``, ``m = 0``, ``m < 0`` (shifted associated Legendre functions), with ``theta, phi``
the polar and azimuthal angles of the unit light direction. Each LTF is fitted by least squares
over its observed cells and evaluated at every cell; pixels sharing a mask share one
pseudo-inverse, and a 6-D lattice gets one fit per view ``(p, q)``.

Where it fails: like PTM it is a global low-order fit, so it blurs highlights and shadow edges,
and lights on a plane cover only a cap of the hemisphere (at most ~55 degrees from the zenith
for a plane as wide as it is high), where higher orders become ill-conditioned and extrapolate
wildly into unobserved corners. With fewer observed cells than basis functions it returns the
minimum-norm fit.
"""

from __future__ import annotations

from math import factorial, pi, prod, sqrt
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.basis import fit_light_basis

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def hsh_basis(directions: np.ndarray, order: int = 3) -> np.ndarray:
    """The ``(order + 1)^2`` HSH functions at unit directions ``(M, 3)``, shape ``(M, B)``."""
    if int(order) != order or order < 0:
        raise LtmError(f"hsh order {order!r} must be a non-negative integer (2 or 3 usual)")
    x = 2 * np.clip(directions[:, 2], -1.0, 1.0) - 1
    phi = np.arctan2(directions[:, 1], directions[:, 0])
    columns = []
    for l in range(int(order) + 1):  # noqa: E741 (the usual name of the degree)
        for m in range(-l, l + 1):
            k = sqrt((2 * l + 1) * factorial(l - abs(m)) / (2 * pi * factorial(l + abs(m))))
            radial = k * legendre(abs(m), l, x)
            if m > 0:
                columns.append(sqrt(2) * np.cos(m * phi) * radial)
            elif m < 0:
                columns.append(sqrt(2) * np.sin(-m * phi) * radial)
            else:
                columns.append(radial)
    return np.column_stack(columns)


def legendre(m: int, l: int, x: np.ndarray) -> np.ndarray:  # noqa: E741
    """The associated Legendre function ``P_l^m(x)`` for integers ``0 <= m <= l``, with the
    Condon-Shortley phase (as :func:`scipy.special.lpmv`, to 1e-12), by the upward recurrence
    in ``l``: NumPy alone, so that fitting and relighting classic captures need not import
    SciPy's special functions."""
    p = np.full_like(x, (-1.0) ** m * prod(range(1, 2 * m, 2)), dtype=np.float64)
    if m:
        p = p * ((1 - x) * (1 + x)) ** (m / 2)
    if l == m:
        return p
    previous, p = p, (2 * m + 1) * x * p
    for k in range(m + 2, l + 1):
        previous, p = p, ((2 * k - 1) * x * p - (k + m - 1) * previous) / (k - m)
    return p


def solve(samples: np.ndarray, geometry: Geometry, *, order: int = 3,
          rcond: float | None = None) -> np.ndarray:
    """Fit HSH of ``order`` (2: 9 functions, 3: 16) to every LTF of a batch (NaN = unobserved).

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    hsh_basis(np.array([[0.0, 0.0, 1.0]]), order)  # validate before any work

    def make_basis(directions: np.ndarray) -> np.ndarray:
        return hsh_basis(directions, order)

    return fit_light_basis(samples, geometry, make_basis, rcond=rcond)
