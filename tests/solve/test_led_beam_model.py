"""The LED as it is (issue 63): the near-light model's ``cos^k`` beam, and its ``k`` chosen by
held-out error.

A 16 x 16 px canvas on a 16 x 16 lattice (the stability regimes' benign handheld path,
``ltmstore.synthetic.regimes``) rendered with the LED pointing straight down and emitting
``cos^2`` of the angle off its axis (``Shading.led_exponent``), and without a beam.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ltmstore.core.dims import LUMA
from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import physical
from ltmstore.stages.surface import (
    choose_led_exponent,
    refine_led_exponent,
    refined_exponents,
    wobble_exponent,
)
from ltmstore.synthetic.regimes import (
    EXPOSURE_PEAK,
    PLANE,
    REGIMES,
    Regime,
    make_regime,
    regime_lattice,
)
from ltmstore.synthetic.render import GGX, render_ltm
from ltmstore.synthetic.scenes import make_scene


def _canvas(led_exponent: float, size: int = 16) -> Regime:
    grid = regime_lattice((16, 16))
    rgb = render_ltm(make_scene("canvas", size=size, seed=0), grid, PLANE.height,
                     shading=replace(GGX, led_exponent=led_exponent))
    lum = rgb @ LUMA.astype(np.float32)
    truth = lum * np.float32(EXPOSURE_PEAK / float(lum.max()))
    return make_regime("benign", REGIMES["benign"], truth, grid, seed=0)


@pytest.fixture(scope="module")
def level_beam() -> Regime:
    return _canvas(2.0)


def test_a_level_beam_is_found_and_modelled(level_beam):
    """Measured: k = 2.5 chosen (held-out error 0.0016 against 0.047 at k = 0, five folds; k = 2
    scores 0.0022 and its SNR 54.9 dB); SNR 54.5 dB against 27.6 without the beam."""
    r = level_beam
    k, record = choose_led_exponent(r.samples, r.geometry)
    assert 1.5 <= k <= 3.0, record
    assert record["source"] == "heldout" and record["errors"]["0"] > 5 * min(
        record["errors"].values()), record
    without = snr_db(r.truth, physical.solve(r.samples, r.geometry))
    beamed = replace(r.geometry, led_exponent=k)
    ours = snr_db(r.truth, physical.solve(r.samples, beamed))
    assert ours > 50 and ours > without + 22, (ours, without)
    # the geometry's exponent is the solver's default: the same as passing it
    explicit = physical.solve(r.samples, r.geometry, led_exponent=k)
    np.testing.assert_array_equal(physical.solve(r.samples, beamed), explicit)


@pytest.mark.parametrize("size", [16, 32])
def test_without_a_beam_the_choice_costs_nothing(size):
    """Beam-free canvases. Measured (five folds): at 16 px k = 0.5 is chosen (held-out error
    0.0011 against 0.0027 at k = 0) and relights above k = 0 (56.67 against 52.51 dB); at 32 px
    k = 1 scores 17 % lower than k = 0 but relights 6.1 dB below it (47.03 against 53.12 dB):
    under the 25 % margin k stays 0 (a 10 % margin, or two folds, took k = 1)."""
    r = _canvas(0.0, size)
    k, record = choose_led_exponent(r.samples, r.geometry)
    assert k <= 0.5, record
    plain = snr_db(r.truth, physical.solve(r.samples, r.geometry))
    chosen = snr_db(r.truth, physical.solve(r.samples, replace(r.geometry, led_exponent=k)))
    assert chosen > plain - 0.1, (chosen, plain, record)
    if size == 32:
        errors = record["errors"]
        assert k == 0.0 and errors["1"] < 0.9 * errors["0"], record
        beamed = snr_db(r.truth, physical.solve(r.samples, replace(r.geometry, led_exponent=1.0)))
        assert plain > beamed + 5, (plain, beamed)


@pytest.mark.parametrize(("beam", "expected"), [
    ({"exponent": 2.0, "source": "profile", "stderr": 0.73, "exponent_rgb": [2.33, 2.36, 2.38]},
     2.3567),
    ({"exponent": 2.0, "source": "profile", "stderr": 0.0, "exponent_rgb": [0.0, 0.0, 0.0]}, 0.0),
    ({"exponent": 2.0, "source": "profile", "stderr": None, "exponent_rgb": None}, 0.0),
    ({"exponent": 2.0, "source": "profile", "stderr": 3.1, "exponent_rgb": [9.0, 7.5, 8.0]}, 4.0),
    # a beam-free canvas tracked from the painting: 1.6 standard errors above 0, no beam
    ({"exponent": 2.0, "source": "profile", "stderr": 0.44, "exponent_rgb": [0.52, 0.73, 0.85]},
     0.0),
    ({}, 0.0),
])
def test_the_wobbles_measure_is_the_default(beam, expected):
    """What ingest measured from the axis's wobble, however uncertain, where it stands two
    standard errors above no beam; else, or nothing measured: 0."""
    assert wobble_exponent(beam) == pytest.approx(expected, abs=1e-4)


def test_the_default_is_kept_unless_clearly_worse(level_beam):
    """From the level cos^2 beam's default k = 2: k = 2.5 scores 0.0016 against 0.0022 (27 %
    lower), so it is taken; from k = 0 (0.047) too; from k = 3 (0.0044) as well."""
    r = level_beam
    for default in (0.0, 2.0, 3.0):
        k, record = choose_led_exponent(r.samples, r.geometry, default=default)
        assert k == 2.5 and record["default"] == default, record
    k, record = choose_led_exponent(r.samples, r.geometry, default=2.4)
    assert k == 2.4, record


def _wobbled(r: Regime, tilt_deg: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The regime's samples (its LED held level) as an LED tilted about ``tilt_deg`` RMS per
    axis, its own tilt in each cell, gives them: each sample times ``(cos a / cos a0)^2``,
    ``a`` and ``a0`` the angles between the tilted and the level axis and the direction from
    the light to the pixel; and each cell's axis ``(M, 3)``."""
    rng = np.random.default_rng(seed)
    g = r.geometry
    m = g.lattice.size
    axis = np.column_stack([np.radians(tilt_deg) * rng.standard_normal((m, 2)), -np.ones(m)])
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    d = np.concatenate([g.pixels[:, None, :] - g.positions()[None, :, :2],
                        np.full((len(g.pixels), m, 1), -g.height)], axis=-1)
    length = np.linalg.norm(d, axis=-1)
    ratio = (np.einsum("nmj,mj->nm", d, axis) / length / (g.height / length)) ** 2
    return (r.samples * ratio.reshape(r.samples.shape)).astype(np.float32), axis


def test_a_wobbling_beam_is_modelled_about_each_cells_axis(level_beam):
    """A hand's wobble (3 degrees RMS, its own tilt per cell) on the level cos^2 beam's
    capture, k = 2 known. Measured: held level, the model relights at 35.68 dB; with each
    cell's axis 56.37 dB, as the capture without the wobble (54.90 dB)."""
    r = level_beam
    samples, axis = _wobbled(r, 3.0, seed=1)
    level = replace(r.geometry, led_exponent=2.0)
    still = snr_db(r.truth, physical.solve(r.samples, level))
    held_level = snr_db(r.truth, physical.solve(samples, level))
    per_cell = snr_db(r.truth, physical.solve(samples, replace(level, led_axis=axis)))
    assert held_level < 37 and per_cell > 55.5 and per_cell > still, (held_level, per_cell,
                                                                      still)


def test_the_refined_exponents_lie_about_the_estimate():
    assert refined_exponents(2.0, 0.1) == pytest.approx(np.linspace(1.8, 2.2, 9))
    assert refined_exponents(0.05, 0.1).min() == 0.0  # none below 0
    assert list(refined_exponents(1.5, 0.0)) == [1.5]


@pytest.mark.parametrize(("estimate", "refined"), [(1.0, False), (2.4, True), (2.9, False)])
def test_the_estimate_is_refined_only_where_the_heldout_error_is_lowest_inside(
        level_beam, estimate, refined):
    """Ingest's estimate +- 0.1 on the level cos^2 beam's capture, whose held-out error is
    lowest at k = 2.225. Measured: from 1.0 it falls all the way to the window's top (0.0200
    at 1.2 against 0.0236 at 1.0) and from 2.9 to its bottom: neither measures k, the estimate
    stands; from 2.4 it is lowest inside the window (0.00082 at 2.225 against 0.00117)."""
    r = level_beam
    k, record = refine_led_exponent(r.samples, r.geometry, estimate, 0.1)
    assert record["default"] == estimate and record["exponent"] == k, record
    if refined:
        assert record["source"] == "ingest, refined by held-out error", record
        assert k == pytest.approx(2.225) and record["errors"][f"{k:g}"] == min(
            record["errors"].values()), record
    else:
        assert record["source"] == "ingest" and k == estimate, record
        assert min(record["errors"].values()) < 0.9 * record["errors"][f"{k:g}"], record
