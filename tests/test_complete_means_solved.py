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
