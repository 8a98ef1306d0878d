"""Fast batched compressive sensing: accelerated DCT thresholding with data consistency.

Solves the paper's problem (its eq. 4), ``min ||H t||_1`` subject to ``t = b`` on the observed
cells, for a whole tile of pixels at once. Each iteration is one forward and one inverse DCT of
the whole batch (fast transforms, no per-pixel Python), a shrinkage and a projection onto the
data, with Nesterov/FISTA extrapolation between iterates:

    f  <- soft(H z, lambda_k)            shrink the coefficients
    t  <- H^T f, then t[observed] = b    keep the data exactly
    z  <- t + beta_k (t - t_previous)    extrapolate (FISTA momentum)

The threshold decays geometrically from each pixel's largest coefficient to ``lam_min`` times
it (continuation). Without momentum this is projection onto convex sets with a decreasing
threshold (Abma and Kabir 2006); the momentum ("fast POCS", Yang et al. 2012) reaches the same
accuracy in about a third of the iterations. In the limit it is the basis-pursuit solution that
LARS finds pixel by pixel. Masks may differ per pixel at no extra cost: the projection is
elementwise. Float32 throughout: the same SNR as float64 to 0.01 dB, half the memory traffic.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.operators import SensingOperator

if TYPE_CHECKING:
    from ltmstore.solve import Geometry

N_ITER = 30  # with momentum: within 0.2 dB of 100 plain iterations on the simulated scenes
# Candidates of the final threshold for the per-tile choice (ltmstore.solve.select).
AUTO_GRID = {"lam_min": (3e-3, 1e-3, 3e-4)}


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
    momentum : bool
        FISTA extrapolation between iterates.
    dtype : numpy dtype
        Working precision.
    """

    def __init__(self, samples: np.ndarray, *, ndim: int = 2, n_iter: int = N_ITER,
                 lam_min: float = 1e-3, momentum: bool = True, dtype=np.float32,
                 workers: int = 1) -> None:
        samples = np.asarray(samples, dtype=dtype)
        self.mask = np.isfinite(samples)
        self.data = np.where(self.mask, samples, 0).astype(dtype)
        # the projection writes the observations by flat index: 15x faster than a masked copy
        self._observed = np.flatnonzero(self.mask)
        self._observations = self.data.reshape(-1)[self._observed]
        self.op = SensingOperator(self.mask, ndim, workers=workers)
        self.n_iter = max(int(n_iter), 1)
        self.momentum = momentum
        axes = tuple(range(-ndim, 0))
        self.lam = np.abs(self.op.adjoint(self.data)).max(axis=axes, keepdims=True)
        self.decay = dtype(lam_min ** (1.0 / max(self.n_iter - 1, 1)))
        self.estimate = self.data.copy()
        self._z = self.data.copy()
        self._buf = np.empty_like(self.data)
        self._t = 1.0
        self.iteration = 0
        self.change = np.inf

    def step(self) -> None:
        """One shrink, project and extrapolate iteration."""
        f = self.op.dct(self._z)
        shrunk = np.abs(f, out=self._buf)
        shrunk -= self.lam
        np.maximum(shrunk, 0, out=shrunk)
        np.copysign(shrunk, f, out=shrunk)
        new = self.op.idct(shrunk)
        np.put(new, self._observed, self._observations)
        np.subtract(new, self.estimate, out=self._z)  # the step, reused for z below
        self.change = float(np.linalg.norm(self._z)) / max(float(np.linalg.norm(new)), 1e-30)
        t_next = (1 + np.sqrt(1 + 4 * self._t**2)) / 2
        self._z *= (self._t - 1) / t_next if self.momentum else 0
        self._z += new
        self._t = t_next
        self.estimate = new
        self.lam *= self.decay
        self.iteration += 1

    def run(self) -> np.ndarray:
        """Run all iterations and return the estimate."""
        while self.iteration < self.n_iter:
            self.step()
        return self.estimate


def solve(samples: np.ndarray, geometry: Geometry, *, n_iter: int = N_ITER,
          lam_min: float = 1e-3, momentum: bool = True, workers: int = 1) -> np.ndarray:
    """Reconstruct a batch of LTFs; see :class:`IterativeThresholding`.

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    solver = IterativeThresholding(samples, ndim=geometry.ndim, n_iter=n_iter, lam_min=lam_min,
                                   momentum=momentum, workers=workers)
    return solver.run().astype(np.float32, copy=False)
