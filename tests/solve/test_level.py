"""The estimated placement levelled by the surface model (``ltmstore.solve.level``): a sparse
handheld path that leaves part of the frame unlit pulls the radial profile's estimate towards
the lights; the surface model's normals show it, and levelling them undoes most of it."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import zarr
from placement_helpers import placement_inputs

from ltmstore.core.binning import cell_means
from ltmstore.solve import Geometry
from ltmstore.solve.level import level_map
from ltmstore.solve.placement import fit_frame, frame_corners

TRUE = frame_corners({"x": [-0.1, 0.1], "y": [-0.1, 0.1]})  # the simulated object's extent
LIT_BELOW_R = 0.05  # frames with the light beyond this r are dropped: the right quarter unlit


@pytest.fixture(scope="module")
def unlit_side(tmp_path_factory, dask_cluster):
    """A 64 px canvas on a sparse path (density 8, as a phone capture's), its placement not
    declared and its lights kept left of r = 0.05, resampled on a 16 x 16 lattice: the store
    and the inputs of the placement."""
    from distributed import Client

    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct
    from ltmstore.synthetic.simulate import simulate_acquisition

    work = tmp_path_factory.mktemp("level")
    acq = work / "acquisition"
    simulate_acquisition(acq, scene="canvas", size=64, seed=0, lattice=(16, 16),
                         path_density=8.0, progress=False)
    shutil.rmtree(acq / "truth.zarr")
    meta = json.loads((acq / "acquisition.json").read_text())
    meta.pop("object", None)
    (acq / "acquisition.json").write_text(json.dumps(meta))
    store = work / "store.zarr"
    ingest(acq, store, progress=False)
    group = zarr.open_group(store, mode="r+")
    group["pose_valid"][:] = group["pose_valid"][:] & (group["pose_r"][:] < LIT_BELOW_R)
    with Client(dask_cluster) as client:  # the samples binned (cubic: no placement needed)
        reconstruct(store, client=client, lattice=(16, 16), method="cubic", progress=False)
    return placement_inputs(store)


def _corner_errors(corners: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.asarray(corners) - TRUE, axis=1)


def test_levelling_undoes_the_pull_of_an_unlit_side(unlit_side):
    from ltmstore.stages.placement import read_pixels

    group, plan, binning, r, s = unlit_side
    values, rows, cols = read_pixels(group, plan)
    lights = cell_means(binning, r, s)
    observed = np.isfinite(values).all(0)
    found, _ = fit_frame(values[:, observed], rows, cols, plan.image, lights[observed], 0.3)
    # the profile alone: measured 4.9, 17.0 and 12.8 mm (top-left, top-right, bottom-left),
    # the unlit right side pulled in; the whole path gives 4.3, 7.6 and 2.1 mm
    assert _corner_errors(found.corners).max() > 0.012
    geometry = Geometry(lattice=binning.lattice, height=0.3, sampled=lights)
    levelled, record = level_map(values.reshape(len(values), 16, 16), rows, cols, plan.image,
                                 found, geometry)
    # measured 4.2, 5.5 and 2.8 mm; the median slopes of the frame's regions 0.022 -> 0.005
    assert _corner_errors(levelled.corners).max() < 0.0075, levelled.corners
    assert record["tilt_after"] < 0.3 * record["tilt_before"] and record["steps"] >= 1
    assert record["moved"] == pytest.approx(
        np.linalg.norm(levelled.corners - found.corners, axis=1).max())


def test_the_placement_records_its_levelling(unlit_side):
    from ltmstore.stages.placement import place_object

    group, plan, binning, r, s = unlit_side
    extent, record = place_object(group, plan, binning, r, s, 0.3, method="auto")
    assert record["source"] == "estimated"
    level = record["estimate"]["levelled"]
    assert level["tilt_after"] < level["tilt_before"] and level["steps"] >= 1
    assert _corner_errors(frame_corners(extent)).max() < 0.0075  # measured as above
