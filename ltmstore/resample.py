"""Binning of the frames onto the lattice (the paper's eq. 2): a Dask reduction over time.

Each valid frame falls in one lattice cell; a cell's sample is the mean of its frames (box
kernel). Per block of frames and pixel tile, sorting the frames by cell and summing segments
gives partial sums; Dask adds the partial sums of all blocks as a tree reduction over time, so
no more than one block of frames per tile is ever in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import dask.array as da
import numpy as np

from ltmstore.dims import Lattice


@dataclass(frozen=True)
class Binning:
    """Cell of every frame and what it implies (K, M, counts)."""

    lattice: Lattice
    cell: np.ndarray  # (t,) flat cell index, -1 for frames not used
    count: np.ndarray  # lattice-shaped number of frames per cell

    @property
    def observed(self) -> np.ndarray:
        return self.count > 0

    @property
    def k(self) -> int:
        return int(self.observed.sum())

    @property
    def m(self) -> int:
        return self.lattice.size

    @property
    def ratio(self) -> float:
        """``K / M``, the sampling ratio."""
        return self.k / self.m


def bin_positions(lattice: Lattice, positions: tuple[np.ndarray, ...],
                  valid: np.ndarray | None = None) -> Binning:
    """Assign each frame's light (and view) position to a lattice cell."""
    cell = lattice.cell_index(*positions)
    if valid is not None:
        cell = np.where(np.asarray(valid, bool), cell, -1)
    used = cell[cell >= 0]
    count = np.bincount(used, minlength=lattice.size).reshape(lattice.shape)
    return Binning(lattice=lattice, cell=cell, count=count)


def _block_sums(block: np.ndarray, cells: np.ndarray, *, m: int) -> np.ndarray:
    """Per-cell sums of one block of frames: ``(t, y, x)`` -> ``(1, y, x, M)``."""
    cells = cells[:, 0, 0]
    used = np.flatnonzero(cells >= 0)
    out = np.zeros((1, *block.shape[1:], m), dtype=np.float32)
    if used.size:
        order = used[np.argsort(cells[used], kind="stable")]
        sorted_cells = cells[order]
        starts = np.flatnonzero(np.r_[True, sorted_cells[1:] != sorted_cells[:-1]])
        sums = np.add.reduceat(block[order].astype(np.float32), starts, axis=0)
        out[0][..., sorted_cells[starts]] = np.moveaxis(sums, 0, -1)
    return out


def bin_frames(frames: da.Array, binning: Binning, *, block_frames: int = 512,
               tile: tuple[int, int] = (32, 32)) -> da.Array:
    """Mean of the frames in each cell, NaN where none: lazy ``(y, x, *lattice)`` float32.

    Each block of ``block_frames`` frames of a pixel ``tile`` is reduced to per-cell sums
    (sort by cell, segment sums: O(frames x pixels), not O(frames x pixels x cells)); Dask adds
    the partial sums of the blocks. Memory per task: one block and one ``(tile, M)`` partial.

    Parameters
    ----------
    frames : dask.array.Array
        ``(t, y, x)`` linear luminance.
    binning : Binning
        The cell of every frame (``-1`` = not used).
    """
    frames = frames.rechunk((block_frames, *tile), method="tasks")  # splits: no P2P shuffle
    cells = da.from_array(binning.cell[:, None, None], chunks=(frames.chunks[0], 1, 1))
    partial = da.map_blocks(_block_sums, frames, cells, m=binning.m, new_axis=3,
                            chunks=((1,) * frames.numblocks[0], *frames.chunks[1:],
                                    (binning.m,)), dtype=np.float32)
    sums = partial.sum(axis=0, split_every=8)
    count = binning.count.reshape(-1).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / np.where(count > 0, count, np.nan)
    return means.reshape(*frames.shape[1:], *binning.lattice.shape)


def path_length(*positions: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Length of the polyline through the positions (consecutive valid frames only)."""
    pts = np.column_stack(positions)
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    if valid is not None:
        valid = np.asarray(valid, bool)
        steps = steps[valid[1:] & valid[:-1]]
    return float(np.nansum(steps))
