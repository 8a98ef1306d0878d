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
