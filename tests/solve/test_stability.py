"""Every method of ``METHODS`` through the regimes where the paper and its baselines break.

The regimes (:mod:`ltmstore.synthetic.regimes`): a very sparse path (K/M < 0.05), a path that
leaves half the plane empty, hard cast shadows, saturated highlights, sensor noise, a lossy video
(a simulated mp4v capture, ingested and binned), tracker jitter, and frames occluded by the phone.
No method is expected to be *accurate* everywhere (``bench/stability_table.py`` measures which
fails where); every method must stay finite and bounded, and the confidence measures must tell
the regimes the data cannot support from the benign one.

Methods are parametrised from :data:`ltmstore.solve.METHODS`, so a new method is covered as
soon as it registers. Batches are small (``PIXELS`` pixels of a 16 x 16 lattice) so that the
per-pixel methods (``lars``, ``omp``) run too.
"""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import METHODS, cs
from ltmstore.solve.confidence import expected_error, flag_unsupported
from ltmstore.synthetic.regimes import REGIMES, build_regimes, lossy_regime, overshoot

PIXELS = 64
REGIME_NAMES = [*REGIMES, "lossy"]
UNSUPPORTED = ("sparse", "half_empty")  # regimes whose sampling cannot support any model
SUPPORTED = tuple(name for name in REGIME_NAMES if name not in UNSUPPORTED)
# How far an estimate may leave the observed [min, max] of its pixel, in units of the pixel's
# observed scale max(max - min, max |b|) (regimes.observed_scale: the range alone degenerates
# when a short path only sees a dim, flat part of the LTF). Measured on every pixel of every
# regime (bench/stability_table.py -> bench/results/stability.json, "overshoot_max"): with the
# paper's sampling, corrupted or not, cs, lars, cubic, kernel, rbf, svt and ptm stay within 1.0
# scale, omp within 1.25 and hsh 1.76; where the data cannot support a model the l1, greedy and
# radial solvers extrapolate further (cs 1.6, lars 2.2, rbf 1.9, omp 2.7 on the 8-cell path).
# The bounds sit just above those, so that a method that runs away (the pairs below) is caught.
BOUND_SUPPORTED = 2.0
BOUND_UNSUPPORTED = 3.0
# Known runaways, measured on these regimes (worst of the PIXELS pixels, in observed scales);
# xfail, not strict: the methods are being worked on, and an XPASS means a pair can be removed.
KNOWN_UNBOUNDED = {
    ("hsh", "sparse"): "7.2 scales: 16 harmonics fitted to 8 cells (minimum norm) extrapolate",
    ("hsh", "half_empty"): "15.3 scales: ill-conditioned harmonics over the empty half",
    ("ptm", "sparse"): "6.6 scales: a biquadratic fitted to 8 cells extrapolates",
    ("ptm", "half_empty"): "3.1 scales: a biquadratic extrapolated over the empty half",
}
# Methods whose held-out error cannot see a sparse path: a global model with few terms fits the
# 8 cells of a short path (and so its held-out cells along the path) about as well as it fits a
# dense path, while everything off the path is extrapolation. flag_unsupported catches these.
# (hsh only just passes: expected error 0.011 on the sparse path against 0.009 on benign.)
HELDOUT_BLIND = {
    "ptm": "6 terms fit 8 cells of a short path: expected error 0.014 there, 0.078 on benign",
}


def _cases():
    for method in sorted(METHODS):
        for name in REGIME_NAMES:
            reason = KNOWN_UNBOUNDED.get((method, name))
            marks = [pytest.mark.xfail(reason=reason, strict=False)] if reason else []
            yield pytest.param(method, name, marks=marks, id=f"{method}-{name}")


def _methods_seeing_sparse_paths():
    for method in sorted(METHODS):
        reason = HELDOUT_BLIND.get(method)
        marks = [pytest.mark.xfail(reason=reason, strict=False)] if reason else []
        yield pytest.param(method, marks=marks)


@pytest.fixture(scope="session")
def lossy(tmp_path_factory):
    """A small lossy (mp4v) simulated capture, ingested and binned: the real pipeline."""
    return lossy_regime(tmp_path_factory.mktemp("lossy"), size=24)


@pytest.fixture(scope="module")
def regimes(lossy):
    """Every regime, rendered once, cut to ``PIXELS`` fixed random pixels."""
    built = build_regimes()
    built["lossy"] = lossy
    out = {}
    for i, (name, regime) in enumerate(built.items()):
        rows = np.random.default_rng([0, i]).choice(len(regime.samples), PIXELS, replace=False)
        out[name] = regime.subset(np.sort(rows))
    return out


@pytest.fixture(scope="module")
def solved(regimes):
    """Estimates, computed once per (method, regime)."""
    cache: dict[tuple[str, str], np.ndarray] = {}

    def get(method: str, name: str) -> np.ndarray:
        if (method, name) not in cache:
            regime = regimes[name]
            cache[method, name] = np.asarray(METHODS[method](regime.samples, regime.geometry))
        return cache[method, name]

    return get


def test_regimes_are_what_they_claim(regimes):
    ratios = {name: r.ratio for name, r in regimes.items()}
    assert ratios["sparse"] < 0.05
    assert 0.25 < ratios["benign"] < 0.45
    half = regimes["half_empty"]
    observed = np.isfinite(half.samples).any(axis=0)
    assert not observed[half.geometry.shape[0] // 2 + 1:].any()  # one half of r is empty
    for name in ("saturated", "noise", "jitter", "occluded", "lossy"):
        mask = np.isfinite(regimes[name].samples)
        err = np.abs(regimes[name].samples[mask] - regimes[name].truth[mask])
        assert err.max() > 0.01, name  # the samples themselves are corrupted
    benign = regimes["benign"]
    mask = np.isfinite(benign.samples)
    np.testing.assert_allclose(benign.samples[mask], benign.truth[mask], rtol=1e-5)


@pytest.mark.parametrize(("method", "name"), _cases())
def test_estimate_is_finite_and_bounded(method, name, regimes, solved):
    regime = regimes[name]
    estimate = solved(method, name)
    assert estimate.shape == regime.samples.shape
    assert np.isfinite(estimate).all(), f"{method} on {name}: non-finite output"
    bound = BOUND_UNSUPPORTED if name in UNSUPPORTED else BOUND_SUPPORTED
    worst = float(np.nanmax(overshoot(regime.samples, estimate)))
    assert worst <= bound, (f"{method} on {name} leaves the observed range by {worst:.2f} "
                            f"scales (bound {bound})")


def test_unsupported_regimes_are_flagged(regimes):
    flagged = {name: flag_unsupported(r.samples, r.geometry).mean() for name, r in regimes.items()}
    for name in UNSUPPORTED:
        assert flagged[name] == 1.0, flagged
    for name in SUPPORTED:
        assert flagged[name] == 0.0, flagged


@pytest.mark.parametrize("method", _methods_seeing_sparse_paths())
def test_expected_error_is_higher_where_the_path_is_sparse(method, regimes):
    """The held-out error of a method is larger on the 8-cell path than on the benign one."""
    med = {name: float(np.nanmedian(expected_error(regimes[name].samples,
                                                   regimes[name].geometry, method)))
           for name in ("benign", "sparse")}
    assert med["sparse"] > med["benign"], med


def test_cs_converges_where_the_data_supports_it(regimes, record_property):
    """The step-wise solver's last relative change is small on every regime, and where the
    data supports a model its 30-iteration answer is close to a 300-iteration one."""
    changes, agreement = {}, {}
    for name, regime in regimes.items():
        solver = cs.IterativeThresholding(regime.samples, ndim=regime.geometry.ndim)
        estimate = solver.run()
        changes[name] = solver.change
        longer = cs.solve(regime.samples, regime.geometry, n_iter=300)
        agreement[name] = snr_db(longer, estimate)
    record_property("cs_final_change", changes)
    record_property("cs_snr_db_against_300_iterations", agreement)
    # Measured (64 pixels): final change 0.003-0.007; agreement 19.5-31.7 dB on the supported
    # regimes, but only 3.9 (sparse) and 7.5 dB (half_empty) where the data cannot pin the
    # solution down: there, the iteration count acts as a regulariser.
    assert max(changes.values()) < 0.02, changes
    assert min(agreement[name] for name in SUPPORTED) > 15, agreement


def test_svt_residual_decreases(regimes, record_property):
    """SVT's relative residual on the observed entries keeps falling (it rarely reaches its
    tolerance within ``max_iter`` on LTFs, which are not low rank across pixels)."""
    if "svt" not in METHODS:
        pytest.skip("no svt method registered")
    from ltmstore.solve import svt

    if not hasattr(svt, "SingularValueThresholding"):
        pytest.skip("svt exposes no step-wise solver")
    regime = regimes["benign"]
    matrices = svt.as_matrices(regime.samples.astype(np.float64), "tile")
    solver = svt.SingularValueThresholding(matrices, np.isfinite(matrices))
    history = []
    while solver.iteration < 300 and solver.residual > 1e-4:
        solver.step()
        history.append(solver.residual)
    record_property("svt_residual", history[-1])
    record_property("svt_iterations", solver.iteration)
    # Measured (64 pixels, benign): 0.29 after 10 iterations, 0.067 after 100, 0.014 after 500.
    assert history[-1] < history[99] < history[9], (history[9], history[99], history[-1])
    assert history[-1] < 0.1
