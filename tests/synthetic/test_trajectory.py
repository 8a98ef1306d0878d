"""Handheld trajectories, the tracker and the sampling ratio K/M."""

from __future__ import annotations

import re

import numpy as np
import pytest

from ltmstore.core.dims import Lattice, Plane
from ltmstore.core.errors import LtmError
from ltmstore.synthetic.simulate import DEFAULT_PATH_DENSITY
from ltmstore.synthetic.trajectory import (
    Trajectory,
    sampling_ratio,
    scribble,
    track,
    trajectory_sampling_ratio,
)

PLANE = Plane((-0.2, 0.2), (-0.2, 0.2), 0.3)


@pytest.fixture(scope="module")
def path() -> Trajectory:
    return scribble(PLANE, path_density=30.0, seed=5)


@pytest.fixture(scope="module")
def tracked(path) -> Trajectory:
    return track(path, seed=5)


@pytest.mark.parametrize("density", [5.0, 20.0, 50.0])
def test_achieved_path_density(density):
    path = scribble(PLANE, path_density=density, seed=1)
    assert path.path_density(PLANE) == pytest.approx(density, rel=0.1)
    assert path.length / path.duration == pytest.approx(0.25, rel=0.1)


def test_path_stays_in_the_plane_and_covers_it(path):
    assert np.all(PLANE.contains(path.r, path.s))
    quadrants = {(a, b) for a, b in zip(path.r > 0, path.s > 0, strict=True)}
    assert len(quadrants) == 4
    assert trajectory_sampling_ratio(path, Lattice.from_plane(PLANE, (4, 4))) == 1.0


def test_hand_speed_varies(path):
    speed = np.hypot(np.diff(path.r), np.diff(path.s)) / np.diff(path.t)
    assert speed.mean() == pytest.approx(0.25, rel=0.1)
    assert 0.15 < speed.std() / speed.mean() < 0.8


def test_sampling_ratio_rises_with_density_and_cell_size():
    lattice = Lattice.from_plane(PLANE, (32, 32))
    ratios = [trajectory_sampling_ratio(scribble(PLANE, path_density=d, seed=2), lattice)
              for d in (10.0, 20.0, 40.0)]
    assert ratios[0] < ratios[1] < ratios[2]
    path = scribble(PLANE, path_density=20.0, seed=2)
    by_delta = [trajectory_sampling_ratio(path, Lattice.from_delta(PLANE, d))
                for d in (0.00625, 0.0125, 0.025)]
    assert by_delta[0] < by_delta[1] < by_delta[2]


def test_default_density_gives_the_papers_sampling_ratio():
    lattice = Lattice.from_plane(PLANE, (32, 32))
    paths = [scribble(PLANE, path_density=DEFAULT_PATH_DENSITY, seed=s) for s in range(3)]
    ratios = [trajectory_sampling_ratio(path, lattice) for path in paths]
    assert 0.25 < np.mean(ratios) < 0.35


def test_sampling_ratio_counts_distinct_cells():
    lattice = Lattice.from_plane(PLANE, (4, 4))
    assert sampling_ratio([0.01, 0.02, 0.03], [0.01, 0.01, 0.01], lattice) == 1 / 16
    assert sampling_ratio([-0.15, 0.15, 0.5], [-0.15, 0.15, 0.0], lattice) == 2 / 16


def test_tracker_reports_at_irregular_times(tracked, path):
    dt = np.diff(tracked.t)
    assert np.all(dt > 0) and dt.std() > 0.2 * dt.mean()
    assert len(tracked.t) / tracked.duration == pytest.approx(60, rel=0.15)
    assert dt.max() > 3 / 60  # dropouts
    assert path.t[0] <= tracked.t[0] and tracked.t[-1] <= path.t[-1]


def test_tracker_noise_level(tracked, path):
    true = path.at(tracked.t)
    for got, want in zip((tracked.r, tracked.s), true[:2], strict=True):
        assert np.std(got - want) == pytest.approx(3e-4, rel=0.15)


def test_excursions_out_of_the_plane(path, tracked):
    off = np.abs(path.z - PLANE.height)
    assert 0.01 < np.mean(off > 1e-3) < 0.06
    assert np.max(np.abs(tracked.z - PLANE.height)) > 10 * 3e-4
    assert np.median(np.abs(tracked.z - PLANE.height)) < 3e-4


def test_interpolation_and_determinism(path):
    r, s, z = path.at(path.t[[10, 11]])
    np.testing.assert_array_equal(r, path.r[[10, 11]])
    mid = path.at((path.t[10] + path.t[11]) / 2)[0]
    assert mid == pytest.approx((path.r[10] + path.r[11]) / 2)
    again = scribble(PLANE, path_density=30.0, seed=5)
    np.testing.assert_array_equal(again.r, path.r)


def test_view_path_for_6d():
    view = Plane((-0.05, 0.05), (-0.02, 0.02), 0.5)
    path = scribble(PLANE, path_density=10.0, seed=1, view=view)
    assert np.all(view.contains(path.p, path.q)) and np.ptp(path.p) > 0
    assert len(path.at([0.5])) == 5
    assert track(path, seed=1).p is not None


@pytest.mark.parametrize("bad", [-1.0, 0, float("nan"), "many"])
def test_bad_path_density(bad):
    with pytest.raises(LtmError, match=re.escape(f"--path-density {bad!r} must be a positive")):
        scribble(PLANE, path_density=bad, seed=0)


def test_bad_tracker_and_trajectory_arguments(path):
    with pytest.raises(LtmError, match="tracker rate 0 must be a positive number"):
        track(path, seed=0, rate_hz=0)
    with pytest.raises(LtmError, match="trajectory times must be strictly increasing"):
        Trajectory(np.array([0.0, 0.0]), np.zeros(2), np.zeros(2), np.zeros(2))
    with pytest.raises(LtmError, match=r"excursion_fraction 0.7 must be in \[0, 0.5\)"):
        scribble(PLANE, path_density=1.0, seed=0, excursion_fraction=0.7)


@pytest.mark.parametrize("density", [0.2, 0.5, 1.0])
def test_very_short_paths_do_not_blow_up(density):
    plane = Plane(r=(-0.1, 0.1), s=(-0.2, 0.2), height=0.3)
    path = scribble(plane, path_density=density, seed=0)
    assert np.isfinite(path.t).all() and path.path_density(plane) == pytest.approx(density, 0.1)
