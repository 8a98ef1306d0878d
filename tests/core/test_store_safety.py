"""Round two of the data-safety audit (issue 27, items 1, 2, 5, 6), each reproduced for real:
`ltm compact` after a SIGKILLed `ltm reconstruct --overwrite`; two writers meeting through a
symlink; the local Dask cluster's listening sockets; a SIGKILLed `ltm compact`."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest
from archive_helpers import (
    SLOW,
    SLOW_ARGS,
    copy_store,
    ingest_only,
    kill_group,
    start_reconstruct,
    tree_digest,
    wait_for_tiles,
)
from pipeline_helpers import BIN, beyond_loopback, only_error_line, run_ltm, tcp_listeners

from ltmstore.core.lock import lock_path
from ltmstore.core.store import (
    CHUNK_TEMPORARY,
    open_group,
    open_store,
    revision_path,
    stages,
    store_summary,
)
from ltmstore.core.swap import PAUSE_BEFORE_ENV
from ltmstore.stages.compact import compact
from ltmstore.stages.reconstruct import reconstruct


def leftovers(store: Path) -> list[Path]:
    """Folders that writers of ``store`` built beside it (copies, revisions, set-aside stores)."""
    return [p for p in store.parent.glob(f".{store.name}.*") if p.is_dir()]


def finished_files(store: Path) -> dict[str, str]:
    """:func:`tree_digest` without the chunk a kill cut short (Zarr's ``*.partial`` temporary,
    which the next writer removes): whether the kill lands mid-write is chance."""
    return {name: digest for name, digest in tree_digest(store).items()
            if not CHUNK_TEMPORARY.search(name)}


# -- item 1: compact after a killed `reconstruct --overwrite` --------------------------------

def test_compact_refuses_a_store_whose_overwrite_was_killed(small_store, tmp_path, client):
    """The killed run (another lattice) left its revision beside the store: compact used to take
    that revision as its copy and swap in its samples (8 x 8) under the old ltm (16 x 16)."""
    store = copy_store(small_store, tmp_path / "store.zarr")
    before = tree_digest(store)
    proc = start_reconstruct(store, *SLOW_ARGS, "--overwrite")
    try:
        wait_for_tiles(proc, revision_path(store), 1)
        listening = tcp_listeners()  # item 5: the run's cluster, up now
    finally:
        kill_group(proc)
    revision = finished_files(revision_path(store))
    refused = run_ltm("compact", store)
    only_error_line(refused, "reconstruct --overwrite", str(revision_path(store)))
    assert tree_digest(store) == before
    assert tree_digest(revision_path(store)) == revision  # the killed run's work is kept
    # the way on that the error names: finish the overwrite (it resumes), then compact
    reconstruct(store, client=client, overwrite=True, progress=False, **SLOW)
    compact(store)
    ds = open_store(store)
    assert ds["samples"].shape[2:] == ds["ltm"].shape[2:] == SLOW["lattice"]
    assert store_summary(store)["complete"] and not leftovers(store)
    assert beyond_loopback(listening) == {}, listening


# -- item 2: two writers through a symlink ---------------------------------------------------

def test_every_name_of_a_store_has_the_same_lock_file(tmp_path, monkeypatch):
    real = tmp_path / "al.zarr"
    real.mkdir()
    (tmp_path / "alias.zarr").symlink_to("al.zarr")
    (tmp_path / "up").symlink_to(tmp_path, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    names = [real, tmp_path / "alias.zarr", Path("al.zarr"), Path("alias.zarr"),
             Path("up/alias.zarr"), tmp_path / "up" / "al.zarr", Path("./up/alias.zarr/../al.zarr")]
    assert {lock_path(name) for name in names} == {real.resolve().parent / ".al.zarr.lock"}


def test_a_second_writer_through_a_symlink_is_refused(small_store, tmp_path):
    store = ingest_only(small_store, tmp_path / "al.zarr")
    alias = tmp_path / "alias.zarr"
    alias.symlink_to("al.zarr")
    proc = start_reconstruct(store, *SLOW_ARGS)
    try:
        wait_for_tiles(proc, store, 1)
        second = run_ltm("reconstruct", alias, *SLOW_ARGS)
    finally:
        kill_group(proc)
    only_error_line(second, "being written by", f"process {proc.pid}")


def test_an_overwrite_through_a_symlink_rewrites_the_store_it_names(small_store, tmp_path,
                                                                    client):
    """The revision is swapped into the real store; the link stays a link."""
    store = copy_store(small_store, tmp_path / "al.zarr")
    alias = tmp_path / "alias.zarr"
    alias.symlink_to("al.zarr")
    reconstruct(alias, client=client, overwrite=True, lattice=(8, 8), method="cs",
                progress=False)
    assert alias.is_symlink() and alias.resolve() == store.resolve()
    assert open_store(store)["ltm"].shape[2:] == (8, 8)
    assert not leftovers(store) and not leftovers(alias)


# -- item 5: everything listens on loopback --------------------------------------------------

@pytest.mark.parametrize("small", [True, False], ids=["threads", "processes"])
def test_the_local_cluster_listens_on_loopback_only(small):
    """Before: the thread cluster's scheduler and worker HTTP servers listened on 0.0.0.0 and
    [::] (reachable from the network: /health, /metrics)."""
    from ltmstore.core.cluster import dask_client

    before = set(tcp_listeners())
    with dask_client(small=small, n_workers=1) as client:
        assert client.submit(sum, [1, 2]).result() == 3
        during = tcp_listeners()
    new = {addr: cmd for addr, cmd in during.items() if addr not in before}
    assert new  # the cluster does listen (its HTTP servers at least) ...
    assert beyond_loopback(new) == {}, new  # ... on loopback only


# -- item 6: a killed compact ----------------------------------------------------------------

def wait_for_compacted_copy(proc: subprocess.Popen, store: Path, timeout: float = 120) -> Path:
    """The copy beside ``store`` that compact finished (and is about to swap in)."""
    deadline = time.monotonic() + timeout
    while True:
        for side in leftovers(store):
            try:
                record = json.loads((side / "zarr.json").read_text())
            except (OSError, ValueError):
                continue
            if record["attributes"]["stages"].get("compact", {}).get("complete"):
                return side
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "compact never finished its copy"
        time.sleep(0.02)


def test_a_killed_compact_leaves_the_store_as_it_was(small_store, tmp_path, dask_cluster):
    """SIGKILL once compact's copy is complete (frames dropped) but not swapped in: the store
    reads, checks and reconstructs as before (`reconstruct --overwrite` used to reuse the copy
    and end in ``KeyError: 'frames'``)."""
    store = copy_store(small_store, tmp_path / "store.zarr")
    before = tree_digest(store)
    proc = subprocess.Popen([BIN / "ltm", "compact", store], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True,
                            env={**os.environ, PAUSE_BEFORE_ENV: "120"})
    try:
        side = wait_for_compacted_copy(proc, store)
    finally:
        kill_group(proc)
    assert not (side / "frames").exists()  # the copy had dropped them
    assert tree_digest(store) == before
    check = run_ltm("check", store)
    assert check.returncode == 0 and "no damage" in check.stdout, check.stdout + check.stderr
    info = store_summary(store)
    assert info["complete"] and "compact" not in info and "stored" not in info["frames"]
    again = run_ltm("reconstruct", store, "--overwrite", "--lattice", "8x8", "--method", "cs",
                    "--scheduler", dask_cluster.scheduler_address)
    assert again.returncode == 0, again.stderr
    assert open_store(store)["samples"].shape[2:] == open_store(store)["ltm"].shape[2:] == (8, 8)
    assert stages(open_group(store))["reconstruct"]["complete"] and not leftovers(store)


def test_reconstruct_overwrite_never_reuses_a_copy_without_frames(small_store, tmp_path, client):
    """A revision beside the store that lacks the store's frames (what a killed compact of an
    earlier version left) is discarded, not resumed."""
    store = copy_store(small_store, tmp_path / "store.zarr")
    side = copy_store(store, revision_path(store))
    group = open_group(side, mode="r+")
    for name in ("frames", "frame_chroma"):
        if name in group:
            del group[name]
    reconstruct(store, client=client, overwrite=True, lattice=(8, 8), method="cs",
                progress=False)
    assert open_store(store)["ltm"].shape[2:] == (8, 8) and (store / "frames").is_dir()
    assert not leftovers(store)
