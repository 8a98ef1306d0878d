"""Failure regimes at the samples level: binned LTFs with their per-cell truth.

Shared by ``tests/solve/test_stability.py`` and ``bench/stability_table.py``. A regime is a
ground-truth LTM rendered on a small lattice, a handheld trajectory seen by a 30 fps video, and a
recipe for what goes wrong between the light and the binned samples:

=============  ===========================================================================
benign         canvas scene, K/M about 0.35 (the paper: 0.29), exact positions, no noise
sparse         a very short path: K/M below 0.05
half_empty     the hand never leaves one half of the plane (the other half has no sample)
shadows        relief scene: hard cast shadows (a raised frame, a block and a boss)
saturated      every frame clipped at 40 % of the truth's peak (blown highlights)
noise          sensor noise, 3 % of the peak per frame, before binning
jitter         tracker error: 6 mm Gaussian noise on the recorded positions before binning
occluded       the phone hides the painting for 20 % of the frames in a row (dark frames)
lossy          (:func:`lossy_regime`) a simulated mp4v capture, ingested and binned for real
=============  ===========================================================================

Frames carry the truth of the lattice cell the light really is in (a piecewise-constant LTF:
with exact positions and no noise, every observed sample equals the truth at its cell), so the
only errors are the regime's. Everything is seeded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import dask.array as da
import numpy as np

from ltmstore.core.dims import LUMA, Lattice, Plane
from ltmstore.solve import Geometry
from ltmstore.stages.resample import bin_frames, bin_positions
from ltmstore.synthetic.render import render_ltm
from ltmstore.synthetic.scenes import make_scene
from ltmstore.synthetic.simulate import EXPOSURE_PEAK, PLANE
from ltmstore.synthetic.trajectory import scribble
from ltmstore.synthetic.writer import FPS


@dataclass(frozen=True)
class RegimeSpec:
    """How the samples of one regime are made (see the module docstring).

    Parameters
    ----------
    scene : str
        Built-in scene rendered as the truth.
    path_density : float
        Trajectory length per unit area of the region the hand covers (1/m).
    half_plane : bool
        The hand stays in the half ``r < centre`` of the plane.
    jitter : float
        Standard deviation of the tracker error added to each recorded position (plane units).
    noise : float
        Standard deviation of the per-frame sensor noise, as a fraction of the truth's peak.
    saturate : float or None
        Clip every frame at this fraction of the truth's peak.
    occlude : float
        Fraction of the frames, in one consecutive run, replaced by a dark frame.
    """

    scene: str = "canvas"
    path_density: float = 14.0
    half_plane: bool = False
    jitter: float = 0.0
    noise: float = 0.0
    saturate: float | None = None
    occlude: float = 0.0


BENIGN = RegimeSpec()
REGIMES: dict[str, RegimeSpec] = {
    "benign": BENIGN,
    "sparse": replace(BENIGN, path_density=1.0),
    "half_empty": replace(BENIGN, half_plane=True),
    "shadows": replace(BENIGN, scene="relief"),
    "saturated": replace(BENIGN, saturate=0.4),
    "noise": replace(BENIGN, noise=0.03),
    "jitter": replace(BENIGN, jitter=0.006),
    "occluded": replace(BENIGN, occlude=0.2),
}
DARK = 0.002  # linear value of an occluded frame (about 1 % of sRGB full scale)


@dataclass(frozen=True, eq=False)
class Regime:
    """Binned samples of one regime and the truth on the same lattice.

    Attributes
    ----------
    name : str
    samples : ndarray, shape (n, R, S), float32
        Binned means, NaN where unobserved; one row per pixel (C order over ``(y, x)``).
    truth : ndarray, shape (n, R, S), float32
        The ground-truth LTFs at the cell centres.
    geometry : Geometry
    image : (int, int)
        Pixel rows and columns of the image the rows come from.
    """

    name: str
    samples: np.ndarray
    truth: np.ndarray
    geometry: Geometry
    image: tuple[int, int]

    @property
    def ratio(self) -> float:
        """``K / M`` of the (shared) sampling mask."""
        return float(np.isfinite(self.samples).any(axis=0).mean())

    def subset(self, rows: np.ndarray) -> Regime:
        """The same regime restricted to some pixels (rows of the batch)."""
        return replace(self, samples=self.samples[rows], truth=self.truth[rows],
                       geometry=self.geometry.take(rows))


def scene_pixels(size: int) -> np.ndarray:
    """Object-plane ``(X, Y)`` of the pixels of a built-in scene of ``size`` pixels a side,
    ``(size * size, 2)`` in C order over ``(y, x)`` (what ``Geometry.pixels`` holds)."""
    x, y = make_scene("canvas", size=size).pixel_centres()
    return np.column_stack([x.ravel(), y.ravel()])


def regime_lattice(shape: tuple[int, int] = (16, 16), plane: Plane = PLANE) -> Lattice:
    """The lattice the regimes live on: ``shape`` cells over the simulator's plane."""
    return Lattice.from_plane(plane, shape)


def render_truth(scene: str, lattice: Lattice, *, size: int = 16, seed: int = 0,
                 plane: Plane = PLANE) -> np.ndarray:
    """Luminance LTM ``(size, size, R, S)`` float32 of a built-in scene, peak scaled to 0.9."""
    rgb = render_ltm(make_scene(scene, size=size, seed=seed), lattice, plane.height)
    lum = rgb @ LUMA.astype(np.float32)
    return lum * np.float32(EXPOSURE_PEAK / float(lum.max()))


def frame_positions(spec: RegimeSpec, *, seed: int = 0,
                    plane: Plane = PLANE) -> tuple[np.ndarray, np.ndarray]:
    """True light positions ``(r, s)`` at the video frame times of the regime's trajectory."""
    region = plane
    if spec.half_plane:
        region = replace(plane, r=(plane.r[0], 0.5 * (plane.r[0] + plane.r[1])))
    path = scribble(region, path_density=spec.path_density, seed=seed)
    times = np.arange(path.t[0], path.t[-1], 1 / FPS)
    r, s, _ = path.at(times)
    return r, s


def make_regime(name: str, spec: RegimeSpec, truth: np.ndarray, lattice: Lattice, *,
                seed: int = 0, plane: Plane = PLANE) -> Regime:
    """Build one regime's samples from a truth LTM ``(H, W, *lattice)``.

    Each frame takes the truth of the cell the light truly is in, goes through the regime's
    corruptions (noise, clipping, occlusion), and is binned at its *recorded* position (with the
    tracker error) by :func:`ltmstore.stages.resample.bin_frames`.
    """
    rng = np.random.default_rng([seed, 505])
    image = truth.shape[:2]
    r, s = frame_positions(spec, seed=seed, plane=plane)
    cell = lattice.cell_index(r, s)
    frames = np.moveaxis(truth.reshape(*image, -1)[..., cell], -1, 0)  # (t, y, x)
    frames = _corrupt(frames, spec, float(truth.max()), rng)
    recorded = (r + rng.normal(0, spec.jitter, r.shape), s + rng.normal(0, spec.jitter, s.shape))
    samples = _bin(frames, bin_positions(lattice, recorded))
    geometry = Geometry(lattice=lattice, height=plane.height, pixels=scene_pixels(image[0]))
    return Regime(name=name, samples=samples.reshape(-1, *lattice.shape),
                  truth=truth.reshape(-1, *lattice.shape).astype(np.float32),
                  geometry=geometry, image=image)


def _corrupt(frames: np.ndarray, spec: RegimeSpec, peak: float,
             rng: np.random.Generator) -> np.ndarray:
    frames = frames.astype(np.float32, copy=True)
    if spec.noise:
        frames += rng.normal(0, spec.noise * peak, frames.shape).astype(np.float32)
    if spec.saturate is not None:
        np.minimum(frames, np.float32(spec.saturate * peak), out=frames)
    if spec.occlude:
        run = int(round(spec.occlude * len(frames)))
        start = int(rng.integers(0, len(frames) - run + 1))
        frames[start:start + run] = DARK
    return frames


def _bin(frames: np.ndarray, binning) -> np.ndarray:
    lazy = da.from_array(frames, chunks=(256, -1, -1))
    return np.asarray(bin_frames(lazy, binning).compute(), dtype=np.float32)


def build_regimes(names: list[str] | None = None, *, size: int = 16,
                  lattice: tuple[int, int] = (16, 16), seed: int = 0) -> dict[str, Regime]:
    """All the rendered regimes of :data:`REGIMES` (or ``names``), each scene rendered once."""
    grid = regime_lattice(lattice)
    names = list(REGIMES) if names is None else names
    truths: dict[str, np.ndarray] = {}
    out = {}
    for name in names:
        spec = REGIMES[name]
        if spec.scene not in truths:
            truths[spec.scene] = render_truth(spec.scene, grid, size=size, seed=seed)
        out[name] = make_regime(name, spec, truths[spec.scene], grid, seed=seed)
    return out


def lossy_regime(folder: str | os.PathLike, *, size: int = 24, lattice: tuple[int, int] = (16, 16),
                 seed: int = 1, path_density: float = 14.0) -> Regime:
    """A simulated lossy (mp4v) capture, ingested and binned by the library: the real path.

    The relief scene is simulated into ``folder/acquisition``, ingested into
    ``folder/store.zarr``, and its valid frames binned onto the truth's lattice.
    """
    from ltmstore.core.store import open_store
    from ltmstore.stages.ingest import ingest
    from ltmstore.synthetic.simulate import simulate_acquisition

    folder = Path(folder)
    acq, store = folder / "acquisition", folder / "store.zarr"
    simulate_acquisition(acq, scene="relief", size=size, seed=seed, lattice=lattice,
                         path_density=path_density, lossy=True, progress=False, overwrite=True)
    ingest(acq, store, progress=False, overwrite=True)
    ds = open_store(store)
    grid = regime_lattice(lattice)
    binning = bin_positions(grid, (ds["pose_r"].values, ds["pose_s"].values),
                            ds["pose_valid"].values)
    samples = np.asarray(bin_frames(ds["frames"].data, binning).compute(), dtype=np.float32)
    truth = open_store(acq / "truth.zarr")["ltm"].values
    return Regime(name="lossy", samples=samples.reshape(-1, *grid.shape),
                  truth=truth.reshape(-1, *grid.shape).astype(np.float32),
                  geometry=Geometry(lattice=grid, height=PLANE.height, pixels=scene_pixels(size)),
                  image=truth.shape[:2])


def observed_scale(samples: np.ndarray) -> np.ndarray:
    """Per-pixel scale of the observations, ``(n,)``: ``max(max - min, max |b|)``.

    The observed range alone degenerates when the few observed cells are nearly equal (a very
    short path through a dim region): the truth can then peak many ranges away.
    """
    flat = np.asarray(samples, dtype=np.float64).reshape(len(samples), -1)
    observed = np.isfinite(flat)
    hi = np.where(observed, flat, -np.inf).max(axis=1)
    lo = np.where(observed, flat, np.inf).min(axis=1)
    peak = np.where(observed, np.abs(flat), 0.0).max(axis=1)
    return np.where(observed.any(axis=1), np.maximum(hi - lo, peak), np.nan)


def overshoot(samples: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """How far each pixel's estimate leaves its observed ``[min, max]``, in units of
    :func:`observed_scale`, ``(n,)`` (0 inside; NaN for a pixel with no observation)."""
    flat = np.asarray(samples, dtype=np.float64).reshape(len(samples), -1)
    est = np.asarray(estimate, dtype=np.float64).reshape(len(samples), -1)
    observed = np.isfinite(flat)
    hi = np.where(observed, flat, -np.inf).max(axis=1)
    lo = np.where(observed, flat, np.inf).min(axis=1)
    over = np.maximum(np.maximum(lo - est.min(axis=1), est.max(axis=1) - hi), 0.0)
    scale = observed_scale(samples)
    with np.errstate(invalid="ignore", divide="ignore"):
        return over / np.where(scale > 0, scale, 1.0)
