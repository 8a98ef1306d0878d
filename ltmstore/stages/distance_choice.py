"""The far-light model of a light as a function of how far it lies from the photographed ones.

Held-out lights (:func:`ltmstore.stages.surface.cross_validated`: every 4th in turn) score
each model about one light spacing away from the nearest photograph it was fitted to. A light
between a dome's photographed lights is nearer to one, and a light at a photographed direction
is that photograph: there an interpolant (an RBF of small smoothing) reproduces the photograph
while the surface model misses it by what its smoothed residual leaves. So the model the
held-out lights prefer is not the best near the photographs. Each candidate's mean squared
error at a light ``delta`` radians from the nearest photographed light is estimated between its
error at the photographed lights themselves (every light fitted, ``delta = 0``:
:func:`ltmstore.stages.surface.in_sample`) and its held-out error (``delta`` about the mean
spacing ``s`` between a photographed light and its nearest neighbour)::

    e(delta) = e_fitted + reach(delta) (e_held_out - e_fitted),  reach = min(1, (delta / s)^2)

(an interpolant's error grows with the square of the distance from its nodes), and the image's
choice is made with these errors light by light. It is piecewise constant in ``reach``:
:class:`DistanceChoice` holds its pieces, and its method name lists them,
``MODEL<REACH<MODEL...`` (the model from each ``reach`` up to the next; the last is the held-out
choice). Over the 49 captures of ``bench/heldout_table.py`` this took the default from 4 to 2
captures more than 0.2 dB below the best classic fit (README); the real captures' held-out
photographs, every 6th light of the dome, lie about one spacing from the others and keep
their model.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass

import numpy as np

from ltmstore.solve.lightfit import Model
from ltmstore.stages.surface import PREFIX, Blend

SEPARATOR = "<"  # between the pieces of a DistanceChoice's method name
STEPS = 100  # reach is scored at 0, 1/STEPS, ..., 1


def spacing(train: np.ndarray) -> float:
    """Mean angle (radians) between each of the unit directions ``train (n, 3)`` and its nearest
    neighbour."""
    angles = _angles(train, train)
    np.fill_diagonal(angles, np.inf)
    return float(angles.min(axis=1).mean())


def reach(train: np.ndarray, query: np.ndarray) -> np.ndarray:
    """``(q,)`` in ``[0, 1]``: how far each of ``query (q, 3)`` lies from the nearest of
    ``train (n, 3)``, ``min(1, (delta / s)^2)`` with ``s`` their :func:`spacing`."""
    nearest = _angles(query, train).min(axis=1)
    return np.minimum(1.0, (nearest / spacing(train)) ** 2)


def pieces(held_out: dict, fitted: dict, choose: Callable[[dict], Hashable]
           ) -> list[tuple[float, Hashable]]:
    """``[(reach, choice), ...]``: ``choose`` of the errors interpolated between ``fitted``
    (every light fitted) and ``held_out`` (same keys) at each reach of :data:`STEPS`, from where
    each choice starts; the last is ``choose(held_out)``."""
    out: list[tuple[float, Hashable]] = []
    for step in range(STEPS + 1):
        r = step / STEPS
        choice = choose({k: fitted[k] + r * (held_out[k] - fitted[k]) for k in fitted})
        if not out or out[-1][1] != choice:
            out.append((r, choice))
    return out


@dataclass(frozen=True)
class DistanceChoice:
    """Far-light models by :func:`reach`: ``models[i]`` from ``starts[i]`` (the first 0) up to
    the next start. Relights as a :class:`~ltmstore.stages.surface.Blend` does (the surface's
    part only where a Blend is the light's model)."""

    models: tuple[Model | Blend, ...]
    starts: tuple[float, ...]

    @property
    def name(self) -> str:
        parts = [self.models[0].name]
        for start, model in zip(self.starts[1:], self.models[1:], strict=True):
            parts += [f"{start:g}", model.name]
        return SEPARATOR.join(parts)

    @classmethod
    def from_name(cls, name: str) -> DistanceChoice:
        parts = name.split(SEPARATOR)
        return cls(tuple(far_model(p) for p in parts[::2]),
                   (0.0, *(float(s) for s in parts[1::2])))

    @property
    def blend(self) -> Blend | None:
        """The surface's Blend among the models (at most one lobe and smoother), if any."""
        return next((m for m in self.models if isinstance(m, Blend)), None)

    def groups(self, train: np.ndarray, query: np.ndarray
               ) -> Iterator[tuple[Model | Blend, np.ndarray]]:
        """Each model with the indices of the ``query (q, 3)`` lights it relights."""
        which = np.searchsorted(self.starts, reach(train, query), side="right") - 1
        for i, model in enumerate(self.models):
            rows = np.flatnonzero(which == i)
            if len(rows):
                yield model, rows

    def weights(self, train: np.ndarray, query: np.ndarray) -> np.ndarray:
        """``(q, n)``: each light's model's linear weights (:meth:`Blend.weights`)."""
        out = np.zeros((len(query), len(train)))
        for model, rows in self.groups(train, query):
            out[rows] = model.weights(train, query[rows])
        return out

    def correction(self, theta: np.ndarray, train: np.ndarray, query: np.ndarray, *,
                   color: bool) -> np.ndarray:
        """The surface's part (:meth:`Blend.correction`) where a Blend relights, else 0:
        ``(q, p[, 3])``."""
        out = np.zeros((len(query), len(theta), *((3,) if color else ())), dtype=np.float32)
        for model, rows in self.groups(train, query):
            if isinstance(model, Blend):
                out[rows] = model.correction(theta, train, query[rows], color=color)
        return out


def far_model(name: str) -> Model | Blend | DistanceChoice:
    """The far-light model of a ``method_map`` name."""
    if SEPARATOR in name:
        return DistanceChoice.from_name(name)
    return Blend.from_name(name) if name.startswith(PREFIX) else Model(name)


def surface_blend(model: Model | Blend | DistanceChoice) -> Blend | None:
    """The surface's :class:`~ltmstore.stages.surface.Blend` a far-light model relights with,
    if any."""
    if isinstance(model, DistanceChoice):
        return model.blend
    return model if isinstance(model, Blend) else None


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(a @ b.T, -1.0, 1.0))
