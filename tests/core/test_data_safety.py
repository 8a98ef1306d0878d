"""Nothing lost: --overwrite only replaces stores, one writer at a time, a killed swap recovers,
dead processes' partial stores are cleaned (issue 13, items 6-9). Real processes, real files."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from ingest_helpers import make_acquisition, tree_hashes
from pipeline_helpers import BIN, ltm_here, only_error_line, run_ltm

from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_group, stages
from ltmstore.core.swap import PAUSE_ENV, journal_path, recover, swap_in
from ltmstore.stages.ingest import ingest


@pytest.fixture(scope="module")
def acq(tmp_path_factory) -> Path:
    return make_acquisition(tmp_path_factory.mktemp("safety") / "acq")


@pytest.fixture
def store(acq, tmp_path) -> Path:
    out = tmp_path / "store.zarr"
    ingest(acq, out, progress=False)
    return out


def start_ltm(*args, pause: float = 60) -> subprocess.Popen:
    """``ltm`` in the background, pausing ``pause`` s between the two renames of its swap."""
    env = {**os.environ, PAUSE_ENV: str(pause)}
    return subprocess.Popen([BIN / "ltm", *map(str, args)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_for(condition, proc: subprocess.Popen, timeout: float = 60) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < end, "timed out"
        time.sleep(0.02)


def in_swap(path: Path):
    """True while a swap into ``path`` is between its two renames."""
    return lambda: journal_path(path).exists() and not path.exists()


def test_overwrite_never_replaces_an_input(acq, capsys):
    before = tree_hashes(acq.parent)
    only_error_line(run_ltm("ingest", acq, acq, "--overwrite"), "input")
    for path in (acq.parent, acq / "video.mkv"):
        only_error_line(ltm_here(capsys, "ingest", acq, path, "--overwrite"), "input")
    assert tree_hashes(acq.parent) == before


def test_overwrite_replaces_only_a_store(acq, tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "a.jpg").write_bytes(b"precious")
    only_error_line(ltm_here(capsys, "ingest", acq, folder, "--overwrite"),
                   "not a store made by ltm")
    assert (folder / "a.jpg").read_bytes() == b"precious"


def test_a_second_writer_is_refused_in_one_line(acq, store):
    first = start_ltm("ingest", acq, store, "--overwrite")
    try:
        wait_for(in_swap(store), first)
        second = run_ltm("ingest", acq, store, "--overwrite")
        only_error_line(second, f"is being written by process {first.pid} on host")
    finally:
        first.kill()
        first.wait()


@contextmanager
def held_in_another_process(lock: str, path: Path):
    """Hold ``lock(path)`` (``module:function``) in a second Python process; yields its pid."""
    module, function = lock.split(":")
    holder = subprocess.Popen(
        [sys.executable, "-c", f"import sys, time; from {module} import {function}\n"
         f"with {function}(sys.argv[1]):\n print('locked', flush=True); time.sleep(60)",
         str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        yield holder.pid
    finally:
        holder.kill()
        holder.wait()


def test_a_second_reconstruct_is_refused_in_one_line(store):
    with held_in_another_process("ltmstore.core.lock:locked", store) as pid:
        only_error_line(run_ltm("reconstruct", store, "--lattice", "8x8"),
                       f"is being written by process {pid} on host")
    assert "reconstruct" not in stages(open_group(store))


def test_the_lock_of_a_dead_process_is_taken_over(acq, store):
    lock = store.parent / f".{store.name}.lock"
    lock.write_text(json.dumps({"pid": 999999, "host": "elsewhere"}))
    ingest(acq, store, overwrite=True, progress=False)
    assert not lock.exists()


def test_one_archive_run_per_root(tmp_path, prefect_harness):
    from flows.archive import reprocess_archive

    with held_in_another_process("ltmstore.archive:archive_lock", tmp_path) as pid:
        with pytest.raises(LtmError, match=f"archive .* is being written by process {pid}"):
            reprocess_archive.fn(str(tmp_path))


def test_a_kill_between_the_renames_is_finished_by_the_next_command(acq, store):
    proc = start_ltm("ingest", acq, store, "--overwrite")
    wait_for(in_swap(store), proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not store.exists()  # the window: no store at its path
    info = run_ltm("info", store)
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["stages"]["ingest"]["complete"] is True
    assert sorted(p.name for p in store.parent.iterdir()) == ["store.zarr"]


def test_a_swap_is_flushed_to_disk(tmp_path, monkeypatch):
    side, path = tmp_path / "side", tmp_path / "store"
    (side / "a").mkdir(parents=True)
    (side / "a" / "chunk").write_bytes(b"data")
    flushed = []
    real = os.fsync

    def fsync(fd):
        flushed.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)
    monkeypatch.setattr("ltmstore.core.swap.os.fsync", fsync)
    swap_in(side, path)
    assert {str(side / "a" / "chunk"), str(side / "a"), str(tmp_path)} <= set(flushed)
    assert (path / "a" / "chunk").read_bytes() == b"data"


def test_an_interrupted_swap_without_its_new_store_is_rolled_back(store, tmp_path):
    old = tmp_path / ".store.zarr.old-1"
    store.rename(old)
    journal_path(store).write_text(json.dumps({"side": str(tmp_path / "gone"),
                                               "old": str(old)}))
    assert recover(store) == "rolled back"
    assert stages(open_group(store))["ingest"]["complete"]
    assert not old.exists() and not journal_path(store).exists()


def test_a_killed_ingest_leaves_nothing_behind(acq, tmp_path):
    store = tmp_path / "store.zarr"
    dead = tmp_path / ".store.zarr.partial-999999"  # what a killed ingest leaves
    (dead / "frames").mkdir(parents=True)
    (dead / "frames" / "zarr.json").write_text("{}")
    proc = start_ltm("ingest", acq, store)
    wait_for(lambda: journal_path(store).exists(), proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    ingest(acq, store, overwrite=True, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store.zarr"]


def test_a_chunk_half_written_by_a_killed_process_is_removed_by_the_next_writer(store):
    """Zarr writes a chunk to a temporary file and renames it: a process killed in between
    leaves ``<key>.<hex>.partial``, which the damage check counts as outside the chunk grid.
    The next command that takes the store's write lock removes it, and nothing else."""
    from ltmstore.core.store import open_store, writing

    chunks = store / "frames" / "c"
    first = next(p for p in sorted(chunks.rglob("*")) if p.is_file())
    stray = first.with_name(first.name + ".0123456789abcdef0123456789abcdef.partial")
    stray.write_bytes(b"half")
    with pytest.raises(LtmError, match=r"\.partial lie outside the chunk grid"):
        open_store(store)
    before = {p for p in store.rglob("*") if p != stray}
    with writing(store):
        pass
    assert not stray.exists() and {p for p in store.rglob("*")} == before
    open_store(store)
