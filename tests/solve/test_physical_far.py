"""The compiled far-light Levenberg-Marquardt against the NumPy one it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.solve import physical, physical_far


def far_pixels(n: int = 300, seed: int = 0, lobe: str = "ggx", noise: float = 0.01
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Light directions ``(48, 3)``, pixel values ``(n, 48)`` (float32) of random surfaces (a
    lobe of the distribution ``lobe``) with ``noise`` (relative), and their true parameters
    ``(n, 6)``."""
    rng = np.random.default_rng(seed)
    elevation, azimuth = rng.uniform(0.2, 1.5, 48), rng.uniform(0, 2 * np.pi, 48)
    directions = np.column_stack([np.cos(elevation) * np.cos(azimuth),
                                  np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    theta = np.column_stack([rng.uniform(-0.4, 0.4, (n, 2)), rng.uniform(0.2, 0.7, n),
                             rng.uniform(0.05, 0.3, n), np.log(rng.uniform(0.1, 0.5, n)),
                             np.full(n, 0.01)])
    lights = physical.far_lights(directions, n, lobe)
    values = physical._model(theta, lights) * (1 + noise * rng.standard_normal((n, 48)))
    return directions, values.astype(np.float32), theta


@pytest.mark.parametrize("lobe", physical.LOBES)
def test_the_compiled_steps_are_numpys(lobe):
    """Same starts, same iterations: the parameters agree to float32 rounding (measured 2e-4 at
    most on the slopes, the costs within 1e-3 relative), and the fit finds the truth, with
    either lobe."""
    directions, y, truth = far_pixels(lobe=lobe)
    far = physical.far_lights(directions, len(y), lobe)
    assert far.far and far.take(np.arange(10)).far and far.rows(np.arange(5)).far
    assert far.take(np.arange(10)).lobe == far.rows(np.arange(5)).lobe == lobe
    near = physical.Lights(far.toward, far.half, far.g, lobe=lobe)  # the NumPy path
    w = np.ones_like(y)
    start = physical._starts(near, y, w)[0]
    compiled, cost = physical.levenberg_marquardt(start, far, y, w)
    reference, cost_ref = physical.levenberg_marquardt(start, near, y, w)
    assert np.median(np.abs(compiled - reference)) < 1e-5
    assert np.median(np.abs(cost / cost_ref - 1)) < 1e-3
    fitted, _ = physical.fit_parameters(y, w, far)
    assert np.median(np.abs(fitted[:, :2] - truth[:, :2])) < 0.02  # slopes; measured 0.002


@pytest.mark.parametrize("lobe", physical.LOBES)
def test_the_compiled_colour_fit_takes_numpys_steps(lobe):
    """The whole colour fit compiled pixel by pixel against NumPy's steps around the compiled
    Levenberg-Marquardt (the two starts, the better one, the robust refit, each channel's linear
    terms), their sums in another order: the parameters equal to float32 rounding (measured: the
    median difference 7e-7 (GGX) and 5e-7 (Beckmann); where rounding changes a kept step, up to
    0.0025 and 0.039), the images they render within 1.0e-4 and 1.9e-4 of each other
    (relative, the largest pixel), and the slopes near the truth's."""
    directions, y, truth = far_pixels(lobe=lobe)
    rgb = (y[..., None] * np.array([0.8, 1.0, 1.2])).astype(np.float32)
    lights = physical.far_lights(directions, len(y), lobe)
    compiled = physical.fit_colour(rgb, lights)
    reference = physical.fit_colour(rgb, lights, compiled=False)
    assert np.median(np.abs(compiled - reference)) < 2e-6
    image, expected = (physical.render_colour(t, lights) for t in (compiled, reference))
    change = np.abs(image - expected).max(axis=(1, 2)) / np.abs(expected).max(axis=(1, 2))
    assert change.max() < 4e-4, np.sort(change)[-3:]
    assert np.median(np.abs(compiled[:, 0, :2] - truth[:, :2])) < 0.02


def test_the_kernel_keeps_the_models_bounds():
    assert np.isclose(np.exp(physical_far.LOG_ALPHA), physical.ALPHA_RANGE).all()
    assert physical_far.SLOPE_MAX == physical.SLOPE_MAX
    directions, y, _ = far_pixels(20)
    far = physical.far_lights(directions, len(y))
    wild = np.tile([10.0, -10.0, -1.0, -1.0, 5.0, -1.0], (len(y), 1))
    theta, cost = physical.levenberg_marquardt(wild, far, y, np.ones_like(y), n_iter=0)
    assert (theta[:, :2] == [3, -3]).all() and (theta[:, [2, 3, 4, 5]] == 0).all()
    assert np.isfinite(cost).all()



def test_a_pixel_stops_once_its_steps_stop_paying():
    """With a tolerance of 1 every pixel stops after its first kept step (as one iteration);
    with :data:`~ltmstore.solve.physical.CONVERGED` the costs are those of every iteration to
    1e-4 relative but for a rare pixel whose later steps pay again (measured: the median 0, the
    99th percentile 4e-5; the largest 7e-5 on one CPU, 4.3e-4 on an AVX-512 one, where Numba's
    vectorised sums round differently)."""
    directions, y, _ = far_pixels()
    far = physical.far_lights(directions, len(y))
    w = np.ones_like(y)
    start = physical._starts(far, y, w)[0]
    toward, half = (np.ascontiguousarray(v[:, 0], dtype=np.float32) for v in (far.toward, far.half))

    def fit(n_iter: int, tol: float) -> tuple[np.ndarray, np.ndarray]:
        theta = np.array(start, dtype=np.float64, order="C")
        return theta, physical_far.levenberg_marquardt(theta, toward, half, y, w, False,
                                                       n_iter, tol)

    (one, one_cost), (stopped, _) = fit(1, 0.0), fit(10, 1.0)
    kept = one_cost < fit(0, 0.0)[1]
    assert kept.mean() > 0.9 and np.array_equal(one[kept], stopped[kept])
    (_, every), (_, converged) = fit(10, 0.0), fit(10, physical.CONVERGED)
    change = np.abs(converged / every - 1)
    assert np.quantile(change, 0.99) < 1e-4 and change.max() < 1e-3, np.sort(change)[-4:]


def test_the_warm_up_loads_the_signature_the_fits_use():
    """``warm_up`` (run on a thread by a far-light reconstruct) must dispatch the very signature
    of :func:`ltmstore.solve.physical.fit_parameters`' calls (read-only light rows): a second
    one would be compiled (about 5 s) in the middle of the first fit of every new machine."""
    physical_far.warm_up()
    directions, y, _ = far_pixels(10)
    for lobe in physical.LOBES:
        lights = physical.far_lights(directions, len(y), lobe)
        physical.fit_parameters(y, np.ones_like(y), lights)
        physical.fit_colour(np.repeat(y[..., None], 3, axis=-1), lights)
    assert len(physical_far.levenberg_marquardt.signatures) == 1
    assert len(physical_far.fit_colour.signatures) == 1


def test_a_lobe_is_fitted_by_its_own_distribution():
    """Beckmann and GGX lobes of the same roughness differ in their tails; each fits its own
    pixels far better than the other (measured: the other's error 21x and 145x), and an unknown
    distribution is refused."""
    def error(y: np.ndarray, lights: physical.Lights) -> float:
        theta, _ = physical.fit_parameters(y, np.ones_like(y), lights)
        return float(np.median(np.sum((physical._model(theta, lights) - y) ** 2, axis=1)))

    for lobe, other in (("ggx", "beckmann"), ("beckmann", "ggx")):
        directions, y, _ = far_pixels(100, lobe=lobe, noise=0.001)
        own = error(y, physical.far_lights(directions, len(y), lobe))
        wrong = error(y, physical.far_lights(directions, len(y), other))
        assert wrong > 10 * own, (own, wrong)
    with pytest.raises(physical.LtmError, match="lobe 'phong' is not one of ggx, beckmann"):
        physical.far_lights(directions, 3, "phong")


# Fits of far (both lobes) and near lights, run in a fresh process: the kernels compiled afresh
# (an empty cache) and then loaded from the cache that run wrote.
KERNEL_RUN = """
import sys
import numpy as np
from ltmstore.core.dims import Lattice
from ltmstore.solve import Geometry, physical

rng = np.random.default_rng(0)
e, a = rng.uniform(0.2, 1.5, 48), rng.uniform(0, 2 * np.pi, 48)
directions = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
theta = np.column_stack([rng.uniform(-0.4, 0.4, (200, 2)), rng.uniform(0.2, 0.7, 200),
                         rng.uniform(0.05, 0.3, 200), np.log(rng.uniform(0.1, 0.5, 200)),
                         np.full(200, 0.01)])
out = []
for lobe in physical.LOBES:
    lights = physical.far_lights(directions, 200, lobe)
    y = physical._model(theta, lights).astype(np.float32)
    out.append(physical.fit_parameters(y, np.ones_like(y), lights)[0])
    out.append(physical.fit_colour(np.repeat(y[..., None], 3, axis=-1), lights)[:, 0])
lattice = Lattice(bounds=((-0.2, 0.2), (-0.2, 0.2)), shape=(16, 16), dims=("r", "s"))
near = physical.near_lights(Geometry(lattice, 0.3, rng.uniform(-0.05, 0.05, (200, 2))))
y = physical._model(theta, near).astype(np.float32)
out.append(physical.fit_parameters(y, (rng.random(y.shape) > 0.4).astype(np.float32), near)[0])
np.save(sys.argv[1], np.stack(out))
"""


def test_the_kernels_give_the_same_values_compiled_afresh_and_cached(tmp_path):
    """The same input gives the same parameters, bit for bit, whether the kernels were compiled
    in this process or loaded from Numba's cache (with fast-math contraction they differed)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    runs = [tmp_path / f"{name}.npy" for name in ("compiled", "cached")]
    for path in runs:
        subprocess.run([sys.executable, "-c", KERNEL_RUN, str(path)], env=env, check=True,
                       timeout=300)
    assert any((tmp_path / "cache").rglob("*.nbi")), "the first run wrote no cache"
    compiled, cached = (np.load(path) for path in runs)
    np.testing.assert_array_equal(cached, compiled)


def colour_theta(n: int = 500, seed: int = 1) -> np.ndarray:
    """Per-channel parameters ``(n, 3, 6)`` of random surfaces sharing their geometry across
    the channels (as a store's), one pixel NaN (a pixel without a surface)."""
    rng = np.random.default_rng(seed)
    theta = np.empty((n, 3, 6))
    theta[:, :, :2] = rng.uniform(-1, 1, (n, 1, 2))
    theta[:, :, 4] = np.log(rng.uniform(0.02, 1, (n, 1)))
    theta[:, :, [2, 3, 5]] = rng.uniform(0, 0.6, (n, 3, 3))
    theta[7] = np.nan
    return theta


@pytest.mark.parametrize("lobe", physical.LOBES)
@pytest.mark.parametrize("shadowed", [False, True])
def test_the_compiled_render_is_numpys(lobe, shadowed, monkeypatch):
    """The far-light render kernel gives NumPy's model: GGX bit for bit, Beckmann to its
    ``exp``'s last bit (measured 1e-7 relative), with and without shadows, NaN where the
    parameters are NaN; a channel of its own geometry is rendered by its own."""
    directions, _, _ = far_pixels(1)
    theta = colour_theta()
    theta[::5, 1, 0] += 0.3  # some pixels' green with its own normal
    visible = np.random.default_rng(2).uniform(0, 1, (len(theta), 48)) if shadowed else None
    lights = physical.far_lights(directions, len(theta), lobe, visible)
    compiled = physical.render_colour(theta, lights)
    monkeypatch.setattr(physical, "COMPILED", False)
    reference = physical.render_colour(theta, lights)
    assert compiled.dtype == reference.dtype == np.float32
    assert np.isnan(compiled[7]).all() and np.isnan(reference[7]).all()
    if lobe == "ggx":
        np.testing.assert_array_equal(compiled, reference)
    else:
        np.testing.assert_allclose(compiled, reference, rtol=1e-6, atol=0)


@pytest.mark.parametrize("color", [True, False])
@pytest.mark.parametrize("shadowed", [False, True])
def test_the_compiled_blend_is_the_weighted_sum_of_the_model(color, shadowed):
    """A blend's image (surface.blend_encoded: photographs and the model at their lights
    weighted, plus the model at the query) equals the same sums over NumPy's encoded model
    images, to float32 rounding (measured 5e-7)."""
    from ltmstore.stages import surface

    directions, _, _ = far_pixels(1)
    train, query = directions[:40], directions[40:]
    theta = colour_theta(seed=3)
    rng = np.random.default_rng(4)
    frames = rng.uniform(0, 1, (40, len(theta), 3) if color else (40, len(theta)))
    weights = rng.normal(0, 0.1, (len(query), 80))
    visible = ((rng.uniform(0, 1, (len(theta), 40)), rng.uniform(0, 1, (len(theta), 8)))
               if shadowed else (None, None))
    blended = surface.blend_encoded(frames.astype(np.float32), weights, theta, train, query,
                                    0.7, visible=visible)
    at_train, at_query = (surface.model_encoded(theta, d, color=color, visible=v)
                          for d, v in zip((train, query), visible, strict=True))
    expected = (np.tensordot(weights, np.concatenate([frames, at_train]), axes=1)
                + 0.7 * at_query)
    assert blended.shape == expected.shape == (8, *frames.shape[1:])
    assert np.isnan(blended[:, 7]).all()
    finite = np.delete(np.arange(len(theta)), 7)
    np.testing.assert_allclose(blended[:, finite], expected[:, finite], rtol=0, atol=2e-6)
