"""Binning of the frames onto the lattice (the paper's eq. 2).

Each valid frame falls in one lattice cell; a cell's sample is the mean of its frames (box
kernel). Per block of frames and pixel tile, sorting the frames by cell and summing segments
gives partial sums, added over the blocks, so no more than one block of frames per tile is ever
in memory: ``ltm reconstruct`` runs one task per pixel region that reads its frames from the
store itself (:func:`resample_region`); :func:`bin_frames` is the same as a lazy Dask array
(a tree reduction over time).

6D lattices ``(r, s, p, q)`` come from registered frames in which a pixel may fall outside the
camera's frame (NaN): each pixel then averages only its own finite values, and its observed
cells (its per-pixel mask) are those with at least one. Partial sums and counts are kept only
for the ``K`` cells some frame visits (the lattice has millions of cells, ``K/M`` is small) and
scattered onto the full lattice at the end.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.binning import Binning, bin_positions  # the counting: shared with capture
from ltmstore.core.dims import Lattice, P, Plane, Q, R, S, cells_of_delta
from ltmstore.core.errors import LtmError

if TYPE_CHECKING:
    import dask.array as da
    import zarr


def _runs(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The used frames (``cells >= 0``) sorted by cell (stable), where each cell's run starts in
    that order, and the cell of each run; all empty when no frame is used."""
    used = np.flatnonzero(cells >= 0)
    if not used.size:
        return used, used, used
    order = used[np.argsort(cells[used], kind="stable")]
    sorted_cells = cells[order]
    starts = np.flatnonzero(np.r_[True, sorted_cells[1:] != sorted_cells[:-1]])
    return order, starts, sorted_cells[starts]


def _block_sums(block: np.ndarray, cells: np.ndarray, *, m: int) -> np.ndarray:
    """Per-cell sums of one block of frames: ``(t, y, x)`` -> ``(1, y, x, M)``."""
    order, starts, idx = _runs(cells[:, 0, 0])
    out = np.zeros((1, *block.shape[1:], m), dtype=np.float32)
    if order.size:
        sums = np.add.reduceat(block[order].astype(np.float32), starts, axis=0)
        out[0][..., idx] = np.moveaxis(sums, 0, -1)
    return out


def _block_sums_masked(block: np.ndarray, cells: np.ndarray, *, k: int) -> np.ndarray:
    """Per-cell sums and finite counts of one block of frames with NaN:
    ``(t, y, x)`` -> ``(1, y, x, 2 K)`` (sums, then counts), over compact cell indices."""
    order, starts, idx = _runs(cells[:, 0, 0])
    out = np.zeros((1, *block.shape[1:], 2 * k), dtype=np.float32)
    if order.size:
        values = block[order].astype(np.float32)
        finite = np.isfinite(values)
        sums = np.add.reduceat(np.where(finite, values, 0), starts, axis=0)
        counts = np.add.reduceat(finite.astype(np.float32), starts, axis=0)
        out[0][..., idx] = np.moveaxis(sums, 0, -1)
        out[0][..., k + idx] = np.moveaxis(counts, 0, -1)
    return out


def _tile_means(block: np.ndarray, cells: np.ndarray, *, count: np.ndarray,
                m: int) -> np.ndarray:
    """All the frames of one pixel tile: ``(t, y, x)`` -> ``(y, x, M)`` means (``count``:
    frames per flat cell), NaN where a cell has none."""
    order, starts, idx = _runs(cells[:, 0, 0])
    out = np.full((*block.shape[1:], m), np.nan, dtype=np.float32)
    if order.size:
        sums = np.add.reduceat(block[order].astype(np.float32), starts, axis=0)
        sums /= count[idx, None, None]
        out[..., idx] = np.moveaxis(sums, 0, -1)
    return out


def _means(sums, count: np.ndarray):
    """Per-cell means of summed frames ``(..., M)`` (NumPy or Dask), ``count`` frames per
    flat cell ``(M,)``: NaN where a cell has none."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / np.where(count > 0, count, np.nan).astype(np.float32)


def _scatter_means(block: np.ndarray, *, cells: np.ndarray, m: int) -> np.ndarray:
    """``(y, x, 2 K)`` sums and counts -> ``(y, x, M)`` means, NaN where a pixel has none."""
    k = len(cells)
    out = np.full((*block.shape[:-1], m), np.nan, dtype=np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        out[..., cells] = block[..., :k] / np.where(block[..., k:] > 0, block[..., k:], np.nan)
    return out


TILE_FRAMES_BYTES = 256 * 2**20  # frames of one pixel tile binned at once
# Frames (as float32) that one resample task reads at once: a region of 128 x 128 px of a
# 1,359-frame 4K video (89 MiB) took 1.2 s (median of 510, bench/cluster_4k.py), where 32 x 32
# px tiles over Dask's rechunked frame chunks made 136,504 tasks of milliseconds.
REGION_FRAMES_BYTES = 128 * 2**20


def region_side(tile: int, frames_chunk: int, n_frames: int) -> int:
    """The side of the square pixel region one resample task bins (:func:`resample_region`):
    the pixel ``tile`` doubled while it stays within the frames' stored chunk side
    ``frames_chunk`` and all ``n_frames`` frames of the region within
    :data:`REGION_FRAMES_BYTES` (a region of whole tiles writes whole chunks of ``samples``)."""
    side = tile
    while 2 * side <= frames_chunk and 4 * n_frames * (2 * side) ** 2 <= REGION_FRAMES_BYTES:
        side *= 2
    return side


def resample_region(where: tuple[slice, slice], *, frames: zarr.Array, samples: zarr.Array,
                    cells: np.ndarray, count: np.ndarray, channel: int | None = None) -> None:
    """Bin one pixel region ``where`` of the stored ``frames`` (``(t, y, x)``, or
    ``(channel, t, y, x)``) and write its samples (``(y, x, *lattice)``): means per cell, NaN
    where a cell has none.

    ``cells`` is every frame's flat cell (``-1``: not used), ``count`` the frames per flat cell.
    The region's frames are read from the store by the task itself, all at once where they fit
    in :data:`REGION_FRAMES_BYTES` (as :func:`bin_frames`' one pass), else in blocks of frames
    whose partial sums add up.
    """
    lead = () if channel is None else (channel,)
    (y0, y1), (x0, x1) = ((s.start, s.stop) for s in where)
    step = max(1, REGION_FRAMES_BYTES // (4 * (y1 - y0) * (x1 - x0)))
    n, m = len(cells), count.size
    if n <= step:
        means = _tile_means(frames[(*lead, slice(None), *where)], cells[:, None, None],
                            count=count, m=m)
    else:
        means = _means(sum(_block_sums(frames[(*lead, slice(t, t + step), *where)],
                                       cells[t:t + step, None, None], m=m)[0]
                           for t in range(0, n, step)), count)
    samples[where] = means.reshape(y1 - y0, x1 - x0, *samples.shape[2:]).astype(samples.dtype)


def bin_frames_masked(frames: da.Array, binning: Binning, *, block_frames: int = 512,
                      tile: tuple[int, int] = (32, 32)) -> da.Array:
    """:func:`bin_frames` for frames with NaN (unobserved pixels): per-pixel means and masks.

    A 6D lattice has millions of cells, so per-time-block partial sums of every tile would not
    fit in memory together. Instead each task takes one pixel tile over (up to
    :data:`TILE_FRAMES_BYTES` of) the whole time axis, the tile being the frames' own spatial
    chunk when it is no larger than ``tile`` (registered frames are stored in small spatial
    chunks), and keeps sums and counts only for the ``K`` visited cells. Memory per task: the
    tile's frames, a ``(tile, 2 K)`` partial and its ``(tile, M)`` means.
    """
    import dask.array as da  # here: a far-light run never needs Dask

    chunk = frames.chunksize[1:]
    tile = tuple(c if c <= t else t for c, t in zip(chunk, tile, strict=True))
    per_frame = 4 * int(np.prod(tile))
    block_frames = max(block_frames, min(frames.shape[0], TILE_FRAMES_BYTES // per_frame))
    frames = frames.rechunk((block_frames, *tile))
    visited = np.flatnonzero(binning.count.reshape(-1) > 0)
    compact = np.full(binning.m, -1, dtype=np.int64)
    compact[visited] = np.arange(len(visited))
    cell = np.where(binning.cell >= 0, compact[np.maximum(binning.cell, 0)], -1)
    k = max(len(visited), 1)
    cells = da.from_array(cell[:, None, None], chunks=(frames.chunks[0], 1, 1))
    partial = da.map_blocks(_block_sums_masked, frames, cells, k=k, new_axis=3,
                            chunks=((1,) * frames.numblocks[0], *frames.chunks[1:], (2 * k,)),
                            dtype=np.float32)
    sums = partial.sum(axis=0, split_every=8) if frames.numblocks[0] > 1 else partial[0]
    means = sums.map_blocks(_scatter_means, cells=visited, m=binning.m,
                            chunks=(*sums.chunks[:2], (binning.m,)), dtype=np.float32)
    return means.reshape(*frames.shape[1:], *binning.lattice.shape)


def bin_frames(frames: da.Array, binning: Binning, *, block_frames: int = 512,
               tile: tuple[int, int] = (32, 32)) -> da.Array:
    """Mean of the frames in each cell, NaN where none: lazy ``(y, x, *lattice)`` float32.

    One task per pixel ``tile`` takes all its frames (up to :data:`TILE_FRAMES_BYTES` of them)
    and reduces them to per-cell means (sort by cell, segment sums: O(frames x pixels), not
    O(frames x pixels x cells)). Memory per task: the tile's frames and its ``(tile, M)``
    means. Longer videos are reduced in blocks of ``block_frames`` frames whose partial sums
    Dask adds (a tree reduction over time): 1.4x the time of the single pass (90 against 66 s
    for Notre Dame-b's 1291 frames of 1 MP on 32 x 80 cells, 2 workers).

    Parameters
    ----------
    frames : dask.array.Array
        ``(t, y, x)`` linear luminance.
    binning : Binning
        The cell of every frame (``-1`` = not used). A lattice with view axes (6D) bins
        registered frames: see :func:`bin_frames_masked`.
    """
    import dask.array as da  # here: a far-light run never needs Dask

    if len(binning.lattice.shape) > 2:
        return bin_frames_masked(frames, binning, block_frames=block_frames, tile=tile)
    cells = binning.cell[:, None, None]
    if frames.shape[0] * 4 * int(np.prod(tile)) <= TILE_FRAMES_BYTES:  # one pass per tile
        frames = frames.rechunk((frames.shape[0], *tile), method="tasks")  # no P2P shuffle
        count = binning.count.reshape(-1).astype(np.float32)
        means = da.map_blocks(_tile_means, frames, da.from_array(cells, chunks=-1), count=count,
                              m=binning.m, drop_axis=0, new_axis=2,
                              chunks=(*frames.chunks[1:], (binning.m,)), dtype=np.float32)
        return means.reshape(*frames.shape[1:], *binning.lattice.shape)
    frames = frames.rechunk((block_frames, *tile), method="tasks")
    cells = da.from_array(cells, chunks=(frames.chunks[0], 1, 1))
    partial = da.map_blocks(_block_sums, frames, cells, m=binning.m, new_axis=3,
                            chunks=((1,) * frames.numblocks[0], *frames.chunks[1:],
                                    (binning.m,)), dtype=np.float32)
    means = _means(partial.sum(axis=0, split_every=8), binning.count.reshape(-1))
    return means.reshape(*frames.shape[1:], *binning.lattice.shape)


def path_length(*positions: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Length of the polyline through the positions (consecutive valid frames only)."""
    pts = np.column_stack(positions)
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    if valid is not None:
        valid = np.asarray(valid, bool)
        steps = steps[valid[1:] & valid[:-1]]
    return float(np.nansum(steps))


TARGET_RATIO_6D = 0.165  # the paper's 6D sampling ratio; the automatic 6D lattice aims at it
VIEW_TO_LIGHT_CELLS = 0.64  # view cells per light cell along a side (the paper: 16 / 25)


def view_positions(group, r: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(r, s)``, or ``(r, s, p, q)`` when the store holds camera positions (6D)."""
    if "pose_p" in group and "pose_q" in group:
        return r, s, group["pose_p"][:], group["pose_q"][:]
    return r, s


def lattice_6d(plane: Plane, view_plane: dict, positions: tuple[np.ndarray, ...],
               valid: np.ndarray, *, shape: tuple[int, ...] | None = None,
               delta: float | None = None, target_ratio: float = TARGET_RATIO_6D,
               max_cells: int = 32) -> tuple[Lattice, str]:
    """The ``(r, s, p, q)`` lattice of a 6D store: given, from a cell size, or automatic.

    Parameters
    ----------
    plane : Plane
        The illumination plane.
    view_plane : dict
        ``{"p": [min, max], "q": [min, max], ...}`` from the acquisition.
    positions : tuple of ndarray
        ``(r, s, p, q)`` per frame.
    valid : ndarray of bool
    shape : tuple of int, optional
        ``(R, S, P, Q)`` cells.
    delta : float, optional
        Cell size on both planes.
    target_ratio : float
        Automatic choice: the finest lattice ``(n, n, m, m)``, ``m = VIEW_TO_LIGHT_CELLS n``,
        whose ``K / M`` reaches this.

    Returns
    -------
    (Lattice, str)
        The lattice and ``"user"`` or ``"automatic"``.
    """
    bounds = (plane.r, plane.s, tuple(view_plane["p"]), tuple(view_plane["q"]))
    dims = (R, S, P, Q)
    if shape is not None:
        if len(tuple(shape)) != 4:
            raise LtmError(f"--lattice {'x'.join(map(str, shape))} has {len(tuple(shape))} "
                           "axes; a 6D store needs RxSxPxQ, e.g. 25x25x16x16")
        return Lattice(bounds=bounds, shape=tuple(int(n) for n in shape), dims=dims), "user"
    if delta is not None:
        return Lattice(bounds=bounds, shape=cells_of_delta(bounds, delta), dims=dims), "user"
    lattice = None
    for n in range(max_cells, 3, -1):
        m = max(2, int(round(VIEW_TO_LIGHT_CELLS * n)))
        lattice = Lattice(bounds=bounds, shape=(n, n, m, m), dims=dims)
        if bin_positions(lattice, positions, valid).ratio >= target_ratio:
            break
    return lattice, "automatic"
