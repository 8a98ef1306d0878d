"""Choose a method, and its regularisation, per pixel tile by held-out error: no bigger model
than needed.

:func:`choose_method` (``method="auto"``) cross-validates every entry of :data:`AUTO_METHODS` on
the same held-out cells of a few dozen pixels of the tile and keeps the one with the lowest
error; listed smallest model first, the smaller one wins a tie (within :data:`TIE`).

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
from ltmstore.solve.validate import heldout_error

AUTO = "auto"
# (label, method, fixed parameters), smallest model first
AUTO_METHODS = (("ptm", "ptm", {}), ("hsh2", "hsh", {"order": 2}), ("hsh3", "hsh", {"order": 3}),
                ("cs", "cs", {}), ("rbf", "rbf", {}), ("cubic", "cubic", {}))
AUTO_METHODS_6D = (("cs", "cs", {}),)  # the one method measured on 6-D lattices (bench_6d.py)
TIE = 0.01  # relative held-out error within which the smaller model wins
PIXELS = 48  # pixels of a tile that are cross-validated
FOLDS = 2
MARGIN = 0.02  # relative held-out improvement needed to leave the default


@dataclass(frozen=True)
class Choice:
    """The chosen parameters and the held-out error of every candidate."""

    params: dict
    errors: dict


def auto_grid(method: str) -> dict:
    """The method's ``AUTO_GRID`` (empty: nothing to choose)."""
    module = importlib.import_module(get_method(method).__module__)
    return dict(getattr(module, "AUTO_GRID", {}))


def choose_params(samples: np.ndarray, geometry: Geometry, method: str, *, params: dict,
                  seed: int = 0) -> Choice:
    """Pick, for this batch, the candidate of ``AUTO_GRID`` with the lowest held-out error.

    Parameters already fixed in ``params`` are never overridden.
    """
    grid = {k: v for k, v in auto_grid(method).items() if k not in params}
    if not grid:
        return Choice(params=dict(params), errors={})
    (name, candidates), = grid.items()
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(samples), size=min(PIXELS, len(samples)), replace=False)
    errors = {}
    for value in candidates:
        held = heldout_error(samples[rows], geometry, method, folds=FOLDS, seed=seed,
                             params={**params, name: value})
        errors[value] = held.relative_error
    default = inspect.signature(get_method(method)).parameters[name].default
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


def choose_method(samples: np.ndarray, geometry: Geometry, *, seed: int = 0) -> MethodChoice:
    """The entry of :data:`AUTO_METHODS` with the lowest held-out error on a few pixels of the
    batch (the same held-out cells for every candidate); the smaller model wins a tie. A 6-D
    lattice keeps :data:`AUTO_METHODS_6D`."""
    entries = AUTO_METHODS if geometry.ndim == 2 else AUTO_METHODS_6D
    if len(entries) == 1:
        (label, method, params), = entries
        return MethodChoice(label=label, method=method, params=dict(params), errors={})
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(samples), size=min(PIXELS, len(samples)), replace=False)
    errors = {label: heldout_error(samples[rows], geometry, method, folds=FOLDS, seed=seed,
                                   params=params).relative_error
              for label, method, params in AUTO_METHODS}
    best = min((e for e in errors.values() if np.isfinite(e)), default=np.inf)
    label, method, params = next(entry for entry in AUTO_METHODS
                                 if not np.isfinite(best) or errors[entry[0]] <= best * (1 + TIE))
    return MethodChoice(label=label, method=method, params=dict(params), errors=errors)


def solve_auto(samples: np.ndarray, geometry: Geometry, *, seed: int = 0) -> np.ndarray:
    """``method="auto"`` as a solver: :func:`choose_method` on the batch, then that method."""
    choice = choose_method(samples, geometry, seed=seed)
    return get_method(choice.method)(samples, geometry, **choice.params)
