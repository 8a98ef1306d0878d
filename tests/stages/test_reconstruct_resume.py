"""Resume: a reconstruct killed with SIGKILL mid-write is finished by a rerun that solves only
the pixel tiles it had not marked done, and gives exactly the ltm of an uninterrupted run."""

from __future__ import annotations

import numpy as np
import pytest
import zarr
from archive_helpers import (
    N_TILES,
    SLOW_ARGS,
    copy_store,
    ingest_only,
    kill_group,
    slow_reference,
    start_reconstruct,
    tiles_done,
    tree_digest,
    wait_for_tiles,
)
from pipeline_helpers import run_ltm

from ltmstore.core.store import (
    STAGES_ATTR,
    open_group,
    open_store,
    revised_store,
    revision_path,
    stages,
)
from ltmstore.stages.reconstruct import reconstruct, tiles_name

OUTPUTS = ("ltm", "expected_error", "unsupported")


@pytest.fixture(scope="module")
def reference(small_store, dask_cluster):
    """The uninterrupted run, on the session's cluster."""
    return open_store(slow_reference(small_store, dask_cluster))


@pytest.fixture(scope="module")
def killed_template(small_store, tmp_path_factory):
    """A store whose `ltm reconstruct` was SIGKILLed after some tiles were written."""
    store = ingest_only(small_store, tmp_path_factory.mktemp("killed") / "store.zarr")
    proc = start_reconstruct(store, *SLOW_ARGS)
    try:
        wait_for_tiles(proc, store, 1)
    finally:
        kill_group(proc)
    done = tiles_done(store)
    assert 0 < done < N_TILES
    rec = stages(open_group(store))["reconstruct"]
    assert rec["complete"] is False and "ltm" not in open_store(store)
    return store, done


@pytest.fixture
def killed(killed_template, tmp_path):
    template, done = killed_template
    return copy_store(template, tmp_path / "store.zarr"), done


def test_rerun_solves_only_the_missing_tiles_and_equals_an_uninterrupted_run(killed, reference,
                                                                             dask_cluster):
    store, done = killed
    # no --overwrite: the stage is incomplete; on the session's (warm) cluster
    proc = run_ltm("reconstruct", store, *SLOW_ARGS, "--scheduler", dask_cluster.scheduler_address)
    assert proc.returncode == 0, proc.stderr
    rec = stages(open_group(store))["reconstruct"]
    assert rec["complete"] and rec["resumed"]
    assert rec["tiles_solved"] == N_TILES - done and rec["tiles_resumed"] == done
    ds = open_store(store)
    for name in OUTPUTS:
        np.testing.assert_array_equal(ds[name].values, reference[name].values, err_msg=name)
    assert tiles_name("ltm") not in open_group(store)  # the marks go once the stage completes


def test_other_parameters_start_over(killed, client):
    store, _ = killed
    info = reconstruct(store, client=client, lattice=(12, 12), tile=8, method="cs",
                       progress=False)
    assert info["tiles_solved"] == N_TILES and info["tiles_resumed"] == 0 and not info["resumed"]
    assert open_store(store)["ltm"].shape[2:] == (12, 12)


def test_a_killed_overwrite_keeps_the_good_ltm_and_the_next_one_resumes(small_store, reference,
                                                                       dask_cluster, tmp_path):
    """--overwrite of a complete ltm builds a revision beside it: SIGKILL leaves the store
    byte-identical, and the next --overwrite run of the same parameters resumes the revision."""
    store = copy_store(small_store, tmp_path / "store.zarr")
    before = tree_digest(store)
    proc = start_reconstruct(store, *SLOW_ARGS, "--overwrite")
    try:
        wait_for_tiles(proc, revision_path(store), 1)
    finally:
        kill_group(proc)
    done = tiles_done(revision_path(store))
    assert tree_digest(store) == before and 0 < done < N_TILES
    proc = run_ltm("reconstruct", store, *SLOW_ARGS, "--overwrite", "--scheduler",
                   dask_cluster.scheduler_address)
    assert proc.returncode == 0, proc.stderr
    rec = stages(open_group(store))["reconstruct"]
    assert rec["complete"] and rec["resumed"] and rec["tiles_solved"] == N_TILES - done
    for name in OUTPUTS:
        np.testing.assert_array_equal(open_store(store)[name].values, reference[name].values,
                                      err_msg=name)
    assert not revision_path(store).exists()


def test_the_same_lattice_with_another_method_starts_over(killed, client):
    """The run key decides: same lattice and tiles (the plan matches), another method."""
    store, done = killed
    info = reconstruct(store, client=client, lattice=(8, 8), tile=8, method="cs",
                       progress=False)
    assert done > 0 and info["tiles_resumed"] == 0 and not info["resumed"]
    assert info["tiles_solved"] == N_TILES
    assert stages(open_group(store))["reconstruct"]["run"]["method"] == "cs"


def test_a_leftover_revision_of_another_ingest_is_not_reused(small_store, tmp_path):
    """A revision beside the store that holds another ingest (the store was ingested again
    after a killed --overwrite) is removed, never swapped in."""
    store = copy_store(small_store, tmp_path / "store.zarr")
    stale = copy_store(store, revision_path(store))
    group = zarr.open_group(str(stale), mode="r+")
    record = group.attrs.asdict()[STAGES_ATTR]
    group.attrs[STAGES_ATTR] = {**record, "ingest": {**record["ingest"], "n_valid": -1}}
    ingest = stages(open_group(store))["ingest"]
    with revised_store(store) as side:
        assert stages(open_group(side))["ingest"] == ingest
    assert stages(open_group(store))["ingest"] == ingest and not stale.exists()
