"""Interrupted reconstructions never leave an ltm that looks complete."""

from __future__ import annotations

import shutil
import subprocess
import time

import pytest
from archive_helpers import ingest_only, kill_group, tree_digest
from pipeline_helpers import BIN, run_ltm

from ltmstore import relight
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_group, open_store, revision_path, stages
from ltmstore.stages.reconstruct import reconstruct


@pytest.fixture
def ingested(small_store, tmp_path):
    """A copy of the session store as ingest left it: reconstruct writes it in place."""
    return ingest_only(small_store, tmp_path / "store.zarr")


@pytest.fixture
def reconstructed(small_store, tmp_path):
    """A copy of the session store with a complete ltm."""
    store = tmp_path / "store.zarr"
    shutil.copytree(small_store, store)
    return store


def fresh_shards(array, since: float) -> bool:
    """Whether any shard of ``array`` was written after ``since`` (seconds since the epoch).

    The rerun deletes the old ``ltm`` while this polls: a file gone mid-scan is not fresh.
    """
    def mtime(f) -> float:
        try:
            return f.stat().st_mtime
        except FileNotFoundError:
            return 0.0
    try:
        return any(mtime(f) >= since for f in (array / "c").rglob("*") if f.is_file())
    except FileNotFoundError:  # a directory removed during the scan
        return False


def assert_not_complete(store) -> None:
    ds = open_store(store)
    assert "ltm" not in ds and "samples" in ds  # resample finished, the solve did not
    assert stages(open_group(store))["reconstruct"]["complete"] is False


def test_a_failing_solver_leaves_the_stage_incomplete(ingested, client):
    with pytest.raises(ValueError, match="many"):
        reconstruct(ingested, client=client, lattice=(16, 16), overwrite=True, method="cs",
                    params={"n_iter": "many"}, progress=False)
    assert_not_complete(ingested)
    proc = run_ltm("relight", ingested, "--light", "0,0", "-o", ingested.parent / "x.png")
    assert proc.returncode == 2 and "no complete ltm" in proc.stderr


def test_sigkill_mid_solve_leaves_the_stage_incomplete(ingested):
    """Kill the whole `ltm reconstruct` process group while the (slow) LARS tiles run."""
    started = time.time()
    proc = subprocess.Popen([BIN / "ltm", "reconstruct", ingested, "--lattice", "16x16",
                             "--method", "lars", "--tile", "8", "--overwrite"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not fresh_shards(ingested / "ltm", started):
            assert proc.poll() is None and time.monotonic() < deadline, "never reached the solve"
            time.sleep(0.05)
        time.sleep(0.5)  # some tiles written, most not
    finally:
        kill_group(proc)
    assert_not_complete(ingested)
    with pytest.raises(LtmError, match="no complete ltm"):
        relight(ingested, [(0.0, 0.0)])


def test_a_failed_rerun_on_another_lattice_leaves_the_good_ltm_untouched(reconstructed, client):
    """--overwrite of a complete ltm works on a revision beside it: a failure changes nothing."""
    before = tree_digest(reconstructed)
    with pytest.raises(ValueError, match="many"):
        reconstruct(reconstructed, client=client, lattice=(12, 12), overwrite=True,
                    method="cs", params={"n_iter": "many"}, progress=False)
    assert tree_digest(reconstructed) == before
    assert not revision_path(reconstructed).exists()
    ds = open_store(reconstructed)
    assert "ltm" in ds and ds.sizes["r"] == 16


def test_bad_tile_is_a_clear_error_before_any_write(ingested):
    before = stages(open_group(ingested))
    with pytest.raises(LtmError, match="--tile 0 must be a positive"):
        reconstruct(ingested, lattice=(16, 16), tile=0, overwrite=True)
    assert stages(open_group(ingested)) == before
