"""Orthogonal matching pursuit in the orthonormal DCT dictionary (greedy sparse recovery).

Pati, Rezaiifar and Krishnaprasad 1993; Tropp and Gilbert, "Signal recovery from random
measurements via orthogonal matching pursuit", IEEE TIT 53(12), 2007. The same model as
:mod:`~ltmstore.solve.lars` (an LTF sparse in the DCT domain, ``t = H^T f``), but the support is
grown greedily: pick the atom most correlated with the residual, refit all chosen atoms by least
squares, repeat. Atoms are the rows of ``H^T`` at the observed cells, normalised to unit norm.
Pixels sharing a mask share the Gram matrix, so scikit-learn's
:func:`~sklearn.linear_model.orthogonal_mp_gram` runs once per mask with every pixel of the group
as a right-hand side (its inner loop over pixels is scikit-learn's own).

Where it fails: greedy selection has no l1 guarantee on structured (trajectory) masks, where
restricted DCT atoms are strongly coherent; a wrong early atom is never removed, so it needs more
cells than basis pursuit for the same sparsity, and with too many atoms it overfits noise in the
observed cells. The dense ``M x M`` Gram matrix limits it to ``(r, s)`` lattices (not 6-D).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.core.operators import SensingOperator
from ltmstore.solve.masks import solve_by_mask

if TYPE_CHECKING:
    from ltmstore.solve import Geometry


def sparse_code(atoms: np.ndarray, values: np.ndarray, *, n_nonzero_coefs: int | None = None,
                tol: float | None = None) -> np.ndarray:
    """OMP coefficients ``(A, g)`` of ``values (K, g)`` over ``atoms (K, A)`` (any column norms).

    Parameters
    ----------
    n_nonzero_coefs : int or None
        Atoms per pixel; default ``K // 4``. Capped at ``K`` and at the usable atoms.
    tol : float or None
        If given, stop each pixel when ``||residual|| <= tol * ||values||`` (overrides
        ``n_nonzero_coefs``).
    """
    from sklearn.linear_model import orthogonal_mp_gram  # imported here: slow, rarely needed

    norms = np.linalg.norm(atoms, axis=0)
    usable = norms > 1e-8 * norms.max(initial=0)
    coef = np.zeros((atoms.shape[1], values.shape[1]))
    scale = np.linalg.norm(values, axis=0)
    live = scale > 0
    if not usable.any() or not live.any():
        return coef
    dictionary = atoms[:, usable] / norms[usable]
    rhs = values[:, live] / scale[live]  # unit columns: one absolute tol is a relative one
    n_atoms = min(n_nonzero_coefs or max(len(atoms) // 4, 1), len(atoms), int(usable.sum()))
    kwargs = ({"n_nonzero_coefs": n_atoms} if tol is None
              else {"tol": tol**2, "norms_squared": np.ones(rhs.shape[1])})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "ended prematurely": residual is 0
        code = orthogonal_mp_gram(dictionary.T @ dictionary, dictionary.T @ rhs,
                                  copy_Xy=False, **kwargs)
    code = np.reshape(code, (int(usable.sum()), rhs.shape[1]))
    coef[np.ix_(usable, live)] = code / norms[usable, None] * scale[live]
    return coef


def solve(samples: np.ndarray, geometry: Geometry, *, n_nonzero_coefs: int | None = None,
          tol: float | None = None) -> np.ndarray:
    """Recover every LTF of a batch ``(n, *lattice)`` (NaN = unobserved) by OMP.

    Parameters
    ----------
    n_nonzero_coefs : int or None
        DCT coefficients per pixel; default a quarter of the observed cells.
    tol : float or None
        Relative residual on the observed cells at which to stop; overrides
        ``n_nonzero_coefs``.

    Returns
    -------
    ndarray of float32, same shape as ``samples``.
    """
    if n_nonzero_coefs is not None and (int(n_nonzero_coefs) != n_nonzero_coefs
                                        or n_nonzero_coefs < 1):
        raise LtmError(f"omp n_nonzero_coefs {n_nonzero_coefs!r} must be a positive integer")
    if tol is not None and not (np.isfinite(tol) and tol >= 0):
        raise LtmError(f"omp tol {tol!r} must be a non-negative number")
    lattice = geometry.shape
    synthesis = SensingOperator(np.ones(lattice, bool), geometry.ndim).matrix(lattice)  # H^T

    def fit(cells: np.ndarray, values: np.ndarray) -> np.ndarray:
        coef = sparse_code(synthesis[cells], values, n_nonzero_coefs=n_nonzero_coefs, tol=tol)
        return synthesis @ coef

    return solve_by_mask(samples, fit)
