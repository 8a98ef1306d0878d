"""Fast batched compressive sensing: iterative DCT thresholding with data consistency.

Solves the paper's problem (its eq. 4), ``min ||H t||_1`` subject to ``t = b`` on the observed
cells, for a whole tile of pixels at once. Each iteration is one forward and one inverse DCT of
the whole batch (fast transforms, no per-pixel Python) followed by a projection onto the data:

    f  <- soft(H t, lambda_k)        shrink the coefficients
    t  <- H^T f, then t[observed] = b    keep the data exactly

with a threshold that decays geometrically from the largest coefficient of each pixel to
``lam_min`` times it (continuation). This is projection onto convex sets with a decreasing
threshold (Abma and Kabir 2006); in the limit it reaches the basis-pursuit solution that LARS
finds pixel by pixel, at a small fraction of the cost. Masks may differ per pixel at no extra
cost: the projection is elementwise.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.operators import SensingOperator

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


class IterativeThresholding:
    """Step-wise solver over a batch of LTFs ``(n, *lattice)``; NaN marks unobserved cells.

    Parameters
    ----------
    samples : ndarray
        Binned observations, NaN where unobserved.
    ndim : int
        Number of lattice dimensions (trailing axes).
    n_iter : int
        Number of iterations (the threshold schedule spans exactly this many).
    lam_min : float
        Final threshold as a fraction of each pixel's largest coefficient.
    dtype : numpy dtype
        Working precision; float32 halves memory and time at no measurable accuracy cost.
    """

    def __init__(self, samples: np.ndarray, *, ndim: int = 2, n_iter: int = 100,
                 lam_min: float = 1e-3, dtype=np.float32, workers: int = 1) -> None:
        samples = np.asarray(samples, dtype=dtype)
        self.mask = np.isfinite(samples)
        self.data = np.where(self.mask, samples, 0).astype(dtype)
        self.op = SensingOperator(self.mask, ndim, workers=workers)
        self.n_iter = max(int(n_iter), 1)
        axes = tuple(range(-ndim, 0))
        lam0 = np.abs(self.op.adjoint(self.data)).max(axis=axes, keepdims=True)
        decay = lam_min ** (1.0 / max(self.n_iter - 1, 1))
        self.lam = lam0.astype(dtype)
        self.decay = dtype(decay)
        self.estimate = self.data.copy()
        self.iteration = 0
        self.change = np.inf

    def step(self) -> None:
        """One shrink-and-project iteration."""
        f = self.op.dct(self.estimate)
        f = np.sign(f) * np.maximum(np.abs(f) - self.lam, 0)
        new = self.op.idct(f)
        np.copyto(new, self.data, where=self.mask)
        scale = max(float(np.linalg.norm(new)), 1e-30)
        self.change = float(np.linalg.norm(new - self.estimate)) / scale
        self.estimate = new
        self.lam = self.lam * self.decay
        self.iteration += 1

    def run(self) -> np.ndarray:
        """Run all iterations and return the estimate."""
        while self.iteration < self.n_iter:
            self.step()
        return self.estimate


def solve(samples: np.ndarray, geometry: Geometry, *, n_iter: int = 100,
          lam_min: float = 1e-3, workers: int = 1) -> np.ndarray:
    """Reconstruct a batch of LTFs; see :class:`IterativeThresholding`.

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    solver = IterativeThresholding(samples, ndim=geometry.ndim, n_iter=n_iter, lam_min=lam_min,
                                   workers=workers)
    return solver.run().astype(np.float32, copy=False)
