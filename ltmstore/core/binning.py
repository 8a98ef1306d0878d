"""Which lattice cell each light (and view) position falls in, and what that implies: the
per-cell frame counts, ``K`` (cells observed), ``M`` (cells) and ``K / M``.

Pure counting, no frames: ``ltm reconstruct`` (through :mod:`ltmstore.stages.resample`) and the
live capture server (:mod:`ltmstore.capture.live`) both call :func:`bin_positions`, so the
coverage shown while capturing is the coverage the reconstruction will use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ltmstore.core.dims import Lattice


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
    """Assign each frame's light (and view) position to a lattice cell.

    Parameters
    ----------
    lattice : Lattice
        The lattice.
    positions : tuple of ndarray
        ``(r, s)`` (or ``(r, s, p, q)``) per frame.
    valid : ndarray of bool, optional
        Frames to count; the others get cell ``-1``.

    Returns
    -------
    Binning
    """
    cell = lattice.cell_index(*positions)
    if valid is not None:
        cell = np.where(np.asarray(valid, bool), cell, -1)
    used = cell[cell >= 0]
    count = np.bincount(used, minlength=lattice.size).reshape(lattice.shape)
    return Binning(lattice=lattice, cell=cell, count=count)


def cell_means(binning: Binning, *values: np.ndarray) -> np.ndarray:
    """The mean of each per-frame quantity in ``values`` over the frames binned into each cell,
    ``(M, len(values))`` in C order of the cells (NaN where none)."""
    used = binning.cell >= 0
    cells, m = binning.cell[used], binning.m
    count = np.bincount(cells, minlength=m).astype(float)
    with np.errstate(invalid="ignore"):
        return np.column_stack([np.bincount(cells, weights=np.asarray(v, float)[used],
                                            minlength=m) / count for v in values])


def segments(binning: Binning, times: np.ndarray, seconds: float) -> np.ndarray:
    """The stretch of the capture, ``seconds`` long, in which each cell took most of its
    frames: ``(M,)`` int, -1 where it took none.

    Neighbouring cells of a handheld path taken within the same second share their errors (a
    codec's key-frame interval, a hand's wobble of the beam); a held-out test that hides the
    cells of whole stretches together is not fooled by them
    (:func:`ltmstore.solve.validate.split_folds`'s ``groups``).
    """
    used = binning.cell >= 0
    if not used.any():
        return np.full(binning.m, -1)
    times = np.asarray(times, dtype=np.float64)[used]
    stretch = np.floor((times - times.min()) / seconds).astype(np.int64)
    cells = binning.cell[used]
    width = int(stretch.max()) + 1
    votes = np.bincount(cells * width + stretch, minlength=binning.m * width)
    votes = votes.reshape(binning.m, width)
    return np.where(votes.any(axis=1), votes.argmax(axis=1), -1)


def revisited(segment: np.ndarray) -> float:
    """The fraction of a lattice's observed cells (``segment`` >= 0, lattice-shaped) beside
    which (any of the eight neighbours) the path passed in another stretch: where it is low, the
    passes lie apart and a hidden stretch has nothing of another second near it."""
    observed = segment >= 0
    if not observed.any():
        return 0.0
    padded = np.pad(segment, 1, constant_values=-1)
    other = np.zeros(segment.shape, dtype=bool)
    rows, cols = segment.shape
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near = padded[1 + dy:1 + dy + rows, 1 + dx:1 + dx + cols]
            other |= (near >= 0) & (near != segment)
    return float((other & observed).sum() / observed.sum())
