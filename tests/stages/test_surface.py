"""The far-light surface's choices (:mod:`ltmstore.stages.surface`): how it is mixed with the
classic fit, and each photograph's exposure (a hand-held flash that does not fire with the same
energy twice)."""

from __future__ import annotations

import numpy as np
import pytest
import zarr
from dome_helpers import RINGS, dome, flash, relit_error, rendered, surface, write_capture

from ltmstore.cli import main
from ltmstore.core.dims import rgb_from_ycbcr
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.core.transfer import linear_to_srgb, srgb_to_linear
from ltmstore.solve import physical
from ltmstore.solve.lightfit import Model
from ltmstore.stages import surface as sf
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.stages.relight import relight


def test_the_frames_colour_is_numpys_bit_for_bit():
    """The surface's linear RGB of stored Y, Cb, Cr (one compiled pass) is NumPy's float32
    passes' exactly: out-of-gamut values above 1 kept, negative ones clipped, NaN kept; frames
    of rows or of sampled pixels alike."""
    rng = np.random.default_rng(0)
    y, cb, cr = (rng.uniform(-0.6, 1.6, (5, 7, 9)).astype(np.float16) for _ in range(3))
    y[0, 0, 0] = np.nan
    expected = np.stack([np.maximum(c, 0) for c in rgb_from_ycbcr(
        *(v.astype(np.float32) for v in (y, cb, cr)))], axis=-1)
    assert (expected > 1).any() and expected.dtype == np.float32
    np.testing.assert_array_equal(sf._rgb(y, cb, cr), expected)
    np.testing.assert_array_equal(sf._rgb(y[:, 2], cb[:, 2], cr[:, 2]), expected[:, 2])


def test_a_blend_is_named_and_mixed_as_chosen():
    train, query = dome(), dome()[::5] * [1, 1, 0.98]
    smoother, classic = Model("rbf:0.3:0.1"), Model("hsh3")
    blend = sf.Blend(smoother, classic, 0.7)
    assert blend.name == "physical+rbf:0.3:0.1*0.7+hsh3"
    assert sf.Blend.from_name(blend.name) == blend
    beckmann = sf.Blend(smoother, classic, 0.7, "beckmann")
    assert beckmann.name == "physical+rbf:0.3:0.1*0.7+hsh3@beckmann"
    assert sf.Blend.from_name(beckmann.name) == beckmann
    alone = sf.Blend.from_name("physical+rbf:0.3:0.1")
    assert alone.weight == 1 and alone.name == "physical+rbf:0.3:0.1"
    np.testing.assert_allclose(blend.weights(train, query),
                               0.7 * smoother.weights(train, query)
                               + 0.3 * classic.weights(train, query))
    theta = surface(5)
    np.testing.assert_allclose(
        blend.correction(theta, train, query, color=False),
        0.7 * sf.correction(theta, train, query, smoother, color=False), rtol=1e-6)


def test_the_simplest_surface_within_a_tie_is_chosen_and_only_by_a_margin():
    scores = {None: 1.0, (False, 1.0): 0.80, (False, 0.85): 0.795, (False, 0.7): 0.70,
              (True, 1.0): 0.75, (True, 0.7): 0.695}
    assert sf.choose_surface(scores) == (False, 0.7)  # exposure's 0.7 % is within the tie
    scores[(True, 0.7)] = 0.60
    assert sf.choose_surface(scores) == (True, 0.7)
    assert sf.choose_surface({None: 1.0, (False, 1.0): 0.96, (True, 1.0): 0.951}) is None


def test_exposures_recover_a_flickering_flash():
    directions = dome()
    rgb = rendered(surface(400), directions)
    truth = flash(len(directions))
    found = sf.exposures(rgb * truth[:, None, None], directions)
    steady = sf.exposures(rgb, directions)
    error = found / (truth / truth.mean()) - 1
    assert np.abs(found.mean() - 1) < 1e-6
    # measured 0.029: the leave-one-out prediction of a photograph carries its neighbours'
    # flicker, so most of it (7.9 % here), not all, is found
    assert np.sqrt(np.mean(error**2)) < 0.035, error
    assert np.std(steady) < 0.001, steady  # measured 0.0006


@pytest.mark.parametrize("flicker", [True, False])
def test_a_flickering_capture_is_fitted_at_its_mean_exposure(tmp_path, capsys, flicker):
    """``auto`` fits the exposures where the flash flickers (and leaves them at 1 where it does
    not): relit without the flicker, three times closer to the steady capture than the surface
    fitted without them."""
    gains = flash(sum(RINGS.values())) if flicker else np.ones(sum(RINGS.values()))
    lp = write_capture(tmp_path / "capture", gains)
    errors = {}
    for method in ("auto", "physical"):  # physical: the surface alone, no exposures
        store = tmp_path / f"{method}.zarr"
        ingest_rti(lp, store, progress=False)
        reconstruct(store, method=method, progress=False)
        errors[method] = relit_error(store, gains)
    ds = open_store(tmp_path / "auto.zarr")
    assert (sf.EXPOSURE in ds) == ds.attrs["stages"]["reconstruct"]["exposure_fitted"]
    if flicker:
        assert sf.EXPOSURE in ds
        # measured 0.96 (0.91 while three of its 168 pixels, fitted at roughness 1, were left
        # several times too bright: see physical.fit_colour)
        assert np.corrcoef(ds[sf.EXPOSURE].values, gains)[0, 1] > 0.93
        # measured 0.0063, 0.34 times the surface alone
        assert errors["auto"] < 0.0075 and errors["auto"] < 0.4 * errors["physical"], errors
        assert main(["reconstruct", str(tmp_path / "auto.zarr"), "--overwrite"]) == 0
        assert "at each photograph's exposure" in capsys.readouterr().out
        reconstruct(tmp_path / "auto.zarr", method="rbf", overwrite=True, progress=False)
        assert sf.EXPOSURE not in open_store(tmp_path / "auto.zarr")  # a later fit's frames
    else:
        # A steady flash: its exposures, where held-out lights still choose to fit them (this
        # noise-free capture, by 5 %), stay at 1 (measured within 0.11 %)
        if sf.EXPOSURE in ds:
            assert np.abs(ds[sf.EXPOSURE].values - 1).max() < 0.005
        # measured 0.0016 (0.0012 while three of its pixels were left too bright, which the
        # residual's smoother then interpolated at these, the photographed, lights)
        assert errors["auto"] < 0.0019, errors


def test_the_luminance_model_is_rendered_once_and_equals_the_three_channels():
    """``model_encoded`` without colour renders the luminance's parameters once (far lights,
    channels sharing normal and roughness): the same values as the three channels' luminance,
    to float32 rounding (measured 1.2e-7 on the coin)."""
    from ltmstore.core.dims import LUMA

    theta, directions = surface(301), dome()  # 301: not a multiple of 3
    lights = physical.far_lights(directions, len(theta))
    three = physical.render_colour(theta, lights) @ LUMA
    expected = linear_to_srgb(three.T.clip(min=0).astype(np.float32))
    got = sf.model_encoded(theta, directions, color=False)
    assert got.shape == expected.shape == (len(directions), len(theta))
    assert np.abs(got - expected).max() < 1e-5
    theta[:, 1, 4] += 0.1  # channels of different roughness: rendered channel by channel
    three = physical.render_colour(theta, lights) @ LUMA
    expected = linear_to_srgb(three.T.clip(min=0).astype(np.float32))
    assert np.abs(sf.model_encoded(theta, directions, color=False) - expected).max() < 1e-5


def test_leave_one_out_choice_by_gram_matrix_equals_the_residuals():
    """``lightfit.choose``'s MSE through the Gram matrix equals the mean squared leave-one-out
    residuals (relative 2e-14 measured)."""
    from ltmstore.solve.lightfit import choose, loo_operator, rbf_models

    directions = dome()
    values = rendered(surface(200), directions)[..., 1]  # (lights, pixels)
    model, mse = choose(values, directions, rbf_models())
    direct = [np.mean((loo_operator(m.hat(directions)) @ values.astype(np.float64)) ** 2)
              for m in rbf_models()]
    np.testing.assert_allclose(list(mse.values()), direct, rtol=1e-9)
    assert model.name == min(mse, key=mse.get) or mse[model.name] <= min(mse.values()) * 1.01


def test_frames_are_read_as_float32_rgb_and_written_with_fast_checksummed_codecs(tmp_path):
    """A classic capture's frames: Blosc LZ4 with a CRC32C (fast to write and read), and
    ``frames_rgb`` gives float32 (the float64 image took 4x the memory and time), equal to the
    float64 conversion rounded."""
    from ltmstore.core.checksum import has_checksums
    from ltmstore.core.dims import rgb_from_ycbcr
    from ltmstore.core.store import open_group

    lp = write_capture(tmp_path / "capture", np.ones(len(dome())))
    store = tmp_path / "c.zarr"
    ingest_rti(lp, store, progress=False)
    group = open_group(store)
    for name in ("frames", "frame_chroma"):
        codecs = [c.to_dict()["name"] for c in group[name].metadata.codecs]
        assert codecs[-2:] == ["blosc", "crc32c"] and has_checksums(group[name])
    valid = np.asarray(group["pose_valid"][:], dtype=bool)
    rgb = sf.frames_rgb(group, valid)
    assert rgb.dtype == np.float32
    y = np.asarray(group["frames"][:])[valid]
    cb, cr = (np.asarray(group["frame_chroma"][i])[valid].astype(np.float32) for i in (0, 1))
    exact = np.stack(rgb_from_ycbcr(y, cb, cr), axis=-1).clip(min=0)
    np.testing.assert_array_equal(rgb, exact.astype(np.float32))
    # a band of rows, and sampled pixels read band by band, are the same values
    luma = y.astype(np.float16)
    np.testing.assert_array_equal(sf.frames_rgb(group, valid, luma, slice(3, 7)), rgb[:, 3:7])
    pixels = np.array([0, 5, 14, 15, 40, 100, 167])
    flat = rgb.reshape(len(rgb), -1, 3)[:, pixels]
    for band_bytes in (sf.BAND_BYTES, 1):  # one band; a band per row
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(sf, "BAND_BYTES", band_bytes)
            assert len(sf.row_bands(luma.shape)) == (1 if band_bytes > 1 else 12)
            np.testing.assert_array_equal(sf.sample_rgb(group, valid, luma, pixels), flat)


def test_the_surface_fitted_band_by_band_is_the_whole_images(tmp_path, monkeypatch):
    """``ltm reconstruct`` reads a classic capture's RGB and fits its surface a band of rows at
    a time (never the whole image in memory): in bands of 5 rows the store's maps, LTM and
    stage choices are those of one band, within the fit's own rounding."""
    lp = write_capture(tmp_path / "capture", flash(sum(RINGS.values())))
    stores = {}
    for band_rows in (None, 5):
        store = tmp_path / f"bands-{band_rows}.zarr"
        ingest_rti(lp, store, progress=False)
        if band_rows:  # 5 rows of 14 pixels at 49 lights
            monkeypatch.setattr(sf, "BAND_BYTES", band_rows * 14 * 49 * 3 * 4)
        info = reconstruct(store, progress=False)
        stores[band_rows] = open_store(store)
        (method,) = info["chosen_per_tile"]  # one model for the image...
        assert method.startswith(sf.PREFIX)  # ...the surface's
    assert len(sf.row_bands((49, 12, 14))) == 3
    one, banded = stores.values()
    assert sf.EXPOSURE in one  # the flash's exposures, fitted on the sample first
    for name in (*sf.SURFACE, sf.EXPOSURE, "ltm", "expected_error"):
        # each pixel's fit is its own (its robust scale's floor too): the same values
        # whichever pixels share its batch
        np.testing.assert_array_equal(banded[name].values, one[name].values, err_msg=name)
    assert (one.attrs["stages"]["reconstruct"]["chosen_per_tile"]
            == banded.attrs["stages"]["reconstruct"]["chosen_per_tile"])


@pytest.mark.parametrize("lobe", physical.LOBES)
def test_the_lobe_is_the_captures_own(tmp_path, lobe):
    """A dome capture of Beckmann lobes is fitted with Beckmann's, one of GGX lobes with GGX's:
    chosen by held-out error, named in the stage record and the roughness's attribute, and
    relit with it between the dome's rings, where the other lobe errs more."""
    lp = write_capture(tmp_path / "capture", np.ones(sum(RINGS.values())), lobe=lobe)
    store = tmp_path / "s.zarr"
    ingest_rti(lp, store, progress=False)
    reconstruct(store, progress=False)
    ds = open_store(store)
    timings = ds.attrs["stages"]["reconstruct"]["timings"]
    assert timings["surface_lobe"] == sf.surface_lobe(ds) == lobe
    mse = timings["surface_lobe_loo_mse"]
    other = next(x for x in physical.LOBES if x != lobe)
    assert mse[lobe] < 0.5 * mse[other], mse  # measured 0.31 (GGX), 0.17 (Beckmann)
    between = np.array([[np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]
                        for e in np.radians([20, 40, 60, 80]) for a in np.linspace(0, 6, 5)])
    truth = linear_to_srgb(rendered(surface(12 * 14), between, lobe).clip(0, 1))

    def rms(encoded: np.ndarray) -> float:
        return float(np.sqrt(np.mean((encoded.reshape(truth.shape) - truth) ** 2)))

    # measured 0.0034 (GGX), 0.0019 (Beckmann)
    assert rms(linear_to_srgb(relight(ds, directions=between).values)) < 0.004
    photos = srgb_to_linear(np.round(linear_to_srgb(
        rendered(surface(12 * 14), dome(), lobe).clip(0, 1)) * 255).astype(np.float32) / 255)
    model = {x: rms(sf.model_encoded(sf.fit_pixels(photos, dome(), x), between, color=True,
                                     lobe=x)) for x in physical.LOBES}
    assert model[lobe] < 0.95 * model[other], model  # measured 0.91 (GGX), 0.65 (Beckmann)
    ds = open_store(store)
    ds["roughness"].attrs["lobe"] = other  # the two disagree
    with pytest.raises(LtmError, match=f"names the {lobe} lobe, its roughness the {other}"):
        relight(ds, directions=between)
    zarr.open_group(str(store), mode="r+")["roughness"].attrs["lobe"] = other  # on disk: damage
    with pytest.raises(LtmError, match="attribute 'lobe' is not what the reconstruct stage"):
        open_store(store)
