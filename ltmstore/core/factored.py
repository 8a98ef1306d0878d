"""The factored stored form of an LTM: per pixel tile, a shared basis over the lattice cells
and per-pixel weights (``ltm compact --form factored``).

Each tile of ``tile x tile`` pixels holds its LTFs as the rows of a matrix ``A`` (pixels by
cells); its truncated SVD ``A ~ U_k (S_k V_k)`` keeps the smallest rank ``k`` whose left-out
energy is within a budget: by default :func:`heldout_budget`, a fraction of the model's own
held-out error in that tile (the rank the data supports, no more), or :func:`target_budget`,
``10**(-target/10)`` of the tile's energy (every tile keeps ``target`` dB against the dense
LTM). Stored, for an LTM variable ``name``:

* ``{name}_weights`` ``(y, x, rank)``: ``U_k`` of the pixel's tile, zero beyond its rank;
* ``{name}_basis`` ``(factor_tile_y, factor_tile_x, rank, r, s)``: ``S_k V_k`` of each tile.

(``rank`` is ``rank_cb``, ``rank_cr`` for the colour LTM's ``ltm_cb``, ``ltm_cr``: each
variable has its own largest rank.)

:func:`derived` presents ``T[y, x, r, s] = sum_k W[y, x, k] B[y // tile, x // tile, k, r, s]``
lazily (Dask), chunked like the dense LTM or light-major (one cell per chunk): relighting one
point light then computes ``W (B l)`` for its cells only, reading the weights and a small part
of the basis.
"""

from __future__ import annotations

import numpy as np

WEIGHTS, BASIS = "_weights", "_basis"
TILE_WEIGHTS, TILE_BASIS = "_tile_weights", "_tile_basis"  # staged by ltm reconstruct
TILE_DIMS = ("factor_tile_y", "factor_tile_x")
DEFAULT_TILE = 32
HELDOUT_FRACTION = 0.3  # the factors' error against the model's held-out error, at most
MAX_DB = 60.0  # no tile is kept closer than this to its dense LTM (float16 rounds at ~70 dB)
BLOCK_TILES = 16  # tiles per side of one stored chunk of weights (512 x 512 pixels)


def weights_name(name: str) -> str:
    """The weights variable of the LTM variable ``name``."""
    return f"{name}{WEIGHTS}"


def basis_name(name: str) -> str:
    """The basis variable of the LTM variable ``name``."""
    return f"{name}{BASIS}"


def rank_dim(name: str) -> str:
    """The rank dimension of the factors of the LTM variable ``name``."""
    return "rank" + name.removeprefix("ltm")


def factor_tile(values: np.ndarray, allowed: float) -> tuple[np.ndarray, np.ndarray]:
    """Truncated SVD of one tile's LTFs, at the smallest rank whose left-out energy (sum of
    squares) is at most ``allowed``.

    First a randomised range finder (:func:`_sketch`: 64 directions, one power iteration,
    about a quarter of the time), which serves wherever its subspace meets the budget at a
    rank its oversampling leaves well found; else the exact top of the spectrum from the
    tile's smaller Gram matrix (``A A^T`` of its pixels, or ``A^T A`` of its cells: one BLAS
    product and a symmetric eigensolver). Either way the left-out energy is that of the
    factors returned, not an estimate.

    Parameters
    ----------
    values : ndarray
        ``(h, w, *cells)`` the tile's LTM, finite.
    allowed : float
        The most energy the rank-``k`` product may leave out (:func:`target_budget`,
        :func:`heldout_budget`); floored at ``MAX_DB`` below the tile's energy.

    Returns
    -------
    weights : ndarray
        ``(h, w, k)`` float64, orthonormal columns.
    basis : ndarray
        ``(k, *cells)`` float64.
    """
    h, w, *cells = values.shape
    a = values.reshape(h * w, -1).astype(np.float64)  # float32's Gram misses 50 dB by 1-2 dB
    total = float(np.sum(a ** 2))
    allowed = max(allowed, total * 10 ** (-MAX_DB / 10))
    u, basis = _sketch(a, total, allowed) or _exact(a, total, allowed)
    return u.reshape(h, w, -1), basis.reshape(-1, *cells)


SKETCH, OVERSAMPLE = 64, 16  # directions of the range finder; those kept beyond the rank


def _sketch(a: np.ndarray, total: float, allowed: float) -> tuple | None:
    """``U_k, S_k V_k^T`` from a randomised range finder with one power iteration (Halko,
    Martinsson and Tropp 2011; a fixed seed: the same tile, the same factors), or None where
    the tile is too small for it or its subspace needs more than ``SKETCH - OVERSAMPLE``
    directions to meet ``allowed``."""
    if 2 * SKETCH > min(a.shape):
        return None
    y = a @ np.random.default_rng(0).standard_normal((a.shape[1], SKETCH))
    y = a @ (a.T @ np.linalg.qr(y)[0])
    q = np.linalg.qr(y)[0]
    small, s, vt = np.linalg.svd(q.T @ a, full_matrices=False)
    reachable = (total - np.cumsum(s ** 2) <= allowed)[: SKETCH - OVERSAMPLE]
    if not reachable.any():
        return None
    k = int(np.argmax(reachable)) + 1
    return q @ small[:, :k], s[:k, None] * vt[:k]


def _exact(a: np.ndarray, total: float, allowed: float) -> tuple[np.ndarray, np.ndarray]:
    """``U_k, S_k V_k^T`` from the top eigenpairs of the smaller Gram matrix."""
    pixels_side = a.shape[0] <= a.shape[1]
    gram = a @ a.T if pixels_side else a.T @ a
    lam, vec = _top_eigen(gram, lambda lam: total - np.cumsum(lam) <= allowed)
    reachable = total - np.cumsum(lam) <= allowed  # left-out energy at rank 1, 2, ...
    k = int(np.argmax(reachable)) + 1 if reachable.any() else len(lam)
    if pixels_side:  # A ~ U_k (U_k^T A)
        u = vec[:, :k]
        return u, u.T @ a
    v = vec[:, :k]  # A ~ (A V_k) V_k^T, A V_k = U_k S_k made orthonormal
    s = np.sqrt(lam[:k])
    return (a @ v) / np.where(s > 0, s, 1), s[:, None] * v.T


def _top_eigen(gram: np.ndarray, enough, first: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The largest eigenvalues (float64, descending, clipped at 0) and their eigenvectors of the
    symmetric ``gram``: the top ``first`` when ``enough(eigenvalues)`` holds somewhere among
    them (LAPACK's ``syevr`` on a subset: the top 64 of a 1024 x 1024 Gram matrix in 0.29 s
    against 0.56 s for all, on a loaded machine), else all of them."""
    from scipy.linalg import eigh

    n = len(gram)
    if 2 * first <= n:
        lam, vec = eigh(gram, subset_by_index=[n - first, n - 1], driver="evr")
        lam, vec = np.clip(lam[::-1], 0, None), vec[:, ::-1]
        if enough(lam).any():
            return lam, vec
    lam, vec = np.linalg.eigh(gram)
    return np.clip(lam[::-1], 0, None), vec[:, ::-1]


def target_budget(values: np.ndarray, target_db: float) -> float:
    """The left-out energy that keeps ``target_db`` of SNR against ``values``."""
    return float(np.sum(np.asarray(values, np.float64) ** 2)) * 10 ** (-target_db / 10)


def heldout_budget(heldout_rms: np.ndarray, cells: int,
                   fraction: float = HELDOUT_FRACTION) -> float:
    """The left-out energy of a tile whose factors may miss by ``fraction`` of its model's
    held-out error: ``fraction**2`` times the energy of an error of the pixels' held-out RMS
    (``heldout_rms``, NaN: none, counts nothing) in each of ``cells`` cells.

    The truncation then adds at most ``fraction**2`` (9 % at 0.3, 0.4 dB) to the error the
    model already makes where it can be checked, and discards what lies below it: mostly the
    solver's noise (at the Toys size the factors relight 0.4 dB nearer the truth than the
    dense LTM, `bench/factored_bench.py`).
    """
    rms = np.nan_to_num(np.asarray(heldout_rms, np.float64), nan=0.0, posinf=0.0)
    return fraction ** 2 * float(np.sum(rms ** 2)) * cells


def _product(weights: np.ndarray, basis: np.ndarray, tile: int) -> np.ndarray:
    """One block of the derived LTM: ``weights (h, w, k)`` of whole tiles (the last ones may be
    cut) and their ``basis (ty, tx, k, *cells)``."""
    h, w, _ = weights.shape
    ty, tx, _, *cells = basis.shape
    out = np.empty((h, w, *cells), np.float32)
    for i in range(ty):
        for j in range(tx):
            part = weights[i * tile:(i + 1) * tile, j * tile:(j + 1) * tile]
            b = basis[i, j].reshape(basis.shape[2], -1)
            out[i * tile:(i + 1) * tile, j * tile:(j + 1) * tile] = (
                part.astype(np.float32) @ b.astype(np.float32)).reshape(*part.shape[:2], *cells)
    return out


def derived(weights, basis, tile: int, cells: tuple[int, int]):
    """The LTM ``(y, x, r, s)`` as a lazy product of its stored factors.

    Parameters
    ----------
    weights : zarr.Array
        ``(y, x, rank)``.
    basis : zarr.Array
        ``(tile_y, tile_x, rank, r, s)``.
    tile : int
        Pixels per tile side.
    cells : (int, int)
        Lattice cells per chunk along ``r, s``: the dense LTM's inner chunk, or ``(1, 1)`` for
        the light-major view that relighting reads.

    Returns
    -------
    dask.array.Array
        float32, chunks of the weights' pixel blocks by ``cells``.
    """
    import dask.array as da

    w = da.from_zarr(weights, chunks=weights.chunks)
    # tiles per stored block of weights: from the stored chunk (whole tiles), not Dask's, which
    # is cut to the image (400 px of 13 tiles of 32: one block of 13 tiles, not 400 // 32)
    block = (weights.chunks[0] // tile, weights.chunks[1] // tile)
    b = da.from_zarr(basis, chunks=(*block, basis.shape[2], *cells))
    return da.blockwise(_product, "yxrs", w, "yxk", b, "yxkrs", dtype=np.float32,
                        align_arrays=False, concatenate=True, tile=tile)


class Eager:
    """A lazy array indexed like a :class:`zarr.Array`: each selection computed to NumPy (for
    readers of the stored array, such as the exporters, when the store holds factors)."""

    def __init__(self, data) -> None:
        self.data = data
        self.shape, self.dtype = data.shape, data.dtype

    def __getitem__(self, key) -> np.ndarray:
        return np.asarray(self.data[key])


def stored_or_derived(group, ds, name: str):
    """``group[name]`` when stored densely, else the derived ``ds[name]`` as :class:`Eager`."""
    return group[name] if name in group else Eager(ds[name].data)


def _expand_dot(weights: np.ndarray, lit: np.ndarray, tile: int) -> np.ndarray:
    """One block of ``W (B l)``: ``weights (h, w, k)`` of whole tiles (the last ones may be
    cut) and each tile's ``B l``, ``lit (lights, ty, tx, k)``. Each tile multiplies its own
    rank only (its basis, hence ``lit``, is zero beyond it): at the Toys size's ranks (mean
    24 of 56) 3x faster than the padded product."""
    h, w, k = weights.shape
    n, ty, tx, _ = lit.shape
    nonzero = (lit != 0).any(axis=0)  # (ty, tx, k)
    ranks = np.where(nonzero.any(axis=2), k - np.argmax(nonzero[:, :, ::-1], axis=2), 0)
    out = np.zeros((n, h, w), np.float32)
    for (i, j), rank in np.ndenumerate(ranks):
        if rank:
            where = (slice(i * tile, (i + 1) * tile), slice(j * tile, (j + 1) * tile))
            part = weights[(*where, slice(0, rank))].astype(np.float32)
            out[(slice(None), *where)] = np.moveaxis(
                part @ lit[:, i, j, :rank].astype(np.float32).T, -1, 0)
    return out


def relight(weights, basis, pattern: np.ndarray, tile: int):
    """Images ``W (B l)`` of lights on a lattice, from the factors (never the dense LTM).

    Parameters
    ----------
    weights : dask.array.Array
        ``(y, x, rank)``, chunked in blocks of whole tiles.
    basis : dask.array.Array
        ``(tile_y, tile_x, rank, r, s)`` (only the cells ``pattern`` covers).
    pattern : ndarray
        ``(lights, r, s)`` the weight of each cell in each light.
    tile : int
        Pixels per tile side.

    Returns
    -------
    dask.array.Array
        ``(lights, y, x)`` float32.
    """
    import dask.array as da

    pattern = np.asarray(pattern, np.float32)
    cells = np.argwhere((pattern != 0).any(axis=0))
    if len(cells):  # read only the cells with a weight
        parts = [basis[:, :, :, i, j].astype(np.float32) for i, j in cells]
        lit = da.tensordot(pattern[:, cells[:, 0], cells[:, 1]], da.stack(parts), axes=1)
    else:
        lit = da.zeros((len(pattern), *basis.shape[:3]), np.float32,
                       chunks=(len(pattern), *basis.chunks[:3]))
    lit = lit.rechunk((-1, basis.chunks[0], basis.chunks[1], -1))  # blocks as the weights
    # the rank in one chunk, passed as is: concatenating a single block along it would copy the
    # block's padded weights (0.26 s of a 0.8 s point light at the Notre Dame-b size)
    return da.blockwise(_expand_only_block, "lyx", weights.rechunk({2: -1}), "yxk", lit, "lyxk",
                        dtype=np.float32, align_arrays=False, concatenate=False, tile=tile)


def _expand_only_block(weights: list, lit: list, tile: int) -> np.ndarray:
    """:func:`_expand_dot` of the one block along the rank (``concatenate=False`` lists it)."""
    (weights,), (lit,) = weights, lit
    return _expand_dot(weights, lit, tile)
