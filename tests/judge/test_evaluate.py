"""Accuracy measures (SNR_Y, PSNR, error maps), held-out error and confidence maps."""

import dask.array as da
import numpy as np
import pytest
import xarray as xr

from ltmstore.core.errors import LtmError
from ltmstore.judge.evaluate import compare_stores, error_maps, psnr_db, snr_db
from ltmstore.judge.heldout import heldout_store
from ltmstore.solve import Geometry
from ltmstore.solve.confidence import coverage, coverage_gap, expected_error, flag_unsupported
from ltmstore.solve.validate import heldout_error, split_folds

LATTICE = (12, 12)
GEOMETRY = Geometry.from_shape(LATTICE)


def smooth_ltfs(n: int, seed: int = 0) -> np.ndarray:
    """Broad lobes (inverse-square-like) at random centres: easy to interpolate."""
    rng = np.random.default_rng(seed)
    r, s = np.meshgrid(*(np.linspace(-1, 1, k) for k in LATTICE), indexing="ij")
    centres = rng.uniform(-0.5, 0.5, (n, 2, 1, 1))
    d2 = (r - centres[:, 0]) ** 2 + (s - centres[:, 1]) ** 2
    return (1 / (1 + d2) ** 1.5).astype(np.float32)


def random_mask(ratio: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.random(LATTICE) < ratio


# --- SNR_Y, PSNR, error maps ---------------------------------------------------------------

def test_snr_and_psnr_known_values():
    truth = np.ones((2, 2, 3, 3))
    assert snr_db(truth, 0.9 * truth) == pytest.approx(20.0)
    assert psnr_db(np.ones((4, 4)), np.full((4, 4), 0.9)) == pytest.approx(20.0)
    assert snr_db(da.from_array(truth, chunks=1), 0.9 * truth) == pytest.approx(20.0)


def test_error_maps_known_values():
    truth = np.zeros((2, 3, 2, 2))
    estimate = truth.copy()
    estimate[0, 0] = [[1, -1], [3, -3]]  # |e| = 1, 1, 3, 3: mean 2, variance 1
    estimate[1, 2] = 0.5  # |e| = 0.5 everywhere: mean 0.5, variance 0
    maps = error_maps(truth, estimate)
    assert set(maps.data_vars) == {"mean_abs_error", "var_abs_error"}
    assert maps["mean_abs_error"].dims == ("y", "x")
    expected_mean = np.zeros((2, 3))
    expected_mean[0, 0], expected_mean[1, 2] = 2.0, 0.5
    expected_var = np.zeros((2, 3))
    expected_var[0, 0] = 1.0
    np.testing.assert_allclose(maps["mean_abs_error"].values, expected_mean)
    np.testing.assert_allclose(maps["var_abs_error"].values, expected_var)


def test_error_maps_take_dask_and_xarray_and_keep_coordinates():
    rng = np.random.default_rng(1)
    truth, estimate = rng.random((4, 5, 3, 3)), rng.random((4, 5, 3, 3))
    dims = ("y", "x", "r", "s")
    coords = {"y": np.arange(10, 14), "x": np.arange(20, 25)}
    ref = error_maps(truth, estimate)
    lazy = error_maps(da.from_array(truth, chunks=2), da.from_array(estimate, chunks=2))
    labelled = error_maps(xr.DataArray(truth, dims=dims, coords=coords),
                          xr.DataArray(estimate, dims=dims, coords=coords))
    for maps in (lazy, labelled):
        np.testing.assert_allclose(maps["mean_abs_error"].values, ref["mean_abs_error"].values)
        np.testing.assert_allclose(maps["var_abs_error"].values, ref["var_abs_error"].values)
    np.testing.assert_array_equal(labelled["y"].values, coords["y"])


def test_error_maps_reject_mismatched_shapes():
    with pytest.raises(LtmError, match=r"truth shape \(2, 2, 3, 3\) and estimate shape"):
        error_maps(np.zeros((2, 2, 3, 3)), np.zeros((2, 2, 3, 4)))


def test_compare_stores_reports_error_maps_and_writes_png(small_store, small_acquisition,
                                                          tmp_path):
    from PIL import Image

    from ltmstore.core.store import open_store

    png = tmp_path / "maps.png"
    truth = small_acquisition / "truth.zarr"
    out = compare_stores(small_store, truth, maps_png=png)
    assert out["snr_y_db"] == pytest.approx(
        snr_db(open_store(truth)["ltm"], open_store(small_store)["ltm"]), abs=1e-6)
    assert 0 < out["mean_abs_error_median"] <= out["mean_abs_error_max"]
    assert 0 < out["var_abs_error_median"] <= out["var_abs_error_max"]
    assert out["maps_png"] == str(png)
    assert Image.open(png).size[0] > 100


# --- held-out error ----------------------------------------------------------------------------

def test_folds_are_disjoint_shared_and_keep_data_to_fit():
    mask = np.broadcast_to(random_mask(0.3), (5, *LATTICE))
    fold = split_folds(mask, 4, seed=2)
    assert (fold == fold[0]).all()  # a shared mask: the same cells for every pixel
    assert (fold[~mask] == -1).all()
    sizes = [int((fold[0] == f).sum()) for f in range(4)]
    k = int(mask[0].sum())
    assert len(set(sizes)) == 1 and sizes[0] == k // 4  # k-fold: equal, disjoint folds
    assert (fold[0][mask[0]] == -1).sum() == k - 4 * (k // 4)


def test_folds_follow_per_pixel_masks_and_blocks():
    rng = np.random.default_rng(3)
    mask = rng.random((6, *LATTICE)) < 0.4
    mask[5] = False
    mask[5, 0, 0] = True  # a single observed cell is never held out: nothing left to fit
    fold = split_folds(mask, 2, fraction=0.2, seed=0)
    assert (fold[~mask] == -1).all() and (fold[5] == -1).all()
    assert not (fold[0] == fold[1]).all()
    full = np.ones((1, *LATTICE), bool)
    blocks = split_folds(full, 3, block=4, seed=1)[0]
    for f in range(3):  # every held-out block of 4 x 4 cells is hidden whole
        tiles = (blocks == f).reshape(3, 4, 3, 4).any(axis=(1, 3))
        assert (blocks == f).sum() == 16 * tiles.sum() > 0


def test_folds_hide_whole_groups():
    mask = np.broadcast_to(random_mask(0.5, seed=6), (3, *LATTICE))
    groups = np.arange(mask[0].size) // 10  # runs of ten cells in C order
    groups[:5] = -1  # cells of no group are never hidden
    fold = split_folds(mask, 2, seed=1, groups=groups)[0].ravel()
    assert (fold[:5] == -1).all() and (fold[~mask[0].ravel()] == -1).all()
    observed = mask[0].ravel()
    for g in np.unique(groups[groups >= 0]):
        members = np.unique(fold[(groups == g) & observed])
        assert len(members) <= 1  # a group's observed cells share one fold
    assert {0, 1} <= set(np.unique(fold))


def test_bad_fold_arguments_are_clear_errors():
    mask = np.ones((1, *LATTICE), bool)
    with pytest.raises(LtmError, match="folds 0 must be a positive integer"):
        split_folds(mask, 0)
    with pytest.raises(LtmError, match=r"fraction 0.6 must be in \(0, 1/folds\]"):
        split_folds(mask, 2, fraction=0.6)


def test_heldout_error_is_zero_for_a_perfect_interpolant():
    levels = np.linspace(0.1, 1.0, 8, dtype=np.float32)[:, None, None]
    samples = np.where(random_mask(0.3, seed=4), levels * np.ones(LATTICE, np.float32), np.nan)
    result = heldout_error(samples, GEOMETRY, "cs", folds=5)
    assert result.relative_error < 1e-4, result.relative_error
    assert result.snr_db > 80
    assert np.nanmax(result.rms) < 1e-4
    assert result.shared_mask and result.folds == 5
    k = int(np.isfinite(samples[0]).sum())
    assert result.cells_per_fold == (k // 5,) * 5


def test_heldout_error_takes_a_callable_and_rises_with_noise():
    truth = smooth_ltfs(16)
    mask = random_mask(0.35, seed=5)

    def oracle(samples, geometry):
        return truth

    exact = heldout_error(np.where(mask, truth, np.nan), GEOMETRY, oracle)
    assert exact.relative_error == 0 and exact.snr_db > 200
    rng = np.random.default_rng(6)
    noise = rng.standard_normal(truth.shape).astype(np.float32)
    errors = [heldout_error(np.where(mask, truth + sigma * noise, np.nan), GEOMETRY, "cs",
                            folds=4).relative_error for sigma in (0.0, 0.02, 0.1)]
    assert errors[0] < errors[1] < errors[2], errors


def test_heldout_error_gives_each_fold_its_rows_of_the_per_pixel_arguments():
    """A pixel with one observed cell hides none: the fold fits the other rows, and the method
    gets exactly their rows of ``per_pixel`` (physical's warm ``start``)."""
    truth = smooth_ltfs(6)
    samples = np.where(random_mask(0.4, seed=7), truth, np.nan)
    samples[0] = np.nan
    samples[0, 3, 4] = truth[0, 3, 4]
    seen = []

    def method(batch, geometry, *, tag):
        seen.append(tag.copy())
        return truth[tag]

    result = heldout_error(samples, GEOMETRY, method, folds=1, fraction=0.2,
                           per_pixel={"tag": np.arange(6)})
    assert [list(t) for t in seen] == [[1, 2, 3, 4, 5]]
    assert result.count[0] == 0 and result.relative_error == 0


def test_heldout_error_scores_each_pixels_own_hidden_cells():
    """Masks that differ per pixel: every fold's errors and kept predictions are those of the
    method at exactly the cells each row hides (checked against the fold split by hand)."""
    truth = smooth_ltfs(5)
    rng = np.random.default_rng(8)
    samples = np.where(rng.random(truth.shape) < 0.4, truth, np.nan)

    def shifted(batch, geometry):  # a prediction that differs from the truth everywhere
        return truth[: len(batch)] + 0.01 * np.arange(1, len(batch) + 1)[:, None, None]

    result = heldout_error(samples, GEOMETRY, shifted, folds=3, keep_prediction=True)
    fold = split_folds(np.isfinite(samples), 3).reshape(5, -1)
    hidden = (fold >= 0) & (fold < 3)
    assert not result.shared_mask
    assert (result.count == hidden.sum(axis=1)).all()
    # each fold's batch holds the rows that hide a cell in it: every row, in every fold here
    assert all((fold == f).any(axis=1).all() for f in range(3))
    np.testing.assert_allclose(result.rms, 0.01 * np.arange(1, 6), rtol=1e-5)
    kept = result.prediction
    assert (np.isfinite(kept) == hidden).all()
    np.testing.assert_allclose(kept[hidden], (truth.reshape(5, -1) + 0.01 * np.arange(
        1, 6)[:, None])[hidden], rtol=1e-6)


def test_heldout_store_reads_a_pixel_subset(small_store):
    out = heldout_store(small_store, method="cs", folds=3, max_pixels=300, seed=1)
    assert out["pixels"] == 300 and out["M"] == 256 and out["shared_mask"]
    assert 0.05 < out["relative_error"] < 0.09  # measured 0.072
    assert out["heldout_snr_db"] == pytest.approx(-20 * np.log10(out["relative_error"]))
    assert 0 < out["relative_rms_median"] < 1


def test_heldout_store_needs_samples(small_acquisition, tmp_path):
    from ltmstore.stages.ingest import ingest

    store = tmp_path / "ingested.zarr"
    ingest(small_acquisition, store, progress=False)
    with pytest.raises(LtmError, match="has no complete samples; run ltm reconstruct first"):
        heldout_store(store)


# --- confidence ----------------------------------------------------------------------------

def test_coverage_gap_known_values():
    geometry = Geometry.from_shape((8, 8))
    mask = np.zeros((3, 8, 8), bool)
    mask[0] = True
    mask[1, 0, 0] = True  # one corner: the far corner is 7 cells away along both axes
    gap = coverage_gap(mask, geometry)
    assert gap[0] == 0
    assert gap[1] == pytest.approx(np.hypot(7, 7) / 8)
    assert gap[2] == np.inf
    np.testing.assert_allclose(coverage(mask, geometry, radius=1 / 8), [1, 3 / 64, 0])


def test_flags_sparse_and_one_sided_masks_not_dense_ones():
    rng = np.random.default_rng(7)
    dense = rng.random((4, *LATTICE)) < 0.3
    few = np.zeros((2, *LATTICE), bool)
    few[0].flat[rng.choice(dense[0].size, 6, replace=False)] = True  # fewer than 8 cells
    few[1, ::3, ::3] = True  # 16 cells spread evenly: enough
    half = dense[:2].copy()
    half[:, LATTICE[0] // 2:] = False  # nothing in half of the plane
    mask = np.concatenate([dense, few, half])
    samples = np.where(mask, 1.0, np.nan)
    flags = flag_unsupported(samples, GEOMETRY)
    np.testing.assert_array_equal(flags, [False] * 4 + [True, False] + [True, True])
    assert flag_unsupported(samples, GEOMETRY, min_cells=20)[5]
    with pytest.raises(LtmError, match=r"do not match the lattice \(12, 12\)"):
        flag_unsupported(np.ones((2, 5, 5)), GEOMETRY)


def test_expected_error_is_relative_and_tracks_noise():
    truth = smooth_ltfs(24, seed=8)
    rng = np.random.default_rng(9)
    sigma = np.repeat([0.0, 0.05], 12)[:, None, None]
    noisy = truth + sigma * rng.standard_normal(truth.shape).astype(np.float32)
    samples = np.where(random_mask(0.35, seed=10), noisy, np.nan)
    samples[0] = np.nan
    samples[0, 0, 0] = 1.0  # one observed cell: nothing to hold out
    err = expected_error(samples, GEOMETRY, "cs")
    assert err.shape == (24,) and err.dtype == np.float32
    assert np.isnan(err[0]) and np.isfinite(err[1:]).all()
    assert np.median(err[12:]) > 2 * np.median(err[1:12])
    scaled = expected_error(np.where(np.isfinite(samples), 10 * samples, np.nan), GEOMETRY, "cs")
    np.testing.assert_allclose(scaled[1:], err[1:], rtol=1e-3)  # relative to the range


def test_at_cells_interpolates_bilinearly_and_clamps_at_the_edge():
    """An LTF linear in every lattice coordinate is reproduced exactly at cells inside the
    store's lattice; cells beyond its outer centres take the edge value (as relight clamps)."""
    from ltmstore.judge.evaluate import at_cells

    def ltm(r, s, p, q):
        grid = np.meshgrid(r, s, p, q, indexing="ij")
        values = 1 + grid[0] - 2 * grid[1] + 0.5 * grid[2] * grid[3]
        return xr.DataArray(np.broadcast_to(values, (2, 3, *values.shape)).astype(np.float32),
                            dims=("y", "x", "r", "s", "p", "q"),
                            coords={"r": r, "s": s, "p": p, "q": q})

    estimate = ltm(np.linspace(0, 1, 5), np.linspace(0, 1, 4), np.array([0.0, 1]),
                   np.array([0.5]))
    truth = ltm(np.array([0.1, 0.35, 0.9]), np.array([0.2, 0.5]), np.array([0.25, 0.75]),
                np.array([0.5]))
    np.testing.assert_allclose(at_cells(estimate.chunk({"r": 2}), truth).values, truth.values,
                               rtol=1e-6)
    edge = at_cells(estimate, ltm(np.array([-1.0]), np.array([2.0]), np.array([0.0]),
                                  np.array([0.5])))
    np.testing.assert_allclose(edge.values, 1 + 0 - 2 * 1, rtol=1e-6)
