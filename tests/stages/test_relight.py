"""Relighting on a hand-made store whose LTM is linear in (r, s): bilinear queries are exact."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from zarr.storage import LocalStore

from ltmstore import relight
from ltmstore.core import store as st
from ltmstore.core.dims import Lattice, Plane, rgb_to_ycbcr, ycbcr_to_rgb
from ltmstore.core.errors import LtmError
from ltmstore.core.lights import normalise
from ltmstore.solve.hsh import hsh_basis
from ltmstore.stages.reconstruct import plan_tiles

PLANE = Plane(r=(-1.0, 1.0), s=(-1.0, 1.0), height=1.0)
LATTICE = Lattice.from_plane(PLANE, (16, 16))
SIZE = (40, 48)
COLOUR = np.array([0.8, 0.5, 0.2])


def linear_ltm(r, s):
    """Value of pixel (y, x) under a light at (r, s): exact under bilinear interpolation."""
    y, x = np.mgrid[: SIZE[0], : SIZE[1]]
    return 1 + 0.01 * y[..., None] + 0.02 * x[..., None] + 0.5 * r + 0.25 * s


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("relight") / "store.zarr"
    plan = plan_tiles(SIZE, LATTICE.shape, tile=32, chunk_bytes=16 * 1024)
    rr, ss = np.meshgrid(*LATTICE.coords().values(), indexing="ij")
    ltm = linear_ltm(rr.ravel(), ss.ravel()).reshape(*SIZE, *LATTICE.shape).astype(np.float32)
    ycc = rgb_to_ycbcr(COLOUR)
    with st.new_store(path) as group:
        group.attrs["acquisition"] = {"plane": PLANE.to_json(), "transfer": "srgb"}
        for name, values in {"y": np.arange(SIZE[0]), "x": np.arange(SIZE[1]),
                             "channel": np.array(["cb", "cr"]), **LATTICE.coords()}.items():
            st.write_coord(group, name, values)
        st.create_variable(group, "ltm", ("y", "x", "r", "s"), ltm.shape, chunks=plan.chunks,
                           shards=plan.shards)[...] = ltm
        chroma = np.broadcast_to(ycc[1:] / ycc[0], (*SIZE, 2)).astype(np.float32)
        st.create_variable(group, "chroma", ("y", "x", "channel"), chroma.shape,
                           chunks=chroma.shape)[...] = chroma
        st.complete_stage(group, "reconstruct", {})
    return path


def test_point_lights_interpolate_bilinearly(store):
    lights = [(LATTICE.centres(0)[3], LATTICE.centres(1)[5]), (0.013, -0.377), (0.9, 0.9)]
    image = relight(store, lights, color=False)
    assert image.dims == ("light", "y", "x") and image.chunks is not None  # lazy
    for k, (r, s) in enumerate(lights):
        np.testing.assert_allclose(image.isel(light=k).values, linear_ltm(r, s)[..., 0],
                                   rtol=1e-5)


def test_colour_comes_back_from_chroma(store):
    rgb = relight(store, [(0.1, 0.2)]).isel(light=0).values
    luminance = linear_ltm(0.1, 0.2)[..., 0]
    expected = luminance[..., None] * ycbcr_to_rgb(rgb_to_ycbcr(COLOUR)) / rgb_to_ycbcr(COLOUR)[0]
    np.testing.assert_allclose(rgb, expected, rtol=1e-4)


def test_light_outside_the_plane_is_extrapolated_not_clamped(store):
    image = relight(store, [(5.0, 0.0)], color=False).isel(light=0).values
    edge = linear_ltm(LATTICE.centres(0)[-1], 0.0)[..., 0]
    assert np.abs(image - edge).mean() > 0.05  # not the edge's image
    # what it claims: each pixel's order-2 HSH least-squares fit, evaluated towards the light
    rr, ss = np.meshgrid(LATTICE.centres(0), LATTICE.centres(1), indexing="ij")
    cells = normalise(np.column_stack([rr.ravel(), ss.ravel(), np.full(rr.size, PLANE.height)]))
    values = st.open_store(store)["ltm"].values.reshape(-1, rr.size)
    coef = np.linalg.lstsq(hsh_basis(cells, 2), values.T, rcond=None)[0]
    expected = (hsh_basis(normalise([5.0, 0.0, PLANE.height]), 2) @ coef).reshape(SIZE)
    assert expected.min() > 1.7  # measured 1.78: the clip at 0 has nothing to hide here
    np.testing.assert_allclose(image, expected, rtol=1e-4)


def test_weight_patterns_are_area_lights(store):
    ds = st.open_store(store)
    weights = xr.DataArray(np.random.default_rng(0).random(LATTICE.shape), dims=("r", "s"))
    image = relight(ds, weights, color=False).isel(light=0).values
    expected = np.einsum("yxrs,rs->yx", ds["ltm"].values, weights.values)
    np.testing.assert_allclose(image, expected, rtol=1e-5)


def test_a_point_light_reads_only_the_chunks_it_needs(store):
    counting = st.CountingStore(LocalStore(str(store), read_only=True))
    relight(st.open_store(counting), [(0.013, -0.377)], color=False).compute()
    total = LATTICE.size * np.prod(SIZE) * 4
    assert 0 < counting.bytes_read < total / 10, (counting.bytes_read, total)


def test_many_lights_relight_as_image_by_image(store, monkeypatch):
    """Above POINT_LIGHTS the lights are relit in one pass over the cell-major LTM (a sparse
    bilinear matrix; beyond the plane, the HSH fit's two factors): the images and coordinates
    that relighting them image by image gives, inside the plane and beyond it."""
    from ltmstore.stages import relight as module

    rng = np.random.default_rng(4)
    lights = np.vstack([rng.uniform(-0.95, 0.95, (module.POINT_LIGHTS + 8, 2)), [[5, 0], [-2, 3]]])
    for some in (lights, lights[:-2]):  # with lights beyond the plane, and all inside
        together = relight(store, some)
        with monkeypatch.context() as m:
            m.setattr(module, "POINT_LIGHTS", len(some))
            one_by_one = relight(store, some)
        assert len(one_by_one.data.dask) > 4 * len(together.data.dask)  # not the same path
        xr.testing.assert_allclose(together, one_by_one, rtol=2e-6)


def test_bad_lights_are_clear_errors(store):
    with pytest.raises(LtmError, match="must be finite"):
        relight(store, [(np.nan, 0.0)])


def test_the_light_major_copy_relights_the_same(store, tmp_path):
    """Point lights bit for bit, weight patterns within rounding, reading fewer bytes."""
    import shutil

    from ltmstore.stages.by_light import write_by_light

    copy = shutil.copytree(store, tmp_path / "copy.zarr")
    write_by_light(st.open_group(copy, mode="r+"), "ltm")
    lights = [(0.013, -0.377), (0.9, 0.9)]
    weights = xr.DataArray(np.zeros(LATTICE.shape), dims=("r", "s"))
    weights[3:6, 8:12] = np.random.default_rng(1).random((3, 4))
    for query in (lights, weights):
        before = relight(store, query).values
        counting = st.CountingStore(LocalStore(str(copy), read_only=True))
        after = relight(st.open_store(counting), query).values
        np.testing.assert_allclose(after, before, rtol=1e-6)
        assert counting.bytes_read < np.prod(SIZE) * 4 * 16  # 12 cells read at most
    assert np.array_equal(relight(copy, lights).values, relight(store, lights).values)


def test_the_light_major_copy_in_bands_on_a_cluster_is_the_same(store, tmp_path):
    """The copy written band by band as tasks of a real cluster (worker processes) equals the
    one written on threads, and the bands tile the array with whole shards."""
    import itertools
    import shutil

    from distributed import Client, LocalCluster

    from ltmstore.core.cluster import LOOPBACK_HTTP
    from ltmstore.stages.by_light import bands, write_by_light

    shape, shards = (40, 70, 12, 16), (40, 70, 4, 4)
    regions = bands(shape, shards, limit=40 * 70 * 4 * 8)
    assert len(regions) == 6 and all(r[3] in (slice(0, 8), slice(8, 16)) for r in regions)
    covered = np.zeros(shape[2:], dtype=int)
    for region in regions:
        covered[region[2:]] += 1
        assert all(s.start % c == 0 for s, c in zip(region, shards, strict=True))
    assert (covered == 1).all()
    assert len(bands(shape, shards, limit=1)) == 12  # never less than one shard
    assert list(itertools.chain(*bands(shape, shards, limit=10**9))) == [
        slice(0, n) for n in shape]

    threads = shutil.copytree(store, tmp_path / "threads.zarr")
    cluster = shutil.copytree(store, tmp_path / "cluster.zarr")
    write_by_light(st.open_group(threads, mode="r+"), "ltm")
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      **LOOPBACK_HTTP) as local, Client(local) as client:
        copy = write_by_light(st.open_group(cluster, mode="r+"), "ltm", client=client,
                              band_bytes=SIZE[0] * SIZE[1] * 4 * 8)
    assert len(bands(copy.shape, copy.shards, SIZE[0] * SIZE[1] * 8)) > 1
    expected = st.open_group(threads, mode="r")["ltm_by_light"][...]
    assert np.array_equal(st.open_group(cluster, mode="r")["ltm_by_light"][...], expected)
    assert np.array_equal(expected, st.open_group(store, mode="r")["ltm"][...])
