"""Held-out error: how well a method predicts observed cells it did not see (no truth needed).

Cross-validation on the lattice: in each fold a random subset of the observed cells is hidden,
the method is fitted on the rest, and its prediction at the hidden cells is compared with the
binned samples there. On a classic RTI capture every cell holds one light, so this is the
RTI world's leave-lights-out test; on a handheld capture it is leave-cells-out.

When all pixels of the batch share one sampling mask (every handheld or RTI capture), all pixels
hide the same cells in a fold, so a batched method still sees one shared mask; otherwise each
pixel draws its own cells. ``block > 1`` hides square blocks of ``block x block`` cells instead of
single cells: a harder, more honest test for trajectories, whose neighbouring cells along the
path are nearly copies of each other.

Held-out cells are scored against the binned samples, not a truth: noise in the samples counts
as error, and cells far from every observation (large empty regions of the plane) are never
scored, because nothing is observed there. :func:`ltmstore.solve.confidence.flag_unsupported`
reports those.
"""

from __future__ import annotations

import inspect
import warnings
from dataclasses import dataclass

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve import Geometry, Method, get_method


@dataclass(frozen=True, eq=False)
class HeldOut:
    """Result of :func:`heldout_error`.

    Attributes
    ----------
    rms : ndarray, shape (n,)
        Per-pixel RMS error over that pixel's held-out cells (all folds); NaN where no cell could
        be held out (fewer than two observed blocks).
    count : ndarray, shape (n,)
        Number of held-out cells per pixel (all folds together).
    relative_error : float
        ``||b_held - prediction|| / ||b_held||`` over every held-out (pixel, cell).
    snr_db : float
        ``20 log10(||b_held|| / ||b_held - prediction||)``: the held-out analogue of SNR_Y.
    folds : int
    cells_per_fold : tuple of float
        Mean number of held-out cells per pixel in each fold (whole numbers for a shared mask).
    shared_mask : bool
        Whether all pixels had the same mask (and so held out the same cells).
    prediction : ndarray, shape (n, cells), or None
        The method's prediction at each held-out cell (NaN at cells never held out); kept only
        when asked for (``keep_prediction``).
    """

    rms: np.ndarray
    count: np.ndarray
    relative_error: float
    snr_db: float
    folds: int
    cells_per_fold: tuple[float, ...]
    shared_mask: bool
    prediction: np.ndarray | None = None


def check_split(folds: int, fraction: float | None, block: int) -> float:
    if int(folds) != folds or folds < 1:
        raise LtmError(f"folds {folds!r} must be a positive integer")
    if int(block) != block or block < 1:
        raise LtmError(f"block {block!r} must be a positive integer (cells per side)")
    fraction = 1.0 / folds if fraction is None else float(fraction)
    if not (0 < fraction <= 1.0 / folds):
        raise LtmError(f"fraction {fraction!r} must be in (0, 1/folds] = (0, {1 / folds:.3g}]: "
                       "the folds hold out disjoint cells")
    return fraction


def _blocks(mask: np.ndarray, block: int,
            groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Block id of every lattice cell ``(M,)`` and the observed blocks of each row ``(n, B)``;
    the blocks are ``groups`` (a group per cell, -1 for none) where given."""
    if groups is not None:  # the cells of no group form one more, never observed
        ids = np.asarray(groups, dtype=np.int64).ravel()
        ids = np.where(ids < 0, ids.max(initial=-1) + 1, ids)
        member = np.zeros((ids.size, int(ids.max()) + 1))
        member[np.arange(ids.size), ids] = 1.0
        flat = mask.reshape(len(mask), -1) & (np.asarray(groups).ravel() >= 0)
        return ids, flat.astype(np.float64) @ member > 0
    lattice = mask.shape[1:]
    nb = tuple(-(-s // block) for s in lattice)
    ids = np.ravel_multi_index(np.indices(lattice).reshape(len(lattice), -1) // block, nb)
    pad = [(0, 0)] + [(0, b * block - s) for b, s in zip(nb, lattice, strict=True)]
    padded = np.pad(mask, pad)
    split = padded.reshape(len(mask), *[d for b in nb for d in (b, block)])
    observed = split.any(axis=tuple(range(2, split.ndim, 2))).reshape(len(mask), -1)
    return ids, observed


def split_folds(mask: np.ndarray, folds: int, *, fraction: float | None = None, block: int = 1,
                seed: int = 0, groups: np.ndarray | None = None) -> np.ndarray:
    """Which fold hides each observed cell: ``(n, *lattice)`` int, -1 for never hidden.

    Parameters
    ----------
    mask : ndarray of bool, shape ``(n, *lattice)``
        Observed cells of each pixel.
    folds : int
        Number of folds; they hide disjoint sets of cells.
    fraction : float, optional
        Fraction of each pixel's observed blocks hidden per fold (default ``1 / folds``: every
        observed cell is hidden once, as in k-fold cross-validation); at least one block per
        fold, and at least one block per pixel is always kept for fitting.
    block : int
        Hide square blocks of ``block`` cells per side (1: single cells).
    seed : int
    groups : ndarray of int, shape ``(M,)``, optional
        Hide the cells of a group together instead of blocks (-1: a cell never hidden), e.g.
        the stretches of a handheld path (:attr:`ltmstore.solve.Geometry.segment`).

    Returns
    -------
    ndarray of int16
        When all rows of ``mask`` are equal, all rows get the same assignment.
    """
    fraction = check_split(folds, fraction, block)
    mask = np.asarray(mask, dtype=bool)
    shared = bool((mask == mask[:1]).all())
    rows = mask[:1] if shared else mask
    ids, observed = _blocks(rows, block, groups)
    keys = np.where(observed, np.random.default_rng([seed, 606]).random(observed.shape), np.inf)
    rank = np.empty_like(observed, dtype=np.int64)
    np.put_along_axis(rank, np.argsort(keys, axis=1),
                      np.broadcast_to(np.arange(keys.shape[1]), keys.shape), axis=1)
    k = observed.sum(axis=1, keepdims=True)
    size = np.minimum(np.maximum(np.floor(k * fraction), 1), (k - 1) // folds).astype(np.int64)
    block_fold = np.where(rank < folds * size, rank // np.maximum(size, 1), -1)
    fold = np.where(rows.reshape(len(rows), -1), block_fold[:, ids], -1).astype(np.int16)
    fold = fold.reshape(rows.shape)
    return np.broadcast_to(fold, mask.shape).copy() if shared else fold


def as_method(method: str | Method) -> Method:
    return get_method(method) if isinstance(method, str) else method


def heldout_error(samples: np.ndarray, geometry: Geometry, method: str | Method, *,
                  folds: int = 5, seed: int = 0, params: dict | None = None,
                  fraction: float | None = None, block: int = 1,
                  keep_prediction: bool = False, per_pixel: dict | None = None,
                  at_samples: bool = False, groups: np.ndarray | None = None) -> HeldOut:
    """Cross-validated error of ``method`` on a batch of binned LTFs (no ground truth needed).

    Parameters
    ----------
    samples : ndarray, shape ``(n, *lattice)``
        Binned samples, NaN where unobserved (one row per pixel).
    geometry : Geometry
    method : str or callable
        A name from :data:`ltmstore.solve.METHODS`, or a function with the same signature.
    folds : int
        Number of folds (one fit of the method each).
    seed : int
        Seed of the random choice of held-out cells.
    params : dict, optional
        Keyword arguments of the method.
    fraction, block, groups
        See :func:`split_folds`.
    keep_prediction : bool
        Keep the prediction at every held-out cell (``HeldOut.prediction``).
    per_pixel : dict, optional
        Keyword arguments of the method with one row per pixel of ``samples`` (physical's
        ``start``), given to each fold's fit for the pixels it fits.
    at_samples : bool
        Predict each hidden cell where its samples were taken, for a method that knows the light
        positions (:func:`ltmstore.solve.physical.solve`'s ``at_samples``); others predict at
        the cells' centres. (The model choices keep the centres: see
        :func:`ltmstore.solve.confidence.expected_error`.)

    Returns
    -------
    HeldOut
    """
    solve, params = as_method(method), dict(params or {})
    samples = np.asarray(samples)
    if samples.dtype.kind != "f":
        samples = samples.astype(np.float64)
    n = len(samples)
    mask = np.isfinite(samples)
    fold = split_folds(mask, folds, fraction=fraction, block=block, seed=seed, groups=groups)
    sq, count = np.zeros(n), np.zeros(n, dtype=np.int64)
    prediction = np.full((n, mask[0].size), np.nan) if keep_prediction else None
    ref = res = 0.0
    per_fold = []
    for f in range(folds):
        hidden = (fold == f).reshape(n, -1)
        per_fold.append(float(hidden.sum()) / max(n, 1))
        rows = np.flatnonzero(hidden.any(axis=1))
        if rows.size == 0:
            continue
        batch, hides = samples[rows], hidden[rows]
        train = np.where(hides.reshape(batch.shape), np.nan, batch)
        rowwise = {k: np.asarray(v)[rows] for k, v in (per_pixel or {}).items()}
        # scored at the cells some row hides (a tenth of the lattice, or fewer), not all
        cols = np.flatnonzero(hides.any(axis=0))
        scored = hides[:, cols]
        pred = _predict(solve, train, geometry.take(rows), scored, cols, {**params, **rowwise},
                        at_samples=at_samples)
        truth = batch.reshape(len(rows), -1)[:, cols].astype(np.float64)
        err = np.where(scored, pred - truth, 0.0)
        if keep_prediction:
            prediction[np.ix_(rows, cols)] = np.where(scored, pred,
                                                      prediction[np.ix_(rows, cols)])
        sq[rows] += (err**2).sum(axis=1)
        count[rows] += scored.sum(axis=1)
        ref += float((np.where(scored, truth, 0.0) ** 2).sum())
        res += float((err**2).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(count > 0, np.sqrt(sq / np.maximum(count, 1)), np.nan)
        rel = float(np.sqrt(res / ref)) if ref > 0 else float("nan")
        snr = float(10 * np.log10(ref / max(res, 1e-300))) if ref > 0 else float("nan")
    return HeldOut(rms=rms, count=count, relative_error=rel, snr_db=snr, folds=int(folds),
                   cells_per_fold=tuple(per_fold), shared_mask=bool((mask == mask[:1]).all()),
                   prediction=prediction)


def _predict(solve: Method, train: np.ndarray, geometry: Geometry, scored: np.ndarray,
             cols: np.ndarray, params: dict, *, at_samples: bool = False) -> np.ndarray:
    """A fold's prediction at the flat cells ``cols`` ``(n, len(cols))`` (float64); ``scored``:
    which of them each row hides. Where every row hides all of them and the method takes ``at``
    (:func:`ltmstore.solve.physical.solve`, :func:`ltmstore.solve.rbf.solve`), computed at those
    cells alone, else everywhere and then taken there; ``at_samples``: where the cells' samples
    were taken, by a method that takes it."""
    if at_samples and _takes(solve, "at_samples"):
        pred = solve(train, geometry, **params, at=cols, at_samples=True)
    elif scored.all() and _takes(solve, "at"):
        pred = solve(train, geometry, **params, at=cols)
    else:
        pred = np.asarray(solve(train, geometry, **params)).reshape(len(train), -1)[:, cols]
    return np.asarray(pred, dtype=np.float64).reshape(len(train), len(cols))


def _takes(solve: Method, name: str) -> bool:
    try:
        return name in inspect.signature(solve).parameters
    except (TypeError, ValueError):  # a callable without a signature
        return False


def observed_range(samples: np.ndarray) -> np.ndarray:
    """Per-pixel ``max - min`` of the observed cells, ``(n,)`` float64 (NaN: none observed)."""
    flat = np.asarray(samples, dtype=np.float64).reshape(len(samples), -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows
        return np.nanmax(flat, axis=1) - np.nanmin(flat, axis=1)
