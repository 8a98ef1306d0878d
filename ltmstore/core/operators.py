"""The sensing operator of the per-pixel compressive-sensing problem.

A light transport function ``t`` lives on a lattice of shape ``(R, S[, P, Q])``; its orthonormal
DCT-II coefficients are ``f = H t``. Only the cells in ``mask`` were observed, so the operator
maps coefficients to observations: ``A f = mask * H^T f``. Measurements are kept on the full
lattice with zeros where unobserved, which makes per-pixel masks cost nothing extra. Every method
takes a batch: arrays of shape ``(n, *lattice)``, one row per pixel.
"""

from __future__ import annotations

import numpy as np
import scipy.fft


class SensingOperator:
    """``A = restriction(mask) . inverse DCT`` over the trailing lattice axes of a batch.

    Parameters
    ----------
    mask : ndarray of bool
        Observed cells: shape ``lattice`` (shared by all pixels) or ``(n, *lattice)``.
    ndim : int
        Number of lattice dimensions (2 for ``(r, s)``, 4 for ``(r, s, p, q)``).
    workers : int
        Threads for :mod:`scipy.fft`.
    """

    def __init__(self, mask: np.ndarray, ndim: int = 2, *, workers: int = 1) -> None:
        self.mask = np.asarray(mask, dtype=bool)
        self.axes = tuple(range(-ndim, 0))
        self.workers = workers

    def dct(self, t: np.ndarray) -> np.ndarray:
        """Orthonormal n-D DCT-II over the lattice axes: ``H t``."""
        return scipy.fft.dctn(t, type=2, norm="ortho", axes=self.axes, workers=self.workers)

    def idct(self, f: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`dct`: ``H^T f``."""
        return scipy.fft.idctn(f, type=2, norm="ortho", axes=self.axes, workers=self.workers)

    def forward(self, f: np.ndarray) -> np.ndarray:
        """``A f``: observed cells of the LTF with coefficients ``f`` (zeros elsewhere)."""
        return self.idct(f) * self.mask

    def adjoint(self, b: np.ndarray) -> np.ndarray:
        """``A^T b``: coefficients of the zero-filled observations."""
        return self.dct(b * self.mask)

    def matrix(self, lattice: tuple[int, ...]) -> np.ndarray:
        """Dense inverse-DCT matrix ``H^T`` of shape ``(M, M)`` (rows: cells in C order)."""
        eye = np.eye(int(np.prod(lattice))).reshape(-1, *lattice)
        return self.idct(eye).reshape(len(eye), -1).T


def dot_test(op: SensingOperator, shape: tuple[int, ...], *, seed: int = 0) -> float:
    """Relative mismatch of ``<A f, b>`` and ``<f, A^T b>`` for random ``f``, ``b``."""
    rng = np.random.default_rng(seed)
    f, b = rng.standard_normal(shape), rng.standard_normal(shape)
    lhs, rhs = np.vdot(op.forward(f), b), np.vdot(f, op.adjoint(b))
    return abs(lhs - rhs) / max(abs(lhs), abs(rhs), 1e-300)
