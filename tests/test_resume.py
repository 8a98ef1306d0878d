"""Resume: a reconstruct killed with SIGKILL mid-write is finished by a rerun that solves only
the pixel tiles it had not marked done, and gives exactly the ltm of an uninterrupted run."""

from __future__ import annotations

import numpy as np
import pytest
from archive_helpers import (
    N_TILES,
    SLOW_ARGS,
    copy_store,
    kill_group,
    slow_reference,
    start_reconstruct,
    tiles_done,
    wait_for_tiles,
)
from pipeline_helpers import run_ltm

from ltmstore.reconstruct import reconstruct, tiles_name
from ltmstore.store import open_group, open_store, stages

OUTPUTS = ("ltm", "expected_error", "unsupported")


@pytest.fixture(scope="module")
def reference(small_store, dask_cluster):
    """The uninterrupted run, on the session's cluster."""
    return open_store(slow_reference(small_store, dask_cluster))


@pytest.fixture(scope="module")
def killed_template(small_store, tmp_path_factory):
    """A store whose `ltm reconstruct` was SIGKILLed after some tiles were written."""
    store = copy_store(small_store, tmp_path_factory.mktemp("killed") / "store.zarr")
    proc = start_reconstruct(store, *SLOW_ARGS, "--overwrite")
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
