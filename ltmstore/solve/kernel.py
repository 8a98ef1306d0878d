"""Classic kernel regression over the cell centres (Nadaraya-Watson or local polynomial).

Takeda, Farsiu and Milanfar, "Kernel regression for image processing and reconstruction",
IEEE TIP 16(2), 2007 (the paper's reference [27]), in its classic (non-adaptive) form: at every
cell ``x`` the LTF value is the constant term of a weighted least-squares polynomial fit of order
0, 1 or 2 to the observed cells ``x_i``, with Gaussian weights ``exp(-|x_i - x|^2 / (2 h^2))``
and ``h`` in cell units. The estimate is linear in the data, ``t = W b``: the equivalent-kernel
matrix ``W (M, K)`` is built once per mask (batched small solves over all cells) and applied to
all pixels of the group as one matrix product. Any number of lattice dimensions.

Where it fails: it smooths rather than interpolates, so shadow edges and highlights narrower than
the bandwidth are blurred or ringed (the paper's Fig. 11), and far from any observed cell (gaps of
a sparse trajectory wider than a few bandwidths) a local polynomial becomes an extrapolation from
a one-sided cluster that overshoots. The fit drops order (2 to 1 to 0) where its normal matrix
is ill-conditioned (``rcond``), which tames the worst of it but not all: near the crossing of two
trajectory strokes a well-conditioned quadratic can still overshoot the data range. Order 0
(Nadaraya-Watson, close to nearest neighbour in gaps) has weights normalised to the nearest
observed cell so that they never underflow. Memory is ``O(M K P)`` per mask (``P`` polynomial
terms): fine for ``(r, s)`` lattices, not for large 6-D ones.
"""

from __future__ import annotations

from itertools import combinations_with_replacement
from math import comb
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.masks import solve_by_mask

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def design(u: np.ndarray, order: int) -> np.ndarray:
    """Polynomial terms up to ``order`` of offsets ``u (..., d)``: ``(..., P)``, constant first."""
    terms = [np.ones(u.shape[:-1])]
    for degree in range(1, order + 1):
        for idx in combinations_with_replacement(range(u.shape[-1]), degree):
            terms.append(np.prod(u[..., list(idx)], axis=-1))
    return np.stack(terms, axis=-1)


def equivalent_kernel(points: np.ndarray, sources: np.ndarray, *, order: int = 2,
                      bandwidth: float = 1.5, rcond: float = 1e-3) -> np.ndarray:
    """The matrix ``W (M, K)`` with ``estimate(points) = W @ values(sources)``.

    Parameters
    ----------
    points, sources : ndarray, shapes ``(M, d)`` and ``(K, d)``
        Target and observed positions, in the units of ``bandwidth``.
    order : {0, 1, 2}
        Order of the local polynomial.
    bandwidth : float
        Standard deviation ``h`` of the Gaussian kernel.
    rcond : float
        A local fit whose Jacobi-scaled normal matrix has a smaller eigenvalue ratio (too few
        or too one-sided observed cells: an extrapolation) drops to the next lower order.
    """
    offsets = (sources[None, :, :] - points[:, None, :]) / bandwidth  # (M, K, d)
    d2 = np.einsum("mkd,mkd->mk", offsets, offsets)
    weights = np.exp(-0.5 * (d2 - d2.min(axis=1, keepdims=True)))  # nearest source: weight 1
    kernel = weights / weights.sum(axis=1, keepdims=True)  # order 0: Nadaraya-Watson
    if order == 0:
        return kernel
    phi = design(offsets, order)  # (M, K, P), terms sorted by degree
    weighted = phi * weights[..., None]
    normal = np.matmul(weighted.transpose(0, 2, 1), phi)  # (M, P, P)
    pending = np.ones(len(points), dtype=bool)
    for degree in range(order, 0, -1):
        terms = comb(degree + sources.shape[1], degree)  # leading block: terms up to degree
        rows = np.flatnonzero(pending)
        ok = _well_conditioned(normal[rows, :terms, :terms], rcond)
        rows = rows[ok]
        if len(rows):
            e1 = np.zeros((len(rows), terms, 1))
            e1[:, 0] = 1
            z = np.linalg.solve(normal[rows, :terms, :terms], e1)[..., 0]  # first row of inverse
            kernel[rows] = np.einsum("mp,mkp->mk", z, weighted[rows, :, :terms])
            pending[rows] = False
    return kernel


def _well_conditioned(normal: np.ndarray, rcond: float) -> np.ndarray:
    """Which symmetric matrices of a stack ``(m, P, P)`` have ``min eig > rcond max eig``
    after Jacobi scaling."""
    scale = 1 / np.sqrt(np.maximum(np.einsum("mpp->mp", normal), 1e-300))
    eig = np.linalg.eigvalsh(normal * scale[:, :, None] * scale[:, None, :])
    return eig[:, 0] > rcond * eig[:, -1]


def solve(samples: np.ndarray, geometry: Geometry, *, order: int = 2, bandwidth: float = 1.5,
          rcond: float = 1e-3) -> np.ndarray:
    """Kernel regression of every LTF of a batch ``(n, *lattice)`` (NaN = unobserved).

    Parameters
    ----------
    order : {0, 1, 2}
        Local polynomial order: 0 is Nadaraya-Watson, 2 Takeda's classic second order.
    bandwidth : float
        Gaussian kernel width in lattice cells.
    rcond : float
        See :func:`equivalent_kernel`.

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    if order not in (0, 1, 2):
        raise LtmError(f"kernel order {order!r} must be 0, 1 or 2")
    if not (np.isfinite(bandwidth) and bandwidth > 0):
        raise LtmError(f"kernel bandwidth {bandwidth!r} must be a positive number of cells")
    points = geometry.positions() / np.asarray(geometry.lattice.deltas)  # cell units

    def fit(cells: np.ndarray, values: np.ndarray) -> np.ndarray:
        kernel = equivalent_kernel(points, points[cells], order=order, bandwidth=bandwidth,
                                   rcond=rcond)
        return kernel @ values

    return solve_by_mask(samples, fit)
