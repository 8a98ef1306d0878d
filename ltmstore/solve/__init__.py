"""Reconstruction methods: one module each, one signature.

Every method is ``solve(samples, geometry, **params) -> ndarray``: ``samples`` is a batch of
binned LTFs of shape ``(n, *lattice)`` (one row per pixel of a tile) with NaN where a cell was not
observed, ``geometry`` a :class:`Geometry` (the lattice and the plane height, for methods that
need cell positions or light directions, and where the acquisition declares the object's
extent, each row's position on the object plane, for methods that model the near light per
pixel); the result is float32 of the same shape.

Beside the methods: ``validate`` (held-out error on the cells, which methods use to choose their
parameters), ``select`` (that choice per tile) and ``confidence`` (coverage and expected error
maps). ``solve`` imports only :mod:`ltmstore.core`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace

import numpy as np

from ltmstore.core.dims import Lattice
from ltmstore.core.errors import LtmError


@dataclass(frozen=True, eq=False)
class Geometry:
    """Where the lattice cells are: what position- or direction-based methods need.

    Parameters
    ----------
    lattice : Lattice
        The lattice the samples live on.
    height : float
        Height of the illumination plane above the object (plane units).
    pixels : ndarray of shape (n, 2), optional
        Object-plane position ``(X, Y)`` of the pixel of each row of the batch (plane units,
        the axes of ``r, s``); ``None`` where the acquisition does not declare the object's
        extent and the capture cannot place it (:mod:`ltmstore.stages.placement`). A method
        that slices rows of a batch slices these with :meth:`take`.
    led_exponent : float
        ``k`` of the near light's ``cos^k`` emission about its axis (straight down, or each
        cell's :attr:`led_axis` where a model fits the samples), one value per capture
        (:func:`ltmstore.stages.reconstruct.led_beam`); 0: no beam.
    sampled : ndarray of shape (M, ndim), optional
        Where each cell's samples were taken: the mean light position of the frames binned into
        it (NaN where none), in C order of the cells. A cell's sample is the mean of frames
        anywhere inside it; a model that fits light positions fits it there, not at the centre.
    led_axis : ndarray of shape (M, 3), optional
        The LED's mean axis over the frames binned into each cell (unit vectors in plane
        coordinates, NaN where none), where the poses give it: a hand's wobble tilts the beam
        of each cell's samples; a model that fits them fits each cell's beam about its own axis
        and relights with the LED held level (straight down). None: level everywhere.
    segment : ndarray of shape (M,), optional
        The stretch of a handheld capture (a second of its video) in which each cell took most
        of its frames, -1 where none (:func:`ltmstore.core.binning.segments`): the held-out
        choice of a regularisation hides whole stretches together.
    """

    lattice: Lattice
    height: float = 1.0
    pixels: np.ndarray | None = None
    led_exponent: float = 0.0
    sampled: np.ndarray | None = None
    led_axis: np.ndarray | None = None
    segment: np.ndarray | None = None

    def take(self, rows: np.ndarray) -> Geometry:
        """The geometry of the batch rows ``rows`` (the same lattice; their pixel positions)."""
        return self if self.pixels is None else replace(self, pixels=self.pixels[rows])

    def with_pixels(self, pixels: np.ndarray | None) -> Geometry:
        """The same lattice with the object-plane positions ``pixels (n, 2)`` of a batch."""
        return replace(self, pixels=None if pixels is None else np.asarray(pixels, float))

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

    def sample_positions(self) -> np.ndarray:
        """Where each cell's samples were taken (:attr:`sampled`), the cell's centre where
        unknown, ``(M, ndim)``."""
        centres = self.positions()
        if self.sampled is None:
            return centres
        return np.where(np.isfinite(self.sampled), self.sampled, centres)

    def directions(self) -> np.ndarray:
        """Unit vectors from the object centre to the light at each cell centre, ``(M, 3)``
        (light axes ``r, s`` only)."""
        rs = self.positions()[:, :2]
        vec = np.column_stack([rs, np.full(len(rs), self.height)])
        return vec / np.linalg.norm(vec, axis=1, keepdims=True)


Method = Callable[..., np.ndarray]


class Registry(Mapping):
    """Method name -> ``solve`` function, each module imported on first use: a caller that
    needs one method (or only the names: the CLI's choices) does not pay for the others'
    imports (SciPy's FFT, scikit-learn)."""

    def __init__(self, modules: dict[str, str]) -> None:
        self._modules = dict(modules)

    def __getitem__(self, name: str) -> Method:
        module = self._modules[name]  # KeyError for an unknown name, as a dict
        return importlib.import_module(f"ltmstore.solve.{module}").solve

    def __iter__(self) -> Iterator[str]:
        return iter(self._modules)

    def __len__(self) -> int:
        return len(self._modules)


# One line per method: its name and its module in ltmstore.solve (which defines ``solve``).
METHODS: Mapping[str, Method] = Registry({
    "cs": "cs", "lars": "lars", "omp": "omp", "cubic": "cubic", "kernel": "kernel",
    "svt": "svt", "ptm": "ptm", "hsh": "hsh", "rbf": "rbf", "blend": "blend",
    "physical": "physical"})
DEFAULT_METHOD = "auto"  # per tile, by held-out error (ltmstore.solve.select.choose_method)


def get_method(name: str) -> Method:
    """The solver called ``name``, or a clear error listing the known ones."""
    try:
        return METHODS[name]
    except KeyError:
        raise LtmError(
            f"unknown method {name!r}; expected one of {', '.join(sorted(METHODS))}"
        ) from None
