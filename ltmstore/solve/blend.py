"""A convex blend of the sparse-DCT fit (``cs``) and the RBF interpolant (``rbf``).

The two fill a handheld path's holes in different ways: ``cs`` keeps a few DCT coefficients
(sharp, global structure), ``rbf`` a thin-plate spline through the observed cells (smooth, local).
Their errors are only partly correlated, so a weighted mean can beat both: on the simulated
handheld scenes of ``bench/auto_handheld.py`` the held-out choice of the weight gives up to
+0.5 dB over the better of the two. ``--method auto`` picks the weight per tile from held-out
cells (:func:`ltmstore.solve.select.choose_method`); ``weight=1`` is ``cs``, ``0`` is ``rbf``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve import cs, rbf

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def solve(samples: np.ndarray, geometry: Geometry, *, weight: float = 0.5) -> np.ndarray:
    """``weight * cs + (1 - weight) * rbf`` of a batch of LTFs (float32, same shape).

    Parameters
    ----------
    samples : ndarray, shape ``(n, *lattice)``
        Binned samples, NaN where unobserved.
    geometry : Geometry
    weight : float
        Weight of ``cs``, in [0, 1].
    """
    if not 0.0 <= weight <= 1.0:
        raise LtmError(f"blend weight {weight!r} must lie in [0, 1]")
    out = np.zeros(samples.shape, dtype=np.float32)
    if weight > 0:
        out += np.float32(weight) * cs.solve(samples, geometry)
    if weight < 1:
        out += np.float32(1 - weight) * rbf.solve(samples, geometry)
    return out
