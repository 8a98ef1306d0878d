"""Handheld light trajectories over the illumination plane, and the tracker that records them.

A hand scribbles over the plane's bounding box: a smooth random walk whose heading turns, with a
bounded turning rate plus smooth random turning, towards goals spread over the box (so that it
keeps spanning the whole box, as the paper's users do), folded back into the rectangle by mirror
reflection.
Its length is set by the **path density** (trajectory length per unit area, 1/plane-unit, as in
the paper), the hand speed varies smoothly around its mean, and for a few short stretches the hand
leaves the plane (``z`` moves by millimetres to centimetres). The tracker (phone A's SLAM)
reports positions at irregular times (jittered intervals around 60 Hz, occasional dropouts) with
Gaussian noise.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ltmstore.capture.acquisition import Poses
from ltmstore.core.dims import LIGHT_DIMS, Lattice, Plane
from ltmstore.core.errors import LtmError
from ltmstore.synthetic.writer import FPS

WALK_STEP = 1e-3  # metres of arc between samples of the generated walk
TURN_STD = 8.0  # rad/m: standard deviation of the random part of the turning rate
TURN_CORR = 0.04  # metres of arc over which the random turning stays correlated
STEER_GAIN = 30.0  # rad/m per rad: how hard the hand turns towards its current goal
MAX_TURN = 30.0  # rad/m: the sharpest steering turn (radius 3.3 cm)
GOAL_GRID = 4  # goals: one per cell of a 4 x 4 grid over the box, in random order
GOAL_RADIUS = 0.12  # a goal counts as reached within this fraction of the box side
SPEED_VARIATION = 0.35  # log-normal modulation of the hand speed
SPEED_CORR = 0.08  # metres of arc over which the speed stays correlated
SAMPLE_HZ = 240.0  # dense time sampling of the true trajectory


@dataclass(frozen=True, eq=False)
class Trajectory(Poses):
    """Light positions over time (and, for 6D, camera positions on a view plane): the
    :class:`~ltmstore.capture.acquisition.Poses` record, with the geometry a simulation needs.
    """

    def __post_init__(self) -> None:
        n = np.shape(self.t)
        if len(n) != 1 or n[0] < 2:
            raise LtmError(f"trajectory needs at least two samples, got shape {n}")
        for name in ("r", "s", "z", "p", "q"):
            value = getattr(self, name)
            if value is not None and np.shape(value) != n:
                raise LtmError(f"trajectory {name} shape {np.shape(value)} must be {n}")
        if (self.p is None) != (self.q is None):
            raise LtmError("trajectory p and q must be given together")
        if not np.all(np.diff(self.t) > 0):
            raise LtmError("trajectory times must be strictly increasing")

    @property
    def length(self) -> float:
        """Length of the path on the illumination plane, ``sum |d(r, s)|``."""
        return float(np.sum(np.hypot(np.diff(self.r), np.diff(self.s))))

    @property
    def duration(self) -> float:
        """``t[-1] - t[0]``, seconds."""
        return float(self.t[-1] - self.t[0])

    def path_density(self, plane: Plane) -> float:
        """Trajectory length per unit area of ``plane`` (1/plane-unit)."""
        return self.length / plane.area

    def at(self, times) -> tuple[np.ndarray, ...]:
        """Linearly interpolated ``(r, s, z)`` (and ``p, q`` when present) at ``times``."""
        times = np.asarray(times, dtype=np.float64)
        cols = [self.r, self.s, self.z] + ([self.p, self.q] if self.p is not None else [])
        return tuple(np.interp(times, self.t, c) for c in cols)


def check_path_density(path_density: float) -> float:
    """Validate a path density, returning it as a float; one-line :class:`LtmError` otherwise."""
    try:
        value = float(path_density)
    except (TypeError, ValueError):
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise LtmError(f"--path-density {path_density!r} must be a positive number "
                       "(trajectory length per unit area, 1/m)")
    return value


def scribble(plane: Plane, *, path_density: float, seed: int, speed: float = 0.25,
             excursion_fraction: float = 0.03, excursion_depth: tuple[float, float] = (0.005, 0.03),
             view: Plane | None = None, view_speed: float = 0.05) -> Trajectory:
    """A simulated handheld scribble over ``plane``.

    Parameters
    ----------
    plane : Plane
        Illumination plane; the path stays in its rectangle, at ``z = plane.height``.
    path_density : float
        Path length per unit plane area (1/plane-unit); total length ``path_density * area``.
    seed : int
    speed : float
        Mean hand speed, plane units per second (smoothly modulated, about +-35 %).
    excursion_fraction : float
        Fraction of the time spent in short excursions out of the plane.
    excursion_depth : (float, float)
        Range of the peak ``|z - height|`` of an excursion (either side of the plane).
    view : Plane, optional
        For 6D: the camera also wanders over this view plane (at ``view.height``).
    view_speed : float
        Mean camera speed on the view plane.

    Returns
    -------
    Trajectory
        Sampled at 240 Hz from ``t = 0``.
    """
    density = check_path_density(path_density)
    if not (np.isfinite(speed) and speed > 0):
        raise LtmError(f"speed {speed!r} must be a positive number (plane units per second)")
    if not 0 <= excursion_fraction < 0.5:
        raise LtmError(f"excursion_fraction {excursion_fraction!r} must be in [0, 0.5)")
    rng = np.random.default_rng([seed, 101])
    arc, pos = _folded_walk((plane.r, plane.s), density * plane.area, rng)
    arc_time = _hand_clock(arc, speed, rng)
    t = np.arange(0.0, arc_time[-1], 1 / SAMPLE_HZ)
    u = np.interp(t, arc_time, arc)
    r, s = (np.interp(u, arc, c) for c in pos)
    z = plane.height + _excursions(t, excursion_fraction, excursion_depth, rng)
    p = q = None
    if view is not None:
        varc, vpos = _folded_walk((view.r, view.s), view_speed * t[-1], rng)
        p, q = (np.interp(t * view_speed, varc, c) for c in vpos)
    return Trajectory(t=t, r=r, s=s, z=z, p=p, q=q)


def _smooth_noise(n: int, corr: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian noise correlated over about ``corr`` samples, clipped at 3 sigma."""
    noise = ndimage.gaussian_filter1d(rng.standard_normal(n), max(corr, 1e-3), mode="wrap")
    return np.clip(noise / max(noise.std(), 1e-12), -3.0, 3.0)  # short paths: no blow-up


def _folded_walk(bounds, length: float, rng: np.random.Generator):
    """A smooth random walk of ``length`` that keeps spanning the rectangle ``bounds``.

    The hand steers (with a bounded turning rate plus smooth random turning) towards goals drawn
    one per cell of a coarse grid over the rectangle, in a fresh random order every round, so the
    whole box gets covered, as a user does; the path is then folded into the rectangle by mirror
    reflection (length preserving). Returns the arc length ``u (n,)`` and positions ``(2, n)``.
    """
    n = max(2, int(np.ceil(length / WALK_STEP)) + 1)
    arc = np.linspace(0.0, length, n)
    du = arc[1] - arc[0]
    lo, hi = np.array(bounds, dtype=np.float64).T
    wobble = TURN_STD * _smooth_noise(n, TURN_CORR / du, rng)
    goals = _goals(lo, hi, rng)
    pos = np.empty((2, n))
    pos[:, 0] = rng.uniform(lo, hi)
    heading = rng.uniform(0, 2 * np.pi)
    goal = next(goals)
    for i in range(1, n):
        to_goal = goal - pos[:, i - 1]
        if np.hypot(*to_goal) < GOAL_RADIUS * np.min(hi - lo):
            goal = next(goals)
        bearing = np.angle(np.exp(1j * (np.arctan2(to_goal[1], to_goal[0]) - heading)))
        heading += (np.clip(STEER_GAIN * bearing, -MAX_TURN, MAX_TURN) + wobble[i]) * du
        pos[:, i] = pos[:, i - 1] + du * np.array([np.cos(heading), np.sin(heading)])
    return arc, np.stack([_reflect(pos[i], lo[i], hi[i]) for i in range(2)])


def _goals(lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator) -> Iterator[np.ndarray]:
    """Endless goals: one random point per cell of a ``GOAL_GRID`` grid, shuffled each round."""
    cells = np.stack(np.meshgrid(np.arange(GOAL_GRID), np.arange(GOAL_GRID)), -1).reshape(-1, 2)
    while True:
        for cell in rng.permutation(cells):
            yield lo + (cell + rng.uniform(0, 1, 2)) / GOAL_GRID * (hi - lo)


def _reflect(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Fold ``x`` into ``[lo, hi]`` by mirror reflections at the edges."""
    width = hi - lo
    m = np.mod(x - lo, 2 * width)
    return lo + np.where(m > width, 2 * width - m, m)


def _hand_clock(arc: np.ndarray, speed: float, rng: np.random.Generator) -> np.ndarray:
    """Time at each arc-length sample for a smoothly varying speed of mean ``speed``."""
    du = arc[1] - arc[0]
    modulation = np.exp(SPEED_VARIATION * _smooth_noise(len(arc), SPEED_CORR / du, rng))
    dt = du / modulation[:-1]
    dt *= (arc[-1] / speed) / dt.sum()  # mean speed (length / duration) is exactly `speed`
    return np.concatenate([[0.0], np.cumsum(dt)])


def _excursions(t: np.ndarray, fraction: float, depth: tuple[float, float],
                rng: np.random.Generator) -> np.ndarray:
    """Height offsets: a few raised-cosine bumps of 0.2-0.5 s covering ``fraction`` of ``t``."""
    dz = np.zeros_like(t)
    total = fraction * (t[-1] - t[0])
    if total <= 0:
        return dz
    durations = rng.uniform(0.2, 0.5, max(1, int(round(total / 0.3))))
    durations *= total / durations.sum()
    starts = np.sort(rng.uniform(t[0], max(t[0], t[-1] - durations.max()), len(durations)))
    for start, dur in zip(starts, durations, strict=True):
        phase = np.clip((t - start) / dur, 0.0, 1.0)
        amplitude = rng.choice([-1.0, 1.0]) * rng.uniform(*depth)
        dz += amplitude * np.sin(np.pi * phase) ** 2
    return dz


def track(trajectory: Trajectory, *, seed: int, rate_hz: float = 60.0, noise: float = 0.0003,
          jitter: float = 0.3, dropout: float = 0.01, start: float | None = None,
          stop: float | None = None) -> Trajectory:
    """What the phone's tracker records: irregular, noisy samples of ``trajectory``.

    Parameters
    ----------
    trajectory : Trajectory
        The true path.
    seed : int
    rate_hz : float
        Mean reporting rate.
    noise : float
        Standard deviation of the Gaussian position noise on every coordinate, plane units.
    jitter : float
        Coefficient of variation of the intervals between reports (gamma distributed).
    dropout : float
        Probability per report that a burst of 1-10 reports is lost.
    start, stop : float, optional
        Time span of the record (default: the whole trajectory; clipped to it).

    Returns
    -------
    Trajectory
        Reports at strictly increasing, irregular times.
    """
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise LtmError(f"tracker rate {rate_hz!r} must be a positive number (Hz)")
    if not (np.isfinite(noise) and noise >= 0):
        raise LtmError(f"tracker noise {noise!r} must be a non-negative number (plane units)")
    rng = np.random.default_rng([seed, 202])
    t0 = trajectory.t[0] if start is None else max(start, trajectory.t[0])
    t1 = trajectory.t[-1] if stop is None else min(stop, trajectory.t[-1])
    times = _report_times(t0, t1, rate_hz, jitter, dropout, rng)
    coords = trajectory.at(times)
    noisy = [c + rng.normal(0.0, noise, len(times)) for c in coords]
    return Trajectory(times, *noisy)


def _report_times(t0: float, t1: float, rate_hz: float, jitter: float, dropout: float,
                  rng: np.random.Generator) -> np.ndarray:
    n = int(np.ceil((t1 - t0) * rate_hz * 1.5)) + 10
    shape = 1 / max(jitter, 1e-3) ** 2
    times = t0 + np.cumsum(rng.gamma(shape, 1 / (rate_hz * shape), n))
    times = np.concatenate([[t0], times[times <= t1]])
    keep = np.ones(len(times), dtype=bool)
    for i in np.flatnonzero(rng.random(len(times)) < dropout):
        keep[i:i + rng.integers(1, 11)] = False
    keep[0] = True
    return times[keep]


def sampling_ratio(r, s, lattice: Lattice) -> float:
    """``K / M``: the fraction of lattice cells holding at least one position ``(r, s)``."""
    if tuple(lattice.dims) != LIGHT_DIMS:
        raise LtmError(f"sampling_ratio needs an (r, s) lattice, got dims {lattice.dims}")
    cells = lattice.cell_index(np.asarray(r), np.asarray(s))
    return np.unique(cells[cells >= 0]).size / lattice.size


def trajectory_sampling_ratio(trajectory: Trajectory, lattice: Lattice, *,
                              fps: float = FPS) -> float:
    """``K / M`` of a trajectory seen by a video at ``fps`` frames per second."""
    times = np.arange(trajectory.t[0], trajectory.t[-1], 1 / fps)
    r, s, *_ = trajectory.at(times)
    return sampling_ratio(r, s, lattice)
