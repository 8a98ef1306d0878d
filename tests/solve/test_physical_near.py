"""The compiled near-light Levenberg-Marquardt and the cached RBF operator against the NumPy
paths they replace."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ltmstore.core.dims import Lattice
from ltmstore.solve import Geometry, physical, physical_near, rbf


def near_pixels(n: int = 200, seed: int = 0) -> tuple[physical.Lights, np.ndarray, np.ndarray]:
    """Near lights of a 16 x 16 lattice 0.3 above ``n`` pixels spread over a 10 cm object,
    pixel values ``(n, 256)`` (float32) of random GGX surfaces with 1 % noise, true
    parameters ``(n, 6)``."""
    rng = np.random.default_rng(seed)
    lattice = Lattice(bounds=((-0.2, 0.2), (-0.2, 0.2)), shape=(16, 16), dims=("r", "s"))
    geometry = Geometry(lattice, 0.3, rng.uniform(-0.05, 0.05, (n, 2)))
    lights = physical.near_lights(geometry, led_exponent=1.0)
    theta = np.column_stack([rng.uniform(-0.4, 0.4, (n, 2)), rng.uniform(0.2, 0.7, n),
                             rng.uniform(0.05, 0.3, n), np.log(rng.uniform(0.1, 0.5, n)),
                             np.full(n, 0.01)])
    values = physical._model(theta, lights) * (1 + 0.01 * rng.standard_normal((n, 256)))
    return lights, values.astype(np.float32), theta


def test_the_compiled_steps_are_numpys(monkeypatch):
    """Same starts, same iterations: the parameters agree to float32 rounding (measured 1e-7
    median on all six, costs 1e-6 relative), and the fit finds the truth."""
    lights, y, truth = near_pixels()
    w = (np.random.default_rng(1).random(y.shape) > 0.4).astype(np.float32)  # a sparse mask
    start = physical._starts(lights, y, w)[0]
    compiled, cost = physical.levenberg_marquardt(start, lights, y, w)
    monkeypatch.setattr(physical, "COMPILED", False)
    reference, cost_ref = physical.levenberg_marquardt(start, lights, y, w)
    assert np.median(np.abs(compiled - reference)) < 1e-5
    assert np.median(np.abs(cost / cost_ref - 1)) < 1e-3
    monkeypatch.setattr(physical, "COMPILED", True)
    fitted, _ = physical.fit_parameters(y, w, lights)
    assert np.median(np.abs(fitted[:, :2] - truth[:, :2])) < 0.02  # slopes; measured 0.003


def test_the_kernel_keeps_the_models_bounds():
    assert np.isclose(np.exp(physical_near.LOG_ALPHA), physical.ALPHA_RANGE).all()
    assert physical_near.SLOPE_MAX == physical.SLOPE_MAX
    lights, y, _ = near_pixels(20)
    start = np.zeros((20, 6))
    start[:, :2] = 10.0  # far outside: clipped first, as NumPy's
    out, _ = physical.levenberg_marquardt(start, lights, y, np.ones_like(y), n_iter=2)
    assert np.abs(out[:, :2]).max() <= physical.SLOPE_MAX


@pytest.mark.parametrize("rows", [40, 300])  # solved directly, and through the operator
def test_the_rbf_operator_interpolates_as_the_direct_solve(rows):
    """A shared mask of 120 cells: the cached operator (float32) gives the direct thin-plate
    interpolant to float32 rounding (measured 3e-7 of the range), and the same call the same
    values whether it is cached or not."""
    rng = np.random.default_rng(2)
    geometry = Geometry.from_shape((16, 16), height=0.8)
    samples = rng.random((rows, 16, 16))
    samples[:, rng.random((16, 16)) > 120 / 256] = np.nan
    points = geometry.directions()[:, :2]
    params = {"kernel": "thin_plate_spline", "smoothing": 0.0, "epsilon": None, "degree": None,
              "neighbors": None}
    cells = np.isfinite(samples[0]).ravel()
    values = samples.reshape(rows, -1)[:, cells].T
    direct = rbf.interpolate(points, points[cells], values, **{**params, "epsilon": 1.0})
    rbf._OPERATORS.clear()
    first = rbf.solve(samples, geometry)
    assert np.abs(first.reshape(rows, -1).T - direct).max() < 1e-5
    np.testing.assert_array_equal(rbf.solve(samples, geometry), first)
    assert len(rbf._OPERATORS) == (rows >= 60)  # through the operator for K / 2 rows or more


@pytest.mark.parametrize("exponent", [0.0, 1.5])
def test_the_compiled_model_values_are_numpys(monkeypatch, exponent):
    """The compiled model values at near lights equal the NumPy ones to float32 rounding
    (measured 3e-7 of the largest value), sharp lobes included."""
    rng = np.random.default_rng(3)
    lattice = Lattice(bounds=((-0.2, 0.2), (-0.2, 0.2)), shape=(16, 16), dims=("r", "s"))
    geometry = Geometry(lattice, 0.3, rng.uniform(-0.05, 0.05, (50, 2)))
    lights = physical.near_lights(geometry, led_exponent=exponent)
    theta = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.random(50), rng.random(50),
                             np.log(rng.uniform(0.02, 1.0, 50)), 0.1 * rng.random(50)])
    values = physical._model(theta, lights)
    monkeypatch.setattr(physical, "COMPILED", False)
    reference = physical._model(theta, lights)
    assert values.dtype == reference.dtype == np.float32
    assert np.abs(values - reference).max() < 1e-5 * np.abs(reference).max()


@pytest.mark.parametrize("exponent", [0.0, 1.5])
@pytest.mark.parametrize("tilted", [False, True])
def test_the_compiled_lights_are_numpys(monkeypatch, exponent, tilted):
    """The compiled near lights equal NumPy's: the same operations in the same order, bit for
    bit but the fall-off's power (measured 9e-8 of the largest value at exponent 1.5), with
    the LED held level or tilted per cell (``led_axis``, a cell unknown: level there)."""
    rng = np.random.default_rng(6)
    lattice = Lattice(bounds=((-0.2, 0.2), (-0.3, 0.1)), shape=(12, 20), dims=("r", "s"))
    axis = None
    if tilted:
        axis = np.column_stack([rng.normal(0, 0.05, (240, 2)), -np.ones(240)])
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        axis[7] = np.nan
    geometry = Geometry(lattice, 0.3, rng.uniform(-0.05, 0.05, (40, 2)), led_axis=axis)
    compiled = physical.near_lights(geometry, led_exponent=exponent, sampled=True)
    monkeypatch.setattr(physical, "COMPILED", False)
    reference = physical.near_lights(geometry, led_exponent=exponent, sampled=True)
    assert np.array_equal(compiled.toward, reference.toward)
    assert np.array_equal(compiled.half, reference.half)
    assert compiled.g.dtype == reference.g.dtype == np.float32
    assert np.abs(compiled.g - reference.g).max() <= 2e-7 * reference.g.max()
    level = physical.near_lights(replace(geometry, led_axis=None), led_exponent=exponent)
    assert np.array_equal(level.g[:, 7], reference.g[:, 7])  # the unknown axis: level
    if tilted and exponent:  # tilts of 3.7 degrees on average: up to 20 % (measured 0.202)
        assert np.abs(reference.g / level.g - 1).max() > 0.15
    else:
        np.testing.assert_array_equal(reference.g, level.g)


def test_a_warm_start_costs_fewer_iterations_and_lands_near_the_cold_fit(monkeypatch):
    """From the fit on all cells, the fit on 90 % of them takes WARM_ITER steps and the robust
    refit instead of two starts and N_ITER more (10 iterations against 25), and lands within
    the noise of the cold fit (slopes: measured median 5e-6 apart)."""
    lights, y, _ = near_pixels()
    w = (np.random.default_rng(4).random(y.shape) > 0.4).astype(np.float32)
    full, _ = physical.fit_parameters(y, w, lights)
    fewer = w * (np.random.default_rng(5).random(y.shape) > 0.1)
    steps = []
    solve = physical.levenberg_marquardt

    def counted(theta, lights, y, w, *, n_iter):
        steps.append(n_iter)
        return solve(theta, lights, y, w, n_iter=n_iter)

    monkeypatch.setattr(physical, "levenberg_marquardt", counted)
    cold, _ = physical.fit_parameters(y, fewer, lights)
    cold_steps, steps[:] = sum(steps), []
    warm, _ = physical.fit_parameters(y, fewer, lights, start=full)
    assert (cold_steps, sum(steps)) == (25, 10)
    assert np.median(np.abs(warm[:, :2] - cold[:, :2])) < 1e-3


@pytest.mark.parametrize("rows", [40, 300])  # rbf solved directly, and through the operator
def test_a_fold_predicts_its_hidden_cells_alone_with_the_same_values(rows):
    """``at``: the physical model and rbf computed at a held-out fold's cells only give the
    values of the whole lattice there (the operator's rows: to float32 rounding), and the
    held-out error is the same as from the whole prediction."""
    from ltmstore.solve.validate import heldout_error

    rng = np.random.default_rng(7)
    lattice = Lattice(bounds=((-0.2, 0.2), (-0.2, 0.2)), shape=(16, 16), dims=("r", "s"))
    geometry = Geometry(lattice, 0.3, rng.uniform(-0.05, 0.05, (rows, 2)))
    values = physical._model(near_pixels(rows)[2], physical.near_lights(geometry))
    samples = values.reshape(rows, 16, 16).astype(np.float32)
    samples[:, rng.random((16, 16)) > 0.4] = np.nan
    at = np.flatnonzero(~np.isfinite(samples[0]).ravel())[::3]
    for solve in (physical.solve, rbf.solve):
        whole = solve(samples, geometry).reshape(rows, -1)[:, at]
        part = solve(samples, geometry, at=at)
        assert part.shape == (rows, len(at))
        np.testing.assert_allclose(part, whole, rtol=0, atol=1e-6 * np.abs(whole).max())
        full = heldout_error(samples, geometry, lambda s, g, f=solve, **p: f(s, g, **p), folds=2)
        fast = heldout_error(samples, geometry, solve, folds=2)
        np.testing.assert_allclose(fast.rms, full.rms, rtol=1e-5)


def test_the_near_lights_of_the_same_pixels_are_kept_read_only():
    rng = np.random.default_rng(8)
    lattice = Lattice(bounds=((-0.2, 0.2), (-0.2, 0.2)), shape=(16, 16), dims=("r", "s"))
    pixels = rng.uniform(-0.05, 0.05, (30, 2))
    first = physical.near_lights(Geometry(lattice, 0.3, pixels))
    assert physical.near_lights(Geometry(lattice, 0.3, pixels.copy())) is first
    assert physical.near_lights(Geometry(lattice, 0.31, pixels)) is not first
    assert physical.near_lights(Geometry(lattice, 0.3, pixels), led_exponent=1.0) is not first
    with pytest.raises(ValueError, match="read-only"):
        first.g[0, 0] = 1.0
