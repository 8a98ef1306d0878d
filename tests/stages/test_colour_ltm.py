"""A scene whose colour changes with the light gets a colour LTM.

On the `canvas` scene a white gloss over coloured paint desaturates the colour where the light
glints: Cb, Cr are not a fixed multiple of Y. (Pure gold leaf is: its colour scales with
its brightness, so the `icon` scene stays luminance-only.)
"""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore import relight
from ltmstore.core.store import open_store
from ltmstore.stages.ingest import ingest
from ltmstore.stages.reconstruct import reconstruct


@pytest.fixture(scope="module")
def canvas_store(tmp_path_factory, dask_cluster):
    from distributed import Client

    from ltmstore.synthetic.simulate import simulate_acquisition

    folder = tmp_path_factory.mktemp("canvas")
    simulate_acquisition(folder / "acq", scene="canvas", size=24, seed=2, lattice=(12, 12),
                         path_density=12.0, progress=False)
    report = ingest(folder / "acq", folder / "store.zarr", progress=False)
    with Client(dask_cluster) as client:
        info = reconstruct(folder / "store.zarr", client=client, lattice=(12, 12),
                           progress=False)
    return folder, report, info


def test_glossy_paint_is_not_chroma_invariant_so_a_colour_ltm_is_built(canvas_store):
    folder, report, info = canvas_store
    assert not report["chroma"]["invariant"] and info["color"]
    ds = open_store(folder / "store.zarr")
    assert ds["ltm_cb"].dims == ds["ltm"].dims and np.isfinite(ds["ltm_cr"].values).all()


def test_colour_ltm_relights_colour_better_than_mean_chroma(canvas_store):
    folder = canvas_store[0]
    ds = open_store(folder / "store.zarr")
    truth = open_store(folder / "acq" / "truth.zarr")["ltm_rgb"]
    errors = {"colour ltm": [], "mean chroma": []}
    for i, j in [(3, 3), (6, 6), (8, 4), (4, 9)]:
        light = (float(ds.r[i]), float(ds.s[j]))
        expected = truth.isel(r=i, s=j).values
        for name, data in (("colour ltm", ds), ("mean chroma", ds.drop_vars(["ltm_cb", "ltm_cr"]))):
            rgb = relight(data, [light]).isel(light=0).values
            errors[name].append(np.sqrt(np.mean((rgb - expected) ** 2)))
    assert np.mean(errors["colour ltm"]) < 0.9 * np.mean(errors["mean chroma"]), errors
