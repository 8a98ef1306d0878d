"""Per-pixel confidence of a reconstruction, from the data alone (pure NumPy, per tile).

Two complementary measures, both on a batch of binned LTFs ``(n, *lattice)`` (NaN =
unobserved), for the reconstruct stage to store as ``expected_error (y, x)`` and
``unsupported (y, x)``:

* :func:`expected_error`: a cheap held-out RMS error (one or two folds of
  :func:`ltmstore.solve.validate.heldout_error`, a small fraction of the cells hidden), relative to
  the pixel's observed range. It measures how well the method interpolates *between* observations.
* :func:`flag_unsupported`: whether the observations can support any model at all: too few
  observed cells, or too much of the lattice far from every observation (:func:`coverage`,
  :func:`coverage_gap`), where the values are guesses. Held-out cells can never reveal this,
  since nothing is observed there to hold out.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ltmstore.core.errors import LtmError
from ltmstore.solve import Geometry, Method
from ltmstore.solve.masks import group_by_mask
from ltmstore.solve.validate import heldout_error, observed_range

MIN_CELLS = 8  # below this many observed cells no smooth LTF model is determined
# Coverage: the fraction of the lattice within COVER_RADIUS (a fraction of the lattice side) of
# an observed cell. Measured over 12 seeds of the simulated scribble
# (tests/solve/test_stability.py): the paper's K/M 0.29-0.35 gives 0.75-0.91 on 16 x 16 and
# 0.87-0.98 on 32 x 32 lattices; a hand that stays in one half of the plane 0.43-0.57; K/M
# 0.03-0.06 (a very short path) 0.10-0.29.
# The largest empty disc (coverage_gap) separates these less well: 0.23-0.45 for the paper's
# 16 x 16 scribbles against 0.52-0.71 for the half-empty plane, so it is off by default.
COVER_RADIUS = 0.125
MIN_COVERAGE = 0.7
EXPECTED_ERROR_FRACTION = 0.1  # cells hidden per fold by expected_error
_FAR = 1e6  # distance between rows of the batch, in lattice sides: "never the nearest"


def _distances(mask: np.ndarray, geometry: Geometry) -> np.ndarray:
    """Distance from every cell centre to the nearest observed one, in lattice sides, ``(n, M)``
    (``inf`` in rows with no observed cell)."""
    mask = np.asarray(mask, dtype=bool)
    _check_batch(mask, geometry)
    n = len(mask)
    any_obs = mask.reshape(n, -1).any(axis=1)
    dist = np.full((n, int(np.prod(geometry.shape))), np.inf)
    if any_obs.any():
        # One Euclidean distance transform over the distinct masks of the batch (usually one:
        # all pixels share the mask): the batch axis is so coarsely sampled that the nearest
        # observed cell always lies in the same row.
        rows = mask[any_obs]
        _, first, inverse = np.unique(np.packbits(rows.reshape(len(rows), -1), axis=1), axis=0,
                                      return_index=True, return_inverse=True)
        sampling = (_FAR, *(1.0 / s for s in geometry.shape))
        edt = ndimage.distance_transform_edt(~rows[first], sampling=sampling)
        dist[any_obs] = edt.reshape(len(first), -1)[inverse.ravel()]
    return dist


def coverage_gap(mask: np.ndarray, geometry: Geometry) -> np.ndarray:
    """Radius of the largest empty disc of each row, as a fraction of the lattice side.

    For every unobserved cell, the distance from its centre to the nearest observed cell centre;
    the largest over the lattice (corners and edges included: extrapolation counts). Each
    lattice axis is scaled to unit length, so the result is comparable across lattices.

    Parameters
    ----------
    mask : ndarray of bool, shape ``(n, *lattice)``
        Observed cells.
    geometry : Geometry

    Returns
    -------
    ndarray, shape (n,), float64
        0 for a fully observed row; ``inf`` for a row with no observed cell.
    """
    return _distances(mask, geometry).max(axis=1)


def coverage(mask: np.ndarray, geometry: Geometry, *, radius: float = COVER_RADIUS) -> np.ndarray:
    """Fraction of the lattice within ``radius`` (a fraction of the lattice side) of an
    observed cell, per row ``(n,)``: 1 for a trajectory that visits the whole plane."""
    return (_distances(mask, geometry) <= radius).mean(axis=1)


def flag_unsupported(samples: np.ndarray, geometry: Geometry, *, min_cells: int = MIN_CELLS,
                     min_coverage: float = MIN_COVERAGE, radius: float = COVER_RADIUS,
                     max_gap: float | None = None) -> np.ndarray:
    """Pixels whose observations cannot support a reconstruction.

    A pixel is flagged when it has fewer than ``min_cells`` observed cells, or when less than
    ``min_coverage`` of the lattice lies within ``radius`` of an observed cell (see
    :func:`coverage`: a large part of the plane is a guess), or, if ``max_gap`` is given, when
    its largest empty disc (:func:`coverage_gap`) is wider than that.

    Parameters
    ----------
    samples : ndarray, shape ``(n, *lattice)``
        Binned samples, NaN where unobserved.
    geometry : Geometry
    min_cells : int
    min_coverage : float
    radius : float
        Fractions of the lattice side.
    max_gap : float, optional

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    mask = np.isfinite(np.asarray(samples))
    flags = np.zeros(len(mask), dtype=bool)
    groups = list(group_by_mask(mask))  # judged once per distinct mask (a handheld tile: one)
    if not groups:
        return flags
    cells = np.stack([c for c, _ in groups])
    dist = _distances(cells.reshape(len(groups), *mask.shape[1:]), geometry)
    judged = (cells.sum(axis=1) < min_cells) | ((dist <= radius).mean(axis=1) < min_coverage)
    if max_gap is not None:
        judged |= dist.max(axis=1) > max_gap
    for flag, (_, rows) in zip(judged, groups, strict=True):
        flags[rows] = flag
    return flags


def expected_error(samples: np.ndarray, geometry: Geometry, method: str | Method, *,
                   params: dict | None = None, folds: int = 2, seed: int = 0,
                   fraction: float = EXPECTED_ERROR_FRACTION, block: int = 1,
                   per_pixel: dict | None = None) -> np.ndarray:
    """Expected reconstruction error per pixel: held-out RMS over the observed range.

    Costs ``folds`` extra solves of the batch; each hides ``fraction`` of the observed cells
    (the same cells for every pixel when the mask is shared). A fold's fit sees only its
    training cells; ``per_pixel`` may start it nearer its end (physical's ``start``: the
    parameters of the fit on all cells, which the reconstruct stage has at hand): a fold then
    costs two thirds of a cold one (a 32 x 32 tile on a 50 x 50 lattice: 0.26-0.29 against
    0.39-0.42 s of CPU), and the map moves by 0.1-3 % (median per pixel; the mean by 0.6-3 %,
    lower: the fit starts in the basin that all cells chose).

    A model that knows the light positions (physical) is scored where each hidden cell's samples
    were taken, not at its centre: the light's fall-off changes by tens of per cent across a
    cell, and scored at the centres the map of the tests' small relief had a median of 3.0 %,
    where the samples stand 0.64 % from the model (``ltm reconstruct --form factored`` took that
    for noise: its factors lost 2.8 dB against the truth). The model choices
    (:mod:`ltmstore.solve.select`) still score at the centres: scored at the samples they chose
    a full residual there, 2.4 dB below the truth's choice.

    Parameters
    ----------
    samples : ndarray, shape ``(n, *lattice)``
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
    per_pixel : dict, optional
        Keyword arguments of the method with one row per pixel
        (:func:`~ltmstore.solve.validate.heldout_error`).

    Returns
    -------
    ndarray of float32, shape (n,)
        RMS error at the hidden cells divided by ``max - min`` of the pixel's observed cells
        (0 for a pixel whose observations and predictions are all equal, ``inf`` for a
        constant pixel predicted wrongly); NaN where nothing could be hidden (fewer than two
        observed cells).
    """
    result = heldout_error(samples, geometry, method, folds=folds, seed=seed, params=params,
                           fraction=fraction, block=block, per_pixel=per_pixel,
                           at_samples=True)
    spread = observed_range(samples)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(result.rms > 0, result.rms / spread, result.rms)
    return rel.astype(np.float32)


def _check_batch(mask: np.ndarray, geometry: Geometry) -> None:
    if mask.shape[1:] != tuple(geometry.shape):
        want = ", ".join(map(str, geometry.shape))
        raise LtmError(f"samples of shape {mask.shape} do not match the lattice "
                       f"{tuple(geometry.shape)}; expected (n, {want})")
