"""Object placement from the data (issue 28, item 1): the frame's extent on the object plane
estimated from a near-light capture when ``acquisition.json`` declares none."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import zarr
from placement_helpers import placement_inputs

from ltmstore.core.dims import Lattice, Plane, object_extent
from ltmstore.core.errors import LtmError
from ltmstore.solve.placement import estimate_placement, profile

TRUE = {"x": [-0.1, 0.1], "y": [-0.1, 0.1]}  # the simulated object's extent (tests/conftest.py)


def _edges(extent: dict) -> np.ndarray:
    return np.array(extent["x"] + extent["y"])


def _profiles(extent: dict, *, shape=(24, 30), jitter=0.003, seed=0):
    """Radial profiles of a frame ``shape`` over ``extent`` (off centre, not square, so that a
    flipped axis or a swapped side shows), each pixel displaced by ``jitter`` (as a tilted
    normal displaces its peak), under a random half of a 16 x 16 lattice, with noise."""
    rng = np.random.default_rng(seed)
    h, w = shape
    rows, cols = (a.ravel() for a in np.indices(shape))
    (left, right), (bottom, top) = extent["x"], extent["y"]
    where = np.column_stack([left + (cols + 0.5) * (right - left) / w,
                             top - (rows + 0.5) * (top - bottom) / h])
    where += rng.normal(0, jitter, where.shape)
    lat = Lattice.from_plane(Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3), (16, 16))
    rr, ss = np.meshgrid(lat.centres(0), lat.centres(1), indexing="ij")
    lights = np.column_stack([rr.ravel(), ss.ravel()])[rng.random(256) < 0.4]
    albedo = rng.uniform(0.2, 1.0, (len(rows), 1))
    values = 0.01 + albedo * profile(lights, where, 0.3, 2.0)
    values += rng.normal(0, 0.005 * values.max(), values.shape)
    return values, rows, cols, shape, lights


def test_estimate_recovers_an_off_centre_extent():
    extent = {"x": [0.02, 0.17], "y": [-0.05, 0.07]}  # pixels 5 mm wide, 5 mm high
    values, rows, cols, shape, lights = _profiles(extent)
    found = estimate_placement(values, rows, cols, shape, lights, 0.3)
    err = np.abs(_edges(found.extent) - _edges(extent))
    # measured: largest edge error 0.5 mm (0.1 px), bootstrap sigma 0.4 mm; a flipped axis or a
    # side off by a tenth is 12-150 mm off
    assert err.max() < 0.002, (found.extent, err)
    assert found.pitch == pytest.approx((0.005, 0.005), rel=0.02)
    assert 0 < found.sigma_max < 0.002 and found.support == pytest.approx(1.0)


def test_estimate_keeps_separate_sides_where_the_data_insist():
    extent = {"x": [-0.12, 0.12], "y": [-0.06, 0.06]}  # 8 mm wide, 5 mm high pixels
    values, rows, cols, shape, lights = _profiles(extent, jitter=0.001)
    found = estimate_placement(values, rows, cols, shape, lights, 0.3)
    assert found.pitch == pytest.approx((0.008, 0.005), rel=0.02)  # measured within 0.4 %
    assert np.abs(_edges(found.extent) - _edges(extent)).max() < 0.002  # measured 0.3 mm


def test_nothing_to_place_gives_no_estimate():
    values, rows, cols, shape, lights = _profiles(TRUE)
    flat = np.ones_like(values)  # no pixel varies with the light
    assert estimate_placement(flat, rows, cols, shape, lights, 0.3) is None


@pytest.fixture(scope="module")
def bare_acquisition(small_acquisition, tmp_path_factory):
    """``small_acquisition`` (relief, 32 x 32 pixels) without the ``object`` field."""
    out = tmp_path_factory.mktemp("bare") / "acquisition"
    shutil.copytree(small_acquisition, out, ignore=shutil.ignore_patterns("truth.zarr"))
    meta = json.loads((out / "acquisition.json").read_text())
    del meta["object"]
    (out / "acquisition.json").write_text(json.dumps(meta))
    return out


@pytest.fixture(scope="module")
def placed_store(bare_acquisition, tmp_path_factory, dask_cluster):
    """``bare_acquisition`` ingested and reconstructed by the default: the placement estimated."""
    from distributed import Client

    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct

    store = tmp_path_factory.mktemp("placed") / "store.zarr"
    ingest(bare_acquisition, store, progress=False)
    with Client(dask_cluster) as client:
        info = reconstruct(store, client=client, lattice=(16, 16), progress=False)
    return store, info


def test_reconstruct_without_object_uses_the_estimate(placed_store):
    from ltmstore.core.store import store_summary

    store, info = placed_store
    placed = info["placement"]
    assert placed["source"] == "estimated"
    assert info["methods_per_tile"] == {"physical": 1}  # the surface model, as when declared
    err = np.abs(_edges(placed["extent"]) - _edges(TRUE))
    # measured 10.6 mm (1.7 px; 20.5 mm before the levelling): at 32 px the relief's 8 mm
    # frame is mostly bevel, its inward tilt pulls the edges in; a flipped axis or a doubled
    # side is 100-200 mm off
    assert err.max() < 0.025, placed["extent"]
    assert placed["extent"]["x"][0] < 0 < placed["extent"]["x"][1]
    estimate = placed["estimate"]
    assert estimate["sigma_pixels"] > 0 and len(estimate["uncertainty"]) == 4
    group = zarr.open_group(store, mode="r")
    assert "normal" in group and np.isfinite(group["normal"][...]).all()  # the surface's maps
    summary = store_summary(store)  # what `ltm info` prints
    assert summary["complete"] and "damaged" not in summary
    assert summary["placement"]["source"] == "estimated"
    assert summary["placement"]["estimated"]["sigma_pixels"] == estimate["sigma_pixels"]
    assert summary["placement"]["estimated"]["levelled"] == estimate["levelled"]
    assert object_extent(group.attrs.asdict()) == placed["extent"]


def test_a_declared_extent_that_disagrees_is_warned_about_and_used(placed_store, tmp_path):
    from ltmstore.stages.placement import PlacementWarning, place_object

    store = tmp_path / "store.zarr"
    shutil.copytree(placed_store[0], store)
    group, plan, binning, r, s = placement_inputs(store)
    wrong = {"x": [-0.2, 0.0], "y": [-0.1, 0.1]}  # shifted by the object's half width
    group.attrs["acquisition"] = {**group.attrs["acquisition"], "object": wrong}
    with pytest.warns(PlacementWarning, match=r"disagrees .* left edge by 0\.1\d* plane units"):
        extent, record = place_object(group, plan, binning, r, s, 0.3, method="auto")
    assert extent == wrong and record["source"] == "declared"
    assert not record["disagreement"]["agrees"]
    group.attrs["acquisition"] = {**group.attrs["acquisition"], "object": TRUE}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the true extent: no warning
        extent, record = place_object(group, plan, binning, r, s, 0.3, method="auto")
    assert record["disagreement"]["agrees"]


@pytest.fixture
def one_sided_store(bare_acquisition, tmp_path):
    """The bare capture with only the frames whose light is left of r = -0.06 (the lights cover
    a tenth of the object)."""
    from ltmstore.stages.ingest import ingest

    store = tmp_path / "store.zarr"
    ingest(bare_acquisition, store, progress=False)
    group = zarr.open_group(store, mode="r+")
    group["pose_valid"][:] = group["pose_valid"][:] & (group["pose_r"][:] < -0.06)
    return store


def test_a_capture_that_cannot_place_the_object_falls_back(one_sided_store, client):
    from ltmstore.stages.placement import PlacementWarning
    from ltmstore.stages.reconstruct import reconstruct

    with pytest.warns(PlacementWarning, match=r"cover 11% of the estimated extent, at least "
                                              r"25% needed; the surface model is left out"):
        info = reconstruct(one_sided_store, client=client, lattice=(16, 16), progress=False)
    assert info["placement"]["source"] == "none" and info["placement"]["extent"] is None
    assert "physical" not in info["methods_per_tile"]
    assert "normal" not in zarr.open_group(one_sided_store, mode="r")


def test_physical_by_name_is_refused_where_the_object_cannot_be_placed(one_sided_store, client):
    from ltmstore.stages.reconstruct import reconstruct

    with pytest.raises(LtmError, match=r"cannot be estimated from this capture: the lights "
                                       r"\(r -0\.\d+\.\.-0\.0\d+, .*cover 11%.*declare it in "
                                       r"acquisition.json"):
        reconstruct(one_sided_store, client=client, lattice=(16, 16), method="physical",
                    progress=False)
