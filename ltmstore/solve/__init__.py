"""Reconstruction methods: one module each, one signature.

Every method is ``solve(samples, geometry, **params) -> ndarray``: ``samples`` is a batch of
binned LTFs of shape ``(n, *lattice)`` (one row per pixel of a tile) with NaN where a cell was not
observed, ``geometry`` a :class:`Geometry` (the lattice and the plane height, for methods that
need cell positions or light directions); the result is float32 of the same shape.

Beside the methods: ``validate`` (held-out error on the cells, which methods use to choose their
parameters), ``select`` (that choice per tile) and ``confidence`` (coverage and expected error
maps). ``solve`` imports only :mod:`ltmstore.core`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ltmstore.core.dims import Lattice
from ltmstore.core.errors import LtmError
from ltmstore.solve import blend, cs, cubic, hsh, kernel, lars, omp, ptm, rbf, svt


@dataclass(frozen=True)
class Geometry:
    """Where the lattice cells are: what position- or direction-based methods need.

    Parameters
    ----------
    lattice : Lattice
        The lattice the samples live on.
    height : float
        Height of the illumination plane above the object (plane units).
    """

    lattice: Lattice
    height: float = 1.0

    @classmethod
    def from_shape(cls, shape: tuple[int, ...], height: float = 1.0) -> Geometry:
        """A lattice of ``shape`` cells over ``[-1, 1]`` along each axis (for arrays alone)."""
        dims = ("r", "s", "p", "q")[: len(shape)]
        return cls(Lattice(bounds=((-1.0, 1.0),) * len(shape), shape=tuple(shape), dims=dims),
                   height)

    @property
    def ndim(self) -> int:
        return len(self.lattice.shape)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.lattice.shape

    def positions(self) -> np.ndarray:
        """Cell centres, ``(M, ndim)``, in C order of the cells."""
        grids = np.meshgrid(*(self.lattice.centres(i) for i in range(self.ndim)), indexing="ij")
        return np.column_stack([g.ravel() for g in grids])

    def directions(self) -> np.ndarray:
        """Unit vectors from the object centre to the light at each cell centre, ``(M, 3)``
        (light axes ``r, s`` only)."""
        rs = self.positions()[:, :2]
        vec = np.column_stack([rs, np.full(len(rs), self.height)])
        return vec / np.linalg.norm(vec, axis=1, keepdims=True)


Method = Callable[..., np.ndarray]

METHODS: dict[str, Method] = {"cs": cs.solve, "lars": lars.solve, "omp": omp.solve,
                              "cubic": cubic.solve, "kernel": kernel.solve, "svt": svt.solve,
                              "ptm": ptm.solve, "hsh": hsh.solve, "rbf": rbf.solve,
                              "blend": blend.solve}
DEFAULT_METHOD = "auto"  # per tile, by held-out error (ltmstore.solve.select.choose_method)


def get_method(name: str) -> Method:
    """The solver called ``name``, or a clear error listing the known ones."""
    try:
        return METHODS[name]
    except KeyError:
        raise LtmError(
            f"unknown method {name!r}; expected one of {', '.join(sorted(METHODS))}"
        ) from None
