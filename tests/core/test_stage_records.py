"""A stage is complete only when its output is there (issue 13, item 1): a relative store path
travels to workers started in another folder; a tile whose ltm is lost is never complete."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from archive_helpers import ingest_only
from pipeline_helpers import BIN, dask_processes

from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_group, open_store
from ltmstore.stages.reconstruct import check_solved, plan_tiles


def test_a_relative_store_path_reaches_workers_in_another_folder(small_store, tmp_path):
    here, elsewhere = tmp_path / "here", tmp_path / "elsewhere"
    here.mkdir()
    elsewhere.mkdir()
    ingest_only(small_store, here / "store.zarr")
    with dask_processes(1, cwd=elsewhere) as address:
        proc = subprocess.run([BIN / "ltm", "reconstruct", "store.zarr", "--lattice", "16x16",
                               "--scheduler", address], cwd=here, capture_output=True,
                              text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    ds = open_store(here / "store.zarr")
    observed = np.isfinite(ds["samples"].values)
    assert observed.any()
    assert np.isfinite(ds["ltm"].values[observed]).all()
    assert list(elsewhere.iterdir()) == []  # nothing written in the workers' folder


def test_a_lost_tile_is_never_complete(small_store, tmp_path, client):
    store = tmp_path / "store.zarr"
    shutil.copytree(small_store, store)
    group = open_group(store, mode="r")
    plan = plan_tiles(group["ltm"].shape[:2], group["ltm"].shape[2:], tile=32)
    check_solved(group, "ltm", plan, client)
    for shard in (store / "ltm" / "c").rglob("*"):
        if shard.is_file():
            shard.unlink()
    with pytest.raises(LtmError, match=r"ltm is not finite at 1024 observed pixels \(first in "
                                       r"tile 0, 0\)"):
        check_solved(group, "ltm", plan, client)


def test_a_tile_solved_to_nan_is_refused_before_it_is_written(small_store, tmp_path,
                                                              monkeypatch):
    """A solver that returns NaN at observed cells fails its tile, naming it; the stage stays
    incomplete and no shard of that tile is written (the workers are threads of this process,
    so they run the broken solver)."""
    from distributed import Client, LocalCluster

    from ltmstore.core.cluster import LOOPBACK_HTTP
    from ltmstore.solve import rbf
    from ltmstore.stages.reconstruct import reconstruct

    real = rbf.solve

    def broken(samples, geometry, **params):
        out = real(samples, geometry, **params)
        out[:3] = np.nan  # three pixels of every tile
        return out

    monkeypatch.setattr(rbf, "solve", broken)
    store = ingest_only(small_store, tmp_path / "store.zarr")
    with (LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                       **LOOPBACK_HTTP) as local, Client(local) as client,
          pytest.raises(LtmError, match=r"the solution of tile \d+, \d+ is not finite at 3 "
                                        r"observed pixels; nothing of it was written")):
        reconstruct(store, client=client, lattice=(16, 16), method="rbf", progress=False)
    group = open_group(store, mode="r")
    assert group.attrs["stages"]["reconstruct"]["complete"] is False
    assert group["ltm"].nchunks_initialized == 0
    assert group["expected_error"].nchunks_initialized == 0  # nor its maps
