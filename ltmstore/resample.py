"""Binning of the frames onto the lattice (the paper's eq. 2): a Dask reduction over time.

Each valid frame falls in one lattice cell; a cell's sample is the mean of its frames (box
kernel). Per block of frames, a one-hot ``(t, M)`` matrix times the ``(t, pixels)`` block gives
partial sums; Dask adds the partial sums of all blocks (``tensordot`` contracts over the chunked
time axis as a tree reduction), so no more than one block of frames is ever in memory.
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


def _one_hot(cell: np.ndarray, m: int) -> np.ndarray:
    hot = np.zeros((len(cell), m), dtype=np.float32)
    used = cell >= 0
    hot[np.flatnonzero(used), cell[used]] = 1.0
    return hot


def bin_frames(frames: da.Array, binning: Binning) -> da.Array:
    """Mean of the frames in each cell, NaN where none: lazy ``(y, x, *lattice)`` float32.

    Parameters
    ----------
    frames : dask.array.Array
        ``(t, y, x)`` linear luminance, chunked along ``t``.
    binning : Binning
        The cell of every frame (``-1`` = not used).
    """
    one_hot = da.from_array(_one_hot(binning.cell, binning.m), chunks=(frames.chunks[0], -1))
    sums = da.tensordot(frames.astype(np.float32), one_hot, axes=([0], [0]))  # (y, x, M)
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
