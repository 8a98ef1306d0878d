"""Per-pixel confidence of a reconstruction, from the data alone (pure NumPy, per tile).

Two complementary measures, both on a batch of binned LTFs ``(n, *lattice)`` (NaN =
unobserved), for the reconstruct stage to store as ``expected_error (y, x)`` and
``unsupported (y, x)``:

* :func:`expected_error`: a cheap held-out RMS error (one or two folds of
  :func:`ltmstore.heldout.heldout_error`, a small fraction of the cells hidden), relative to the
  pixel's observed range. It measures how well the method interpolates *between* observations.
* :func:`flag_unsupported`: whether the observations can support any model at all: too few
  observed cells, or a region of the lattice so far from every observation (the radius of the
  largest empty disc, :func:`coverage_gap`) that the values there are guesses. Held-out cells
  can never reveal this, since nothing is observed there to hold out.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ltmstore.errors import LtmError
from ltmstore.heldout import heldout_error, observed_range
from ltmstore.solve import Geometry, Method

MIN_CELLS = 8  # below this many observed cells no smooth LTF model is determined
# Largest empty disc, as a fraction of the lattice side. 0.25 means a hole half the plane wide.
# Measured on 16 x 16 lattices (tests/test_stability.py, seed 0): about 0.13 for the paper's
# K/M 0.3 scribble, 0.25-0.28 for K/M 0.03 (8 cells), 0.5 when half the plane is empty.
MAX_GAP = 0.2
EXPECTED_ERROR_FRACTION = 0.1  # cells hidden per fold by expected_error
_FAR = 1e6  # distance between rows of the batch, in lattice sides: "never the nearest"


def coverage_gap(mask: np.ndarray, geometry: Geometry) -> np.ndarray:
    """Radius of the largest empty disc of each row, as a fraction of the lattice side.

    For every unobserved cell, the distance from its centre to the nearest observed cell centre;
    the largest over the lattice (corners and edges included: extrapolation counts). Each
    lattice axis is scaled to unit length, so the result is comparable across lattices.

    Parameters
    ----------
    mask : ndarray of bool, shape (n, *lattice)
        Observed cells.
    geometry : Geometry

    Returns
    -------
    ndarray, shape (n,), float64
        0 for a fully observed row; ``inf`` for a row with no observed cell.
    """
    mask = np.asarray(mask, dtype=bool)
    _check_batch(mask, geometry)
    n = len(mask)
    any_obs = mask.reshape(n, -1).any(axis=1)
    gap = np.full(n, np.inf)
    if not any_obs.any():
        return gap
    # One Euclidean distance transform over the whole batch: the batch axis is so coarsely
    # sampled that the nearest observed cell always lies in the same row.
    sampling = (_FAR, *(1.0 / s for s in geometry.shape))
    dist = ndimage.distance_transform_edt(~mask[any_obs], sampling=sampling)
    gap[any_obs] = dist.reshape(int(any_obs.sum()), -1).max(axis=1)
    return gap


def flag_unsupported(samples: np.ndarray, geometry: Geometry, *, min_cells: int = MIN_CELLS,
                     max_gap: float = MAX_GAP) -> np.ndarray:
    """Pixels whose observations cannot support a reconstruction.

    Parameters
    ----------
    samples : ndarray, shape (n, *lattice)
        Binned samples, NaN where unobserved.
    geometry : Geometry
    min_cells : int
        Flag a pixel with fewer observed cells than this.
    max_gap : float
        Flag a pixel whose :func:`coverage_gap` exceeds this fraction of the lattice side.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    mask = np.isfinite(np.asarray(samples))
    k = mask.reshape(len(mask), -1).sum(axis=1)
    return (k < min_cells) | (coverage_gap(mask, geometry) > max_gap)


def expected_error(samples: np.ndarray, geometry: Geometry, method: str | Method, *,
                   params: dict | None = None, folds: int = 2, seed: int = 0,
                   fraction: float = EXPECTED_ERROR_FRACTION, block: int = 1) -> np.ndarray:
    """Expected reconstruction error per pixel: held-out RMS over the observed range.

    Costs ``folds`` extra solves of the batch; each hides ``fraction`` of the observed cells
    (the same cells for every pixel when the mask is shared).

    Parameters
    ----------
    samples : ndarray, shape (n, *lattice)
        Binned samples, NaN where unobserved.
    geometry : Geometry
    method : str or callable
        A name from :data:`ltmstore.solve.METHODS` (or a function with its signature).
    params : dict, optional
        Keyword arguments of the method.
    folds : int
        One or two folds is enough for a map; more average out the choice of cells.
    seed : int
    fraction : float
        Fraction of the observed cells hidden in each fold (at most ``1 / folds``).
    block : int
        Hide ``block x block`` squares of cells instead of single cells.

    Returns
    -------
    ndarray of float32, shape (n,)
        RMS error at the hidden cells divided by ``max - min`` of the pixel's observed cells
        (0 for a pixel whose observations and predictions are all equal, ``inf`` for a
        constant pixel predicted wrongly); NaN where nothing could be hidden (fewer than two
        observed cells).
    """
    result = heldout_error(samples, geometry, method, folds=folds, seed=seed, params=params,
                           fraction=fraction, block=block)
    spread = observed_range(samples)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(result.rms > 0, result.rms / spread, result.rms)
    return rel.astype(np.float32)


def _check_batch(mask: np.ndarray, geometry: Geometry) -> None:
    if mask.shape[1:] != tuple(geometry.shape):
        raise LtmError(f"samples of shape {mask.shape} do not match the lattice "
                       f"{tuple(geometry.shape)}; expected (n, {', '.join(map(str, geometry.shape))})")
