"""Far-light fits at the exact light directions: PTM, HSH and RBF as linear smoothers.

Every classic RTI model predicts a pixel at a new direction as a fixed linear combination of
that pixel's observations: ``y(d) = w(d) . y_obs``, with weights that depend only on the light
directions (all pixels of a capture share them). So one weight matrix, computed once, fits and
relights every pixel of a capture (or of a tile) at once, and the leave-one-light-out error has a
closed form through the hat matrix ``H = W(train, train)``: ``e_i = (y_i - (H y)_i) / (1 - H_ii)``
(exact for least squares and kernel ridge).

Models (:class:`Model`), smallest first:

* ``ptm``: biquadratic in ``(lx, ly)`` (6 terms; :func:`ltmstore.solve.ptm.ptm_basis`);
* ``hsh2``, ``hsh3``: hemispherical harmonics of order 2 and 3 (9 and 16 terms);
* ``rbf:WIDTH:SMOOTHING``: Gaussian kernel ridge on unit directions plus an unpenalised
  constant (far from every light it tends to that constant, never to 0 or to infinity),
  ``WIDTH`` the kernel's standard deviation (chord length) and ``SMOOTHING`` the ridge added to
  the kernel's unit diagonal; :data:`RBF_WIDTHS` x :data:`RBF_SMOOTHING` are the candidates,
  chosen by leave-one-out;
* ``hsh3+rbf:WIDTH:SMOOTHING``: HSH of order 3 plus the same RBF interpolating its residual
  (the RTI world's HSH + RBF residual fit): ``B(q) c + R(q) (y - B c)`` with ``c`` the HSH
  least-squares coefficients, still linear in ``y``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.hsh import hsh_basis
from ltmstore.solve.ptm import ptm_basis

RBF_WIDTHS = (0.1, 0.15, 0.2, 0.3, 0.45, 0.7)
RBF_SMOOTHING = (1e-3, 1e-2, 1e-1)
TIE = 0.01  # a model within this relative leave-one-out MSE of the best counts as a tie
EXACT = 1e-12  # an MSE below this fraction of the values' mean square is an exact fit
HSH_RBF = "hsh3+rbf"  # family of HSH order 3 plus an RBF of its residual
CACHED_WEIGHTS = 256  # Model.weights kept (a 240-light hat matrix: 0.5 MB)
BASES = {"ptm": ptm_basis, "hsh2": lambda d: hsh_basis(d, 2), "hsh3": lambda d: hsh_basis(d, 3)}


@cache
def _basis_size(family: str) -> int:
    """Terms of a linear basis of :data:`BASES` (asked once per tile and model by the choice)."""
    return BASES[family](np.array([[0.0, 0.0, 1.0]])).shape[1]


@dataclass(frozen=True)
class Model:
    """One far-light model: ``name`` is ``ptm``, ``hsh2``, ``hsh3``, ``rbf:WIDTH:SMOOTHING`` or
    ``hsh3+rbf:WIDTH:SMOOTHING``."""

    name: str

    @property
    def family(self) -> str:
        return self.name.split(":")[0]

    def size(self, n_lights: int) -> int:
        """Number of free coefficients (ties go to the smaller model)."""
        if self.family == "rbf":
            return n_lights + 1
        if self.family == HSH_RBF:
            return n_lights + 1 + _basis_size("hsh3")
        return _basis_size(self.family)

    def weights(self, train: np.ndarray, query: np.ndarray) -> np.ndarray:
        """``(q, n)`` weights: the prediction at ``query (q, 3)`` from observations at
        ``train (n, 3)`` (read-only: the same lights give the same array, computed once while
        it is among the :data:`CACHED_WEIGHTS` last used)."""
        train, query = (np.ascontiguousarray(a, dtype=np.float64) for a in (train, query))
        return _cached_weights(self, train.tobytes(), query.tobytes())

    def _weights(self, train: np.ndarray, query: np.ndarray) -> np.ndarray:
        if self.family in BASES:
            basis = BASES[self.family]
            return basis(query) @ np.linalg.pinv(basis(train))
        if self.family == HSH_RBF:  # HSH, plus the RBF of its residual at the training lights
            basis = BASES["hsh3"]
            coefficients = np.linalg.pinv(basis(train))
            residual = np.eye(len(train)) - basis(train) @ coefficients
            rbf = Model("rbf:" + self.name.split(":", 1)[1]).weights(train, query)
            return basis(query) @ coefficients + rbf @ residual
        if self.family != "rbf":
            raise LtmError(f"unknown far-light model {self.name!r}")
        width, smoothing = (float(v) for v in self.name.split(":")[1:])
        n = len(train)
        # [[K + s I, 1], [1^T, 0]] [alpha; c] = [y; 0]: the interpolant k(q) alpha + c
        system = np.ones((n + 1, n + 1))
        system[:n, :n] = _gaussian(train, train, width) + smoothing * np.eye(n)
        system[n, n] = 0.0
        rows = np.column_stack([_gaussian(query, train, width), np.ones(len(query))])
        return np.linalg.solve(system, rows.T).T[:, :n]

    def hat(self, train: np.ndarray) -> np.ndarray:
        """The ``(n, n)`` hat matrix: fitted values at the training lights."""
        return self.weights(train, train)


@lru_cache(maxsize=CACHED_WEIGHTS)
def _cached_weights(model: Model, train: bytes, query: bytes) -> np.ndarray:
    """:meth:`Model.weights` of directions given as the bytes of ``(n, 3)`` float64 arrays.

    A capture's fit asks for the same weights many times (each fold of
    :func:`ltmstore.stages.surface.cross_validated` scores the residual smoothers, the
    exposures and the blends on the same lights): a 240-light dome's ``reconstruct`` spent
    1.7 s of its threads' time recomputing them."""
    weights = model._weights(*(np.frombuffer(b).reshape(-1, 3) for b in (train, query)))
    weights.flags.writeable = False
    return weights


def _gaussian(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray:
    squared = ((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1)  # as scipy's cdist, exactly
    return np.exp(-squared / (2 * width * width))


def rbf_models() -> list[Model]:
    return [Model(f"rbf:{w:g}:{s:g}") for w in RBF_WIDTHS for s in RBF_SMOOTHING]


def hsh_rbf_models() -> list[Model]:
    """HSH order 3 plus an RBF residual at every width and smoothing of :func:`rbf_models`."""
    return [Model(HSH_RBF + m.name.removeprefix("rbf")) for m in rbf_models()]


@lru_cache(maxsize=1)
def candidates() -> tuple[Model, ...]:
    """Every model ``auto`` chooses among, smallest first."""
    return (Model("ptm"), Model("hsh2"), Model("hsh3"), *rbf_models(), *hsh_rbf_models())


def loo_operator(hat: np.ndarray) -> np.ndarray | None:
    """The ``(n, n)`` matrix ``A`` with ``A @ values`` the leave-one-light-out residuals of a
    linear smoother with hat matrix ``hat``: ``(I - H) / (1 - diag H)`` row-wise; None when a
    light cannot be left out (as many coefficients as lights)."""
    leverage = 1 - np.diag(hat)
    if (leverage < 1e-6).any():
        return None
    return (np.eye(len(hat)) - hat) / leverage[:, None]


def pick(mse: np.ndarray, models: tuple[Model, ...] | list[Model], n_lights: int) -> int:
    """Index of the lowest ``mse``; among those within :data:`TIE` of it, the smallest model.
    An MSE below zero (rounding, where a model fits exactly) counts as zero."""
    mse = np.maximum(mse, 0.0)
    best = int(np.argmin(mse))
    if not np.isfinite(mse[best]):
        return 0
    tied = [i for i in range(len(models)) if mse[i] <= mse[best] * (1 + TIE)]
    return min(tied, key=lambda i: (models[i].size(n_lights), mse[i]))


def choose(values: np.ndarray, train: np.ndarray,
           models: tuple[Model, ...] | list[Model] | None = None) -> tuple[Model, dict[str, float]]:
    """The model with the lowest leave-one-light-out MSE on ``values (n_lights, n_pixels)``
    observed at ``train (n_lights, 3)``; the smaller model wins a tie. Returns it and every
    candidate's MSE.

    The mean of the squared residuals ``A V`` is ``sum((A G) * A) / V.size`` with the Gram
    matrix ``G = V V^T`` (float64): one ``(n, p)`` product in all, then ``n^3`` per model
    instead of ``n^2 p`` (18 RBF smoothers of 4096 pixels: 3x faster). That sum cancels to
    rounding where a model fits exactly (-2.5e-17 against 1e-32 for ``(A V)^2``): below
    :data:`EXACT` of the values' mean square an MSE counts as zero, so exact fits tie.
    """
    models = list(candidates() if models is None else models)
    operators = [loo_operator(m.hat(train)) for m in models]
    flat = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    gram = flat @ flat.T
    mse = np.array([np.inf if a is None else float(np.sum((a @ gram) * a)) / flat.size
                    for a in operators])
    mse[mse <= EXACT * np.trace(gram) / flat.size] = 0.0
    return models[pick(mse, models, len(train))], dict(zip([m.name for m in models], mse,
                                                           strict=True))


def relit(values: np.ndarray, train: np.ndarray, query: np.ndarray, model: Model) -> np.ndarray:
    """``model`` fitted to ``values (n_lights, ...)`` at ``train``, evaluated at ``query (q, 3)``:
    ``(q, ...)``, clipped at 0 (no negative radiance)."""
    flat = values.reshape(len(values), -1)
    out = model.weights(train, query) @ flat
    return np.clip(out, 0, None).reshape(len(query), *values.shape[1:])
