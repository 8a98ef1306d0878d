"""Singular value thresholding: low-rank matrix completion of the tile's pixels x cells matrix.

Cai, Candes and Shen, "A singular value thresholding algorithm for matrix completion", SIAM J.
Optim. 20(4), 2010 (the paper's reference [28]). The tile is one matrix ``X (n, M)``, pixels by
cells, observed on ``Omega``; SVT approaches the minimum-nuclear-norm completion by the iteration

    X_k     = D_tau(Y_{k-1})                      shrink the singular values by tau
    Y_k     = Y_{k-1} + delta P_Omega(B - X_k)    gradient step on the dual, observed entries only

started from ``Y_0 = k_0 delta P_Omega(B)`` (the paper's "kicking") and stopped when the relative
residual on the observed entries falls below ``tol``. Only the singular triplets above ``tau``
are computed, with the paper's rank prediction (ARPACK through :func:`scipy.sparse.linalg.svds`,
or a dense SVD when that rank is not small). It uses the whole batch jointly: what is shared is
the low rank across pixels, not the mask, so per-pixel masks cost nothing extra. Rows with no
observed cell come out as zeros.

Where it fails: it needs observed entries spread over every row and column. A cell that no pixel
observes (every cell off the trajectory, when all pixels share one mask, which is the usual case)
is a column with no entry at all, which no completion can recover: those cells come out as zero
(the paper's Fig. 11: matrix completion "fails completely"). ``layout="lattice"`` instead
completes each LTF as its own ``R x S`` matrix (low rank over the lattice, one batched dense SVD of
all pixels per iteration), which works with a shared mask as long as every lattice row and column
holds an observed cell, but smooth-yet-not-separable LTFs (a round highlight) are not low rank.
On data that is not low rank, SVT with a large ``tau`` converges slowly: it may stop at
``max_iter`` with the observed cells fitted only to a few percent.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


#: Cap of the default step: the convergence guarantee holds for steps in (0, 2).
MAX_DEFAULT_STEP = 1.9


def top_svd(matrix: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``k`` largest singular triplets of a matrix, descending (ARPACK when ``k`` is small
    against the matrix, else a dense SVD)."""
    small = min(matrix.shape)
    if not matrix.any():  # all zero (a black video): ARPACK would refuse its zero start vector
        return np.zeros((matrix.shape[0], k)), np.zeros(k), np.zeros((k, matrix.shape[1]))
    if k < small // 4 and small > 32:
        from scipy.sparse.linalg import svds  # imported here: slow, rarely needed

        u, s, vt = svds(matrix, k=k, random_state=0)
        order = np.argsort(s)[::-1]
        return u[:, order], s[order], vt[order]
    u, s, vt = np.linalg.svd(matrix, full_matrices=False)
    return u[:, :k], s[:k], vt[:k]


def _norms(stack: np.ndarray) -> np.ndarray:
    """Frobenius norm of every matrix of a stack ``(B, a, b)``, shape ``(B, 1, 1)``."""
    return np.sqrt(np.einsum("bij,bij->b", stack, stack))[:, None, None]


class SingularValueThresholding:
    """Step-wise SVT over a stack of matrices ``data (B, a, b)`` observed where ``mask`` is True.

    Each matrix is completed on its own (its own ``tau``, ``delta`` and kick); a single large
    matrix (``B = 1``) uses partial SVDs with rank prediction, a stack of small ones one batched
    dense SVD per iteration.

    Parameters
    ----------
    data : ndarray
        Observations (anything where unobserved).
    mask : ndarray of bool
        Observed entries ``Omega``.
    tau : float or None
        Threshold; default ``5 sqrt(a' b')`` times the RMS of the observed entries of each matrix,
        where ``a' x b'`` counts the rows and columns that hold any observation.
    delta : float or None
        Step; default ``min(1.2 / p, 1.9)`` with ``p = |Omega| / (a' b')`` for each matrix. The
        paper's ``1.2 / p`` suits uniformly random entries; on trajectory masks it oscillates
        without converging, while any step in ``(0, 2)`` provably converges (the paper's
        convergence theorem).
    increment : int
        How many more singular values to ask for when the predicted rank was too small.
    """

    def __init__(self, data: np.ndarray, mask: np.ndarray, *, tau: float | None = None,
                 delta: float | None = None, increment: int = 5) -> None:
        self.mask = np.asarray(mask, dtype=bool)
        self.data = np.where(self.mask, data, 0.0)
        # rows and columns with no observation are zero in exact arithmetic: keep them so
        self.support = self.mask.any(axis=2, keepdims=True) & self.mask.any(axis=1, keepdims=True)
        size = self.support.sum(axis=(1, 2), keepdims=True)  # rows x columns that hold data
        observed = np.maximum(self.mask.sum(axis=(1, 2)), 1)[:, None, None]
        self.data_norm = _norms(self.data)
        rms = self.data_norm / np.sqrt(observed)
        self.tau = 5 * np.sqrt(size) * rms if tau is None else np.full_like(rms, tau)
        self.delta = (np.minimum(1.2 * size / observed, MAX_DEFAULT_STEP) if delta is None
                      else np.full_like(rms, delta))
        self.increment = max(int(increment), 1)
        spectral = np.array([top_svd(m, 1)[1][0] for m in self.data])[:, None, None]
        kick = np.ceil(self.tau / np.maximum(self.delta * spectral, 1e-300))
        self.dual = np.where(spectral > 0, kick, 0.0) * self.delta * self.data
        self.estimate = np.zeros_like(self.data)
        self.rank = 0
        self.residual = np.inf
        self.iteration = 0

    def _shrink_one(self, dual: np.ndarray, tau: float) -> np.ndarray:
        """``D_tau`` of one large matrix by partial SVDs (Cai, Candes and Shen, Section 5.1)."""
        kmax = min(dual.shape)
        k = min(self.rank + 1, kmax)
        while True:
            u, s, vt = top_svd(dual, k)
            if s[-1] <= tau or k == kmax:
                break
            k = min(k + self.increment, kmax)
        keep = s > tau
        self.rank = int(keep.sum())
        return (u[:, keep] * (s[keep] - tau)) @ vt[keep]

    def shrink(self) -> np.ndarray:
        """``D_tau(Y)``: singular values of each dual matrix above ``tau``, reduced by ``tau``."""
        if len(self.dual) == 1:
            return self._shrink_one(self.dual[0], float(self.tau[0, 0, 0]))[None]
        u, s, vt = np.linalg.svd(self.dual, full_matrices=False)
        s = np.maximum(s - self.tau[:, :, 0], 0)
        self.rank = int((s > 0).sum(axis=1).max())
        return np.matmul(u * s[:, None, :], vt)

    def step(self) -> None:
        """One shrinkage and one dual step."""
        self.estimate = self.shrink() * self.support
        misfit = np.where(self.mask, self.data - self.estimate, 0.0)
        relative = _norms(misfit) / np.maximum(self.data_norm, 1e-300)
        self.residual = float(relative.max())
        self.dual += self.delta * misfit
        self.iteration += 1

    def run(self, *, max_iter: int = 500, tol: float = 1e-4) -> np.ndarray:
        """Iterate until every relative residual on ``Omega`` is below ``tol``, or ``max_iter``."""
        while self.iteration < max_iter and self.residual > tol:
            self.step()
        return self.estimate


LAYOUTS = ("tile", "lattice")


def as_matrices(samples: np.ndarray, layout: str) -> np.ndarray:
    """The batch ``(n, *lattice)`` as a stack of matrices to complete.

    ``"tile"``: one matrix, pixels x cells ``(1, n, M)``. ``"lattice"``: every LTF on its own,
    rows the first lattice axis, columns the others ``(n, R, M / R)`` (for ``(r, s, p, q)`` the
    first two against the last two: ``(n, R S, P Q)``).
    """
    n, lattice = len(samples), samples.shape[1:]
    if layout == "tile":
        return samples.reshape(1, n, -1)
    rows = int(np.prod(lattice[: max(len(lattice) // 2, 1)]))
    return samples.reshape(n, rows, -1)


def solve(samples: np.ndarray, geometry: Geometry, *, tau: float | None = None,
          delta: float | None = None, max_iter: int = 500, tol: float = 1e-4,
          layout: str = "tile") -> np.ndarray:
    """Complete a batch ``(n, *lattice)`` (NaN = unobserved) by SVT.

    Parameters
    ----------
    tau, delta : float or None
        Threshold and step; see :class:`SingularValueThresholding`.
    max_iter : int
        Iteration cap.
    tol : float
        Stop when every matrix's relative residual on its observed entries is below this.
    layout : {"tile", "lattice"}
        Which matrices are low rank (see :func:`as_matrices`): the tile's pixels x cells
        (default; needs every cell observed by some pixel) or each LTF on its ``R x S`` lattice
        (works with a shared mask; needs every lattice row and column observed).

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    for name, value in (("tau", tau), ("delta", delta)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise LtmError(f"svt {name} {value!r} must be a positive number")
    if layout not in LAYOUTS:
        raise LtmError(f"svt layout {layout!r} is unknown; expected one of {', '.join(LAYOUTS)}")
    samples = np.asarray(samples, dtype=np.float64)
    matrices = as_matrices(samples, layout)
    mask = np.isfinite(matrices)
    if not mask.any():
        return np.zeros(samples.shape, dtype=np.float32)
    solver = SingularValueThresholding(matrices, mask, tau=tau, delta=delta)
    return solver.run(max_iter=max_iter, tol=tol).reshape(samples.shape).astype(np.float32)
