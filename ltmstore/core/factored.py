"""The factored stored form of an LTM: per pixel tile, a shared basis over the lattice cells
and per-pixel weights (``ltm compact --form factored``, ``ltm reconstruct --form factored``).

Each tile of ``tile x tile`` pixels holds its LTFs as the rows of a matrix ``A`` (pixels by
cells); its truncated SVD ``A ~ U_k (S_k V_k)`` keeps a rank ``k`` set by one of two rules: by
default :func:`heldout_threshold`, Gavish and Donoho's optimal hard threshold on the singular
values for noise of the model's own held-out error in that tile (the rank the data supports, no
more), or :func:`target_budget`, a left-out energy of ``10**(-target/10)`` of the tile's
(every tile keeps ``target`` dB against the dense LTM).

Ranks differ from tile to tile (at the 4K bench: median 9, 99th percentile 33), so the
factors are stored packed, each tile at its own rank, never padded to the largest (padding made
one point light at 4K decompress 3.9 GB of weights where 0.47 GB are not zero). For an LTM
variable ``name``:

* ``{name}_ranks`` ``(factor_tile_y, factor_tile_x)`` int32: each tile's rank ``k``;
* ``{name}_weights`` ``(factor_weight,)``: each tile's ``U_k`` ``(h, w, k)`` in C order;
* ``{name}_basis`` ``(factor_row, r, s)``: each tile's ``k`` rows of ``S_k V_k``;

the tiles in the same order in both (:class:`Packing`: blocks of ``BLOCK_TILES`` x
``BLOCK_TILES`` tiles, row by row, and the tiles of a block row by row), so one block's factors
are one contiguous range of each. (``factor_weight_cb``, ``factor_row_cb`` ... for the colour
LTM's ``ltm_cb``, ``ltm_cr``.)

:func:`derived` presents ``T[y, x, r, s] = sum_k W[y, x, k] B[y // tile, x // tile, k, r, s]``
lazily (Dask), chunked by blocks and the dense LTM's lattice chunk, or light-major (one cell
per chunk); :func:`relight` computes ``W (B l)`` block by block from the packed arrays, reading
the weights once and the basis rows of the light's cells only.
"""

from __future__ import annotations

import functools
import threading

import numpy as np

WEIGHTS, BASIS, RANKS = "_weights", "_basis", "_ranks"
TILE_WEIGHTS, TILE_BASIS = "_tile_weights", "_tile_basis"  # staged by ltm reconstruct
TILE_DIMS = ("factor_tile_y", "factor_tile_x")
# the attributes the factors carry for their own reading, not the LTM's (units, long name ...)
LAYOUT_ATTRS = ("factored_form_of", "tile", "image", "lattice_chunk")
DEFAULT_TILE = 32
RANK_RULE = "gavish-donoho"  # the default rank rule, as the stage records name it
MAX_DB = 60.0  # no tile is kept closer than this to its dense LTM (float16 rounds at ~70 dB)
BLOCK_TILES = 16  # tiles per side of a block (512 x 512 pixels): one Dask task of a view
WEIGHT_CHUNK = 1 << 20  # packed weights per stored chunk (4 MiB of float32)
ROW_CHUNK = 4096  # basis rows per stored chunk (of one cell; a shard holds every cell)
KEPT_BYTES = 1 << 30  # decoded weights an opened store keeps in memory (a 4K LTM's: 0.46 GB)


def factored_by(stages: dict) -> str | None:
    """Which command stored the LTM as factors, from a store's stage records: ``reconstruct``
    or ``compact`` (each with ``form: factored``), or None (a dense LTM). A plain ``ltm compact``
    of a store that ``ltm reconstruct`` factored records ``form: factored`` as well; those
    factors remain reconstruct's."""
    for stage in ("reconstruct", "compact"):
        if (stages.get(stage) or {}).get("form") == "factored":
            return stage
    return None


def weights_name(name: str) -> str:
    """The weights variable of the LTM variable ``name``."""
    return f"{name}{WEIGHTS}"


def basis_name(name: str) -> str:
    """The basis variable of the LTM variable ``name``."""
    return f"{name}{BASIS}"


def ranks_name(name: str) -> str:
    """The per-tile ranks variable of the LTM variable ``name``."""
    return f"{name}{RANKS}"


def packed_dims(name: str) -> tuple[str, str]:
    """The dimensions of the packed weights and of the basis rows of the LTM variable ``name``
    (each variable has its own lengths)."""
    suffix = name.removeprefix("ltm")
    return f"factor_weight{suffix}", f"factor_row{suffix}"


def factor_tile(values: np.ndarray, allowed: float = 0.0, threshold: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Truncated SVD of one tile's LTFs: at the smallest rank whose left-out energy (sum of
    squares) is at most ``allowed``, or, given a ``threshold``, at the number of singular
    values above it (at least 1).

    First a randomised range finder (:func:`_sketch`: 64 directions, one power iteration,
    about a quarter of the time), which serves wherever its subspace meets the rule at a
    rank its oversampling leaves well found; else the exact top of the spectrum from the
    tile's smaller Gram matrix (``A A^T`` of its pixels, or ``A^T A`` of its cells: one BLAS
    product and a symmetric eigensolver). Either way the left-out energy is that of the
    factors returned, not an estimate.

    Parameters
    ----------
    values : ndarray
        ``(h, w, *cells)`` the tile's LTM, finite.
    allowed : float
        The most energy the rank-``k`` product may leave out (:func:`target_budget`), floored
        at ``MAX_DB`` below the tile's energy (which a ``threshold`` stops at too).
    threshold : float, optional
        The least singular value kept (:func:`heldout_threshold`).

    Returns
    -------
    weights : ndarray
        ``(h, w, k)`` float64, orthonormal columns.
    basis : ndarray
        ``(k, *cells)`` float64.
    """
    h, w, *cells = values.shape
    a = values.reshape(h * w, -1).astype(np.float64)  # float32's Gram misses 50 dB by 1-2 dB
    total = energy(a)
    enough = _enough(total, max(allowed, total * 10 ** (-MAX_DB / 10)), threshold)
    u, basis = _sketch(a, enough) or _exact(a, enough)
    return u.reshape(h, w, -1), basis.reshape(-1, *cells)


def _enough(total: float, allowed: float, threshold: float | None):
    """The rule as ``enough(lam, complete)``: at each rank ``1, 2, ...``, whether it is met,
    from the squared singular values ``lam`` (descending; ``complete``: all of them). A
    threshold is met too where the left-out energy is within ``allowed`` (the ``MAX_DB``
    floor)."""
    def within(lam: np.ndarray, complete: bool) -> np.ndarray:
        return total - np.cumsum(lam) <= allowed

    if threshold is None:
        return within
    return lambda lam, complete: (np.append(lam[1:] <= threshold ** 2, complete)
                                  | within(lam, complete))


SKETCH, OVERSAMPLE = 64, 16  # directions of the range finder; those kept beyond the rank


def _sketch(a: np.ndarray, enough) -> tuple | None:
    """``U_k, S_k V_k^T`` from a randomised range finder with one power iteration (Halko,
    Martinsson and Tropp 2011; a fixed seed: the same tile, the same factors), or None where
    the tile is too small for it or its subspace needs more than ``SKETCH - OVERSAMPLE``
    directions to meet the rule ``enough`` (:func:`_enough`)."""
    if 2 * SKETCH > min(a.shape):
        return None
    y = a @ np.random.default_rng(0).standard_normal((a.shape[1], SKETCH))
    y = a @ (a.T @ np.linalg.qr(y)[0])
    q = np.linalg.qr(y)[0]
    small, s, vt = np.linalg.svd(q.T @ a, full_matrices=False)
    reachable = enough(s ** 2, False)[: SKETCH - OVERSAMPLE]
    if not reachable.any():
        return None
    k = int(np.argmax(reachable)) + 1
    return q @ small[:, :k], s[:k, None] * vt[:k]


def _exact(a: np.ndarray, enough) -> tuple[np.ndarray, np.ndarray]:
    """``U_k, S_k V_k^T`` from the top eigenpairs of the smaller Gram matrix."""
    pixels_side = a.shape[0] <= a.shape[1]
    gram = a @ a.T if pixels_side else a.T @ a
    lam, vec = _top_eigen(gram, enough)
    reachable = enough(lam, len(lam) == len(gram))  # the rule at rank 1, 2, ...
    k = int(np.argmax(reachable)) + 1 if reachable.any() else len(lam)
    if pixels_side:  # A ~ U_k (U_k^T A)
        u = vec[:, :k]
        return u, u.T @ a
    v = vec[:, :k]  # A ~ (A V_k) V_k^T, A V_k = U_k S_k made orthonormal
    s = np.sqrt(lam[:k])
    return (a @ v) / np.where(s > 0, s, 1), s[:, None] * v.T


def _top_eigen(gram: np.ndarray, enough, first: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The largest eigenvalues (float64, descending, clipped at 0) and their eigenvectors of the
    symmetric ``gram``: the top ``first`` when the rule ``enough(eigenvalues, False)`` holds
    somewhere among them (LAPACK's ``syevr`` on a subset: the top 64 of a 1024 x 1024 Gram
    matrix in 0.29 s against 0.56 s for all, on a loaded machine), else all of them."""
    from scipy.linalg import eigh

    n = len(gram)
    if 2 * first <= n:
        lam, vec = eigh(gram, subset_by_index=[n - first, n - 1], driver="evr")
        lam, vec = np.clip(lam[::-1], 0, None), vec[:, ::-1]
        if enough(lam, False).any():
            return lam, vec
    lam, vec = np.linalg.eigh(gram)
    return np.clip(lam[::-1], 0, None), vec[:, ::-1]


def energy(values: np.ndarray) -> float:
    """The sum of squares of ``values``, in float64."""
    return float(np.sum(np.asarray(values, np.float64) ** 2))


def target_budget(values: np.ndarray, target_db: float) -> float:
    """The left-out energy that keeps ``target_db`` of SNR against ``values``."""
    return energy(values) * 10 ** (-target_db / 10)


def heldout_threshold(heldout_rms: np.ndarray, cells: int) -> float:
    """The singular value below which a tile's factors are noise: Gavish and Donoho's optimal
    hard threshold ("The optimal hard threshold for singular values is 4/sqrt(3)", IEEE Trans.
    Inf. Theory 60, 2014) for the tile's matrix (its pixels by ``cells``) whose entries carry
    noise of the pixels' held-out RMS (``heldout_rms``, one per pixel; NaN: none, counts as 0).

    The held-out error holds the model's error as well as the video's noise, so the threshold
    errs on the side of a lower rank. Against the energy budget before it (the factors within
    0.3 of the held-out error), SNR_Y against the truth went from 36.53 to 36.69 dB at the 4K
    bench (mean rank 14.0 to 10.6) and from 38.65 to 39.22 dB on its 384 px capture (22.8 to
    24.1).
    """
    rms = np.nan_to_num(np.asarray(heldout_rms, np.float64), nan=0.0, posinf=0.0)
    sigma = float(np.sqrt(np.mean(rms ** 2))) if rms.size else 0.0
    m, n = sorted((rms.size, int(cells)))
    beta = m / n
    scale = np.sqrt(2 * (beta + 1) + 8 * beta / (beta + 1 + np.sqrt(beta ** 2 + 14 * beta + 1)))
    return float(scale * np.sqrt(n) * sigma)


def left_out(values: np.ndarray, basis: np.ndarray) -> float:
    """The fraction of the energy of ``values`` that factors of orthonormal weights and
    ``basis`` leave out."""
    total = energy(values)
    return max(total - energy(basis), 0.0) / total if total > 0 else 0.0


def _sides(n: int, tile: int) -> np.ndarray:
    """The pixels of each tile along an image side of ``n`` pixels (the last one may be cut)."""
    return np.minimum(tile, n - np.arange(0, n, tile))


class Packing:
    """Where each tile's factors lie in the packed weights and basis rows.

    Parameters
    ----------
    ranks : ndarray
        ``(tile_y, tile_x)`` each tile's rank.
    image : (int, int)
        The image's pixels ``(y, x)``.
    tile : int
        Pixels per tile side.
    """

    def __init__(self, ranks: np.ndarray, image: tuple[int, int], tile: int) -> None:
        self.ranks = np.asarray(ranks, np.int64)
        self.image, self.tile = (int(image[0]), int(image[1])), int(tile)
        self.heights, self.widths = _sides(image[0], tile), _sides(image[1], tile)
        if self.ranks.shape != (len(self.heights), len(self.widths)):
            raise ValueError(f"ranks of shape {self.ranks.shape} do not tile an image of "
                             f"{image} pixels in tiles of {tile}")
        ty, tx = np.indices(self.ranks.shape)
        order = np.lexsort((tx.ravel(), ty.ravel(), tx.ravel() // BLOCK_TILES,
                            ty.ravel() // BLOCK_TILES))
        sizes = (self.heights[:, None] * self.widths[None, :] * self.ranks).ravel()
        self.sizes = sizes.reshape(self.ranks.shape)
        self.weight_start = _starts(sizes, order).reshape(self.ranks.shape)
        self.row_start = _starts(self.ranks.ravel(), order).reshape(self.ranks.shape)
        self.n_weights, self.n_rows = int(sizes.sum()), int(self.ranks.sum())

    def blocks(self) -> list[tuple[slice, slice]]:
        """The tiles of each block, in packed order."""
        ty, tx = self.ranks.shape
        return [(slice(i, min(i + BLOCK_TILES, ty)), slice(j, min(j + BLOCK_TILES, tx)))
                for i in range(0, ty, BLOCK_TILES) for j in range(0, tx, BLOCK_TILES)]

    def span(self, tiles: tuple[slice, slice]) -> tuple[slice, slice]:
        """The packed weights and basis rows of one block's ``tiles``."""
        first = (tiles[0].start, tiles[1].start)
        last = (tiles[0].stop - 1, tiles[1].stop - 1)
        return (slice(int(self.weight_start[first]),
                      int(self.weight_start[last] + self.sizes[last])),
                slice(int(self.row_start[first]), int(self.row_start[last] + self.ranks[last])))

    def pixels(self, tiles: tuple[slice, slice]) -> tuple[slice, slice]:
        """The pixels ``(y, x)`` of a block's ``tiles``."""
        t = self.tile
        return (slice(tiles[0].start * t, min(tiles[0].stop * t, self.image[0])),
                slice(tiles[1].start * t, min(tiles[1].stop * t, self.image[1])))

    def tiles(self, tiles: tuple[slice, slice], weights: np.ndarray):
        """Each tile of a block: ``(i, j, w, rows)`` its index in the block, its weights
        ``(h, w, k)`` from the block's packed ``weights`` and its rows' slice in the block."""
        w0, r0 = (part.start for part in self.span(tiles))
        for i in range(tiles[0].start, tiles[0].stop):
            for j in range(tiles[1].start, tiles[1].stop):
                start, k = int(self.weight_start[i, j]) - w0, int(self.ranks[i, j])
                part = weights[start:start + int(self.sizes[i, j])].reshape(
                    self.heights[i], self.widths[j], k)
                rows = slice(int(self.row_start[i, j]) - r0, int(self.row_start[i, j]) - r0 + k)
                yield i - tiles[0].start, j - tiles[1].start, part, rows


def _starts(sizes: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Each item's offset when items of ``sizes`` are laid out in ``order``."""
    ordered = sizes[order]
    starts = np.empty_like(sizes)
    starts[order] = np.cumsum(ordered) - ordered
    return starts


def pack(packing: Packing, tiles: tuple[slice, slice],
         parts: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]):
    """One block's packed weights and basis rows, in packed order, from each tile's
    ``(weights, basis)`` in ``parts`` (keyed by the tile's index in the image; tiles of other
    blocks are left alone)."""
    keys = [(i, j) for i in range(tiles[0].start, tiles[0].stop)
            for j in range(tiles[1].start, tiles[1].stop)]
    for i, j in keys:
        if parts[i, j][0].shape != (packing.heights[i], packing.widths[j], packing.ranks[i, j]):
            raise ValueError(f"tile {i}, {j}: weights of shape {parts[i, j][0].shape}, "
                             f"expected rank {packing.ranks[i, j]}")
    return (np.concatenate([parts[k][0].ravel() for k in keys]),
            np.concatenate([parts[k][1] for k in keys]))


class Packed:
    """The LTM ``(y, x, r, s)`` of packed factors, or its images ``(y, x, lights)`` under the
    lights of a ``pattern``, read block by block from the stored arrays (what :func:`derived`
    and :func:`relight` wrap for Dask).

    Parameters
    ----------
    weights, basis : zarr.Array
        The packed factors.
    packing : Packing
        Where each tile lies in them.
    pattern : ndarray, optional
        ``(lights, r, s)`` the weight of each cell in each light: each block then reads the
        basis rows of the cells with a weight only, and multiplies ``W (B l)``.
    """

    def __init__(self, weights, basis, packing: Packing, pattern: np.ndarray | None = None
                 ) -> None:
        self.weights, self.basis, self.packing = weights, basis, packing
        self.pattern = None if pattern is None else np.asarray(pattern, np.float32)
        tail = basis.shape[1:] if pattern is None else (len(pattern),)
        self.shape = (*packing.image, *tail)
        self.dtype, self.ndim = np.dtype(np.float32), len(self.shape)
        if self.pattern is not None:  # the box of cells with a weight, or none
            used = np.argwhere((self.pattern != 0).any(axis=0))
            self.box = tuple(slice(lo, hi + 1) for lo, hi in
                             zip(used.min(0), used.max(0), strict=True)) if len(used) else None

    def __dask_tokenize__(self):
        return (type(self).__name__, self.weights, self.basis, self.packing.ranks,
                self.packing.image, self.packing.tile, self.pattern)

    @functools.cached_property
    def _lit(self) -> np.ndarray:
        """``(factor_row, lights)`` every basis row under each light of the pattern: the
        cells with a weight read once for all blocks."""
        if self.box is None:
            return np.zeros((self.basis.shape[0], len(self.pattern)), np.float32)
        basis = np.asarray(self.basis[(slice(None), *self.box)], np.float32)
        weights = self.pattern[(slice(None), *self.box)]
        return np.tensordot(basis, weights, axes=((1, 2), (1, 2)))

    def _columns(self, rows: slice, key: tuple[slice, ...]) -> np.ndarray:
        """``(k, ...)`` each basis row of a block as the output's trailing axes at ``key``."""
        if self.pattern is None:
            return np.asarray(self.basis[rows, key[0], key[1]], np.float32)
        return self._lit[rows, key[0]]

    def __getitem__(self, key: tuple[slice, ...]) -> np.ndarray:
        ys, xs = (range(*k.indices(n)) for k, n in zip(key[:2], self.shape[:2], strict=True))
        if ys.step != 1 or xs.step != 1:
            raise IndexError(f"{key}: the factored LTM is read in steps of 1 along y, x")
        tail = tuple(len(range(*k.indices(n))) for k, n in zip(key[2:], self.shape[2:],
                                                                strict=True))
        out = np.zeros((len(ys), len(xs), *tail), np.float32)
        t = self.packing.tile
        for tiles in self.packing.blocks():
            by, bx = self.packing.pixels(tiles)
            if not out.size or by.start >= ys.stop or by.stop <= ys.start \
                    or bx.start >= xs.stop or bx.stop <= xs.start:
                continue
            wsl, rsl = self.packing.span(tiles)
            weights = np.asarray(self.weights[wsl], np.float32)
            columns = self._columns(rsl, key[2:])
            for i, j, part, rows in self.packing.tiles(tiles, weights):
                y0, x0 = by.start + i * t, bx.start + j * t
                yy = slice(max(y0, ys.start), min(y0 + part.shape[0], ys.stop))
                xx = slice(max(x0, xs.start), min(x0 + part.shape[1], xs.stop))
                if yy.start < yy.stop and xx.start < xx.stop:
                    product = part[yy.start - y0:yy.stop - y0, xx.start - x0:xx.stop - x0] \
                        @ columns[rows].reshape(part.shape[2], -1)
                    out[yy.start - ys.start:yy.stop - ys.start,
                        xx.start - xs.start:xx.stop - xs.start] = product.reshape(
                            *product.shape[:2], *tail)
        return out


def _lazy(packed: Packed, cells: tuple[int, ...]):
    """``packed`` as a Dask array of one chunk per block by ``cells``."""
    import dask.array as da

    side = BLOCK_TILES * packed.packing.tile
    return da.from_array(packed, chunks=(side, side, *cells), asarray=False, fancy=False,
                         meta=np.empty((0,) * packed.ndim, np.float32))


def derived(weights, basis, ranks: np.ndarray, tile: int, cells: tuple[int, int]):
    """The LTM ``(y, x, r, s)`` as a lazy product of its stored factors.

    Parameters
    ----------
    weights : zarr.Array
        ``(factor_weight,)`` packed.
    basis : zarr.Array
        ``(factor_row, r, s)`` packed; its attribute ``image`` holds the pixels ``(y, x)``.
    ranks : ndarray
        ``(tile_y, tile_x)``.
    tile : int
        Pixels per tile side.
    cells : (int, int)
        Lattice cells per chunk along ``r, s``: the dense LTM's inner chunk, or ``(1, 1)`` for
        the light-major view.

    Returns
    -------
    dask.array.Array
        float32, chunks of the blocks' pixels by ``cells``.
    """
    packing = Packing(ranks, tuple(basis.attrs["image"]), tile)
    return _lazy(Packed(weights, basis, packing), cells)


def relight(weights, basis, ranks: np.ndarray, pattern: np.ndarray, tile: int):
    """Images ``W (B l)`` of lights on a lattice, from the packed factors (never the dense LTM):
    each block reads its weights once and the basis rows of the cells with a weight.

    Parameters
    ----------
    weights, basis : zarr.Array
        The packed factors (as :func:`derived`).
    ranks : ndarray
        ``(tile_y, tile_x)``.
    pattern : ndarray
        ``(lights, r, s)`` the weight of each cell in each light.
    tile : int
        Pixels per tile side.

    Returns
    -------
    dask.array.Array
        ``(lights, y, x)`` float32, one chunk per block.
    """
    packing = Packing(ranks, tuple(basis.attrs["image"]), tile)
    packed = Packed(weights, basis, packing, pattern)
    return _lazy(packed, (len(packed.pattern),)).transpose(2, 0, 1)


class Kept:
    """A stored array whose blocks, once read, stay decoded in memory (up to ``budget`` bytes,
    kept as first read: a store opened once relights light after light without decompressing
    its weights again). Read by slices along its one axis, as :class:`Packed` reads weights.

    Parameters
    ----------
    array : zarr.Array
        ``(n,)`` the stored array.
    budget : int
        Bytes of decoded blocks to keep; blocks read past it are read each time.
    """

    def __init__(self, array, budget: int = KEPT_BYTES) -> None:
        self.array, self.budget = array, budget
        self.shape, self.dtype = array.shape, array.dtype
        self.blocks: dict[tuple[int, int], np.ndarray] = {}
        self.nbytes = 0
        self.lock = threading.Lock()

    def __dask_tokenize__(self):
        return type(self).__name__, self.array  # the stored array's token, not the blocks'

    def __getitem__(self, key: slice) -> np.ndarray:
        span = key.indices(self.shape[0])[:2]
        block = self.blocks.get(span)
        if block is None:
            block = np.asarray(self.array[key])
            block.flags.writeable = False  # shared by every later read
            with self.lock:
                if span not in self.blocks and self.nbytes + block.nbytes <= self.budget:
                    self.blocks[span] = block
                    self.nbytes += block.nbytes
        return block


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
