"""Choose a method, and its regularisation, per pixel tile by held-out error: no bigger model
than needed.

:func:`choose_method` (``method="auto"``) cross-validates every entry of :data:`AUTO_METHODS` on
the same held-out cells of a few dozen pixels of the tile, and blends of ``cs`` and ``rbf`` from
the same held-out predictions, and keeps the one with the lowest error; listed smallest model
first, the smaller one wins a tie (within :data:`TIE`).

A method that can be tuned declares ``AUTO_GRID``, a mapping of one parameter to its candidate
values (for ``cs`` the final threshold ``lam_min``: a larger one keeps fewer DCT coefficients, a
sparser model). For each tile a small random subset of pixels is cross-validated (cells held out,
predicted from the rest; :func:`ltmstore.solve.validate.heldout_error`) with every candidate, and
the candidate with the lowest held-out error wins, unless it beats the method's default by less
than :data:`MARGIN` (a held-out estimate on a few dozen pixels is noisy by about that much; on
the simulated scenes the held-out error always leans to the largest threshold by 1-2 %, while the
truth prefers the default by up to 0.6 dB). The cost is a few solves of a few dozen pixels.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass

import numpy as np

from ltmstore.solve import Geometry, get_method
from ltmstore.solve.validate import HeldOut, heldout_error

AUTO = "auto"
# (label, method, fixed parameters), smallest model first
AUTO_METHODS = (("ptm", "ptm", {}), ("hsh2", "hsh", {"order": 2}), ("hsh3", "hsh", {"order": 3}),
                ("cs", "cs", {}), ("rbf", "rbf", {}), ("cubic", "cubic", {}))
# tried as well where the batch knows its pixels' positions on the object plane (near lights)
AUTO_PHYSICAL = (("physical", "physical", {}),)
BLEND = "cs+rbf"  # label of the blend of cs and rbf that auto may choose (ltmstore.solve.blend)
AUTO_LABELS = (*(entry[0] for entry in AUTO_METHODS + AUTO_PHYSICAL), BLEND)  # method_map names
BLEND_WEIGHTS = (0.25, 0.5, 0.75)  # weights of cs tried (0 and 1 are rbf and cs themselves)
AUTO_METHODS_6D = (("cs", "cs", {}),)  # the one method measured on 6-D lattices (bench_6d.py)
TIE = 0.01  # relative held-out error within which the smaller model wins
PIXELS = 48  # pixels of a tile that are cross-validated
FOLDS = 2
MARGIN = 0.02  # relative held-out improvement needed to leave the default
# folds of the choice where it hides whole stretches of a handheld path (Geometry.segment): each
# fit then keeps four fifths of the path (two folds, half the path each, fitted the surface model
# worse than the whole path does, and chose its full residual in 5 of 20 tiles of a lossless
# 720 px capture, 0.9 dB below the model alone against the truth; five folds: 2 tiles, 0.3 dB)
SEGMENT_FOLDS = 5
HOLE = 0.25  # side of the held-out blocks that test the physical model, fraction of the lattice
HOLE_QUANTILE = 0.75  # ... or twice this quantile of the unobserved cells' distance to the path
# The physical model extrapolates by physics where the path left the lattice empty, which no
# held-out block reaches: an interpolant must predict the blocks this much better to replace
# it. On the 720 px simulated canvas with the LED's beam (K/M 0.20, the path over half the
# plane), tiles that chose rbf by 1-13 % lower block errors relit 1-14 dB below the physical
# model against the truth.
HOLE_MARGIN = 0.25


@dataclass(frozen=True)
class Choice:
    """The chosen parameters and the held-out error of every candidate."""

    params: dict
    errors: dict


def _declared(method: str, name: str) -> dict:
    """The mapping ``name`` that the method's module declares (empty where it declares none)."""
    return dict(getattr(importlib.import_module(get_method(method).__module__), name, {}))


def auto_grid(method: str) -> dict:
    """The method's ``AUTO_GRID`` (empty: nothing to choose)."""
    return _declared(method, "AUTO_GRID")


def auto_default(method: str, name: str, *, revisited: bool = False) -> object:
    """The value of parameter ``name`` that the choice keeps unless another predicts held-out
    cells better by :data:`MARGIN`: the solver's default, or on a path revisited beside most of
    its cells (``revisited``) the method's ``REVISITED_DEFAULT`` where it declares one."""
    fallback = _declared(method, "REVISITED_DEFAULT") if revisited else {}
    if name in fallback:
        return fallback[name]
    return inspect.signature(get_method(method)).parameters[name].default


def choose_params(samples: np.ndarray, geometry: Geometry, method: str, *, params: dict,
                  seed: int = 0, pixels: int = PIXELS) -> Choice:
    """Pick, for this batch, the candidate of ``AUTO_GRID`` with the lowest held-out error
    on ``pixels`` of its rows.

    Parameters already fixed in ``params`` are never overridden. The choice keeps
    :func:`auto_default` unless another candidate beats it by :data:`MARGIN`. Where the geometry
    knows the stretches of a handheld path (:attr:`~ltmstore.solve.Geometry.segment`), the folds
    hide whole stretches (:data:`SEGMENT_FOLDS`): neighbouring cells of one stretch share their
    errors (a codec's), and hiding them one by one rewards a model that copies them; there the
    default is the method's ``REVISITED_DEFAULT`` (the surface model alone). On 20 tiles
    of a 720 px simulated canvas filmed as H.264 at 0.27 bits per pixel, cells hidden one by one
    chose the surface model's residual in every tile, 1.8 dB below the model alone against the
    truth; whole seconds hidden chose the model alone in 17 (0.05 dB below it).
    """
    grid = {k: v for k, v in auto_grid(method).items() if k not in params}
    if not grid:
        return Choice(params=dict(params), errors={})
    (name, candidates), = grid.items()
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(samples), size=min(pixels, len(samples)), replace=False)
    folds = FOLDS if geometry.segment is None else SEGMENT_FOLDS
    errors = {}
    for value in candidates:
        held = heldout_error(samples[rows], geometry.take(rows), method, folds=folds, seed=seed,
                             params={**params, name: value}, groups=geometry.segment)
        errors[value] = held.relative_error
    default = auto_default(method, name, revisited=geometry.segment is not None)
    finite = {v: e for v, e in errors.items() if np.isfinite(e)}
    best = min(finite, key=finite.get) if finite else default
    if default in finite and finite[best] > (1 - MARGIN) * finite[default]:
        best = default
    return Choice(params={**params, name: best}, errors=errors)


@dataclass(frozen=True)
class MethodChoice:
    """The method chosen for a tile: its ``label`` (e.g. ``hsh2``), solver name, fixed
    parameters, and the held-out error of every candidate label."""

    label: str
    method: str
    params: dict
    errors: dict


def choose_method(samples: np.ndarray, geometry: Geometry, *, seed: int = 0,
                  pixels: int = PIXELS, labels: tuple[str, ...] | None = None) -> MethodChoice:
    """The entry of :data:`AUTO_METHODS` with the lowest held-out error on ``pixels`` rows of
    the batch (the same held-out cells for every candidate), or a blend of ``cs`` and ``rbf``
    (:data:`BLEND`) where a weight of :data:`BLEND_WEIGHTS` predicts those cells better still;
    the smaller model wins a tie (the blend counts as the largest). Where ``geometry`` carries
    the pixels' positions, :data:`AUTO_PHYSICAL` (the physical reflectance model) is a candidate
    too, and where the cells chose another, the two meet again on large held-out blocks
    (:func:`_fill_holes`). A 6-D lattice keeps :data:`AUTO_METHODS_6D`. ``labels``: only these
    candidates (:func:`finalists` of an earlier choice on a wider sample)."""
    entries = AUTO_METHODS if geometry.ndim == 2 else AUTO_METHODS_6D
    if geometry.ndim == 2 and geometry.pixels is not None:
        entries = AUTO_METHODS + AUTO_PHYSICAL
    if labels is not None:
        keep = {*labels, *(("cs", "rbf") if BLEND in labels else ())}
        entries = tuple(e for e in entries if e[0] in keep)
    if len(entries) == 1:
        (label, method, params), = entries
        return MethodChoice(label=label, method=method, params=dict(params), errors={})
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(samples), size=min(pixels, len(samples)), replace=False)
    picked = samples[rows]
    held = {label: heldout_error(picked, geometry.take(rows), method, folds=FOLDS, seed=seed,
                                 params=params, keep_prediction=label in ("cs", "rbf"))
            for label, method, params in entries}
    errors = {label: h.relative_error for label, h in held.items()}
    candidates = list(entries)
    if "cs" in held and "rbf" in held and (labels is None or BLEND in labels):
        weight, errors[BLEND] = _best_blend(held["cs"], held["rbf"],
                                            picked.reshape(len(rows), -1))
        candidates.append((BLEND, "blend", {"weight": weight}))
    best = min((e for e in errors.values() if np.isfinite(e)), default=np.inf)
    label, method, params = next(entry for entry in candidates
                                 if not np.isfinite(best) or errors[entry[0]] <= best * (1 + TIE))
    if entries[-1] in AUTO_PHYSICAL and label != AUTO_PHYSICAL[0][0]:
        label, method, params = _fill_holes(picked, geometry.take(rows), (label, method, params),
                                            AUTO_PHYSICAL[0], errors, seed=seed)
    return MethodChoice(label=label, method=method, params=dict(params), errors=errors)


def finalists(choice: MethodChoice) -> tuple[str, ...]:
    """The labels worth trying again on a part of the batch that ``choice`` was made on: the
    best of the interpolating candidates by held-out cells, and the physical model where it was
    a candidate (the two that :func:`choose_method` lets meet on held-out blocks)."""
    physical = AUTO_PHYSICAL[0][0]
    cells = {k: v for k, v in choice.errors.items()
             if "@" not in k and k != physical and np.isfinite(v)}
    if not cells:
        return (choice.label,)
    best = min(cells.values())
    order = [e[0] for e in AUTO_METHODS] + [BLEND]  # smallest model first, as choose_method
    other = next(label for label in order if label in cells and cells[label] <= best * (1 + TIE))
    return (other, physical) if physical in choice.errors else (other,)


def _fill_holes(samples: np.ndarray, geometry: Geometry, chosen: tuple, physical: tuple,
                errors: dict, *, seed: int) -> tuple:
    """``physical``, unless ``chosen`` predicts held-out blocks (:func:`hole_sides`: the holes
    a handheld path leaves, which single held-out cells beside the path never test: there the
    interpolating methods look better than they are) clearly better, by :data:`HOLE_MARGIN`;
    the errors go into ``errors`` as ``label@holes``."""
    widest, block = hole_sides(np.isfinite(samples).any(axis=0))
    for side in range(widest, block - 1, -1):  # narrower where too few blocks were observed
        scores = {label: heldout_error(samples, geometry, method, folds=FOLDS, seed=seed,
                                       params=params, block=side).relative_error
                  for label, method, params in (chosen, physical)}
        if np.isfinite(list(scores.values())).all():
            break
    errors.update({f"{label}@holes": e for label, e in scores.items()})
    ours, theirs = scores[physical[0]], scores[chosen[0]]
    kept = np.isfinite(ours) and not theirs < ours * (1 - HOLE_MARGIN)
    return physical if kept else chosen


def hole_sides(observed: np.ndarray) -> tuple[int, int]:
    """The widest and the narrowest side (cells) of the held-out blocks that weigh the
    physical model against an interpolating one on a lattice whose ``observed`` cells (any
    pixel's) a handheld path left: twice the distance from the path within which
    :data:`HOLE_QUANTILE` of the unobserved cells lie (an interpolant is only tested as far
    from the path as its blocks reach, and the relit image needs it as far as the unobserved
    cells lie), at most half the lattice's side; and :data:`HOLE` of that side."""
    from scipy import ndimage

    side = min(observed.shape)
    narrowest = max(2, round(side * HOLE))
    widest = narrowest
    if observed.any() and not observed.all():
        far = ndimage.distance_transform_edt(~observed)[~observed]
        widest = max(narrowest, round(2 * float(np.quantile(far, HOLE_QUANTILE))))
    return int(min(widest, max(narrowest, side // 2))), narrowest


def _best_blend(cs: HeldOut, rbf: HeldOut, observed: np.ndarray) -> tuple[float, float]:
    """The weight of ``cs`` in :data:`BLEND_WEIGHTS` whose blend best predicts the held-out
    cells, and its relative error (both methods held out the same cells)."""
    hidden = np.isfinite(cs.prediction) & np.isfinite(rbf.prediction)
    truth = np.where(hidden, observed, 0.0)
    norm = float(np.sqrt((truth**2).sum()))
    if not hidden.any() or norm == 0:
        return BLEND_WEIGHTS[0], float("nan")
    errors = {w: float(np.sqrt((np.where(hidden, w * cs.prediction + (1 - w) * rbf.prediction
                                          - observed, 0.0) ** 2).sum())) / norm
              for w in BLEND_WEIGHTS}
    weight = min(errors, key=errors.get)
    return weight, errors[weight]


def solve_auto(samples: np.ndarray, geometry: Geometry, *, seed: int = 0) -> np.ndarray:
    """``method="auto"`` as a solver: :func:`choose_method` on the batch, then that method."""
    choice = choose_method(samples, geometry, seed=seed)
    return get_method(choice.method)(samples, geometry, **choice.params)
