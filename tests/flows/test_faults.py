"""Faults with real processes: a Dask worker killed mid-run, a full disk, an unwritable store."""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from archive_helpers import (
    N_TILES,
    SLOW_ARGS,
    copy_store,
    dask_cluster_processes,
    ingest_only,
    kill_group,
    slow_reference,
    start_reconstruct,
    tree_digest,
    wait_for_tiles,
)
from pipeline_helpers import BIN, tmpfs

from ltmstore.core.store import open_group, open_store, stages


def test_a_worker_killed_mid_run_the_run_completes_with_the_same_values(small_store, tmp_path,
                                                                          dask_cluster):
    reference = slow_reference(small_store, dask_cluster)
    store = ingest_only(small_store, tmp_path / "store.zarr")
    with dask_cluster_processes(2) as (address, workers):
        proc = start_reconstruct(store, *SLOW_ARGS, "--scheduler", address)
        try:
            wait_for_tiles(proc, store, 1)
            kill_group(workers[0])  # the nanny and its worker, SIGKILL: tasks on it are lost
            _, stderr = proc.communicate(timeout=300)
        finally:
            kill_group(proc)
    assert proc.returncode == 0, stderr.decode()
    rec = stages(open_group(store))["reconstruct"]
    assert rec["complete"] and rec["tiles_solved"] == N_TILES
    for name in ("ltm", "expected_error", "unsupported"):
        np.testing.assert_array_equal(open_store(store)[name].values,
                                      open_store(reference)[name].values, err_msg=name)


def one_error_line(stderr: str) -> str:
    """The one `ltm: error:` line, last on stderr (progress bars may come before it)."""
    lines = stderr.strip().splitlines()
    assert "Traceback" not in stderr, stderr
    assert [line for line in lines if line.startswith("ltm: error")] == lines[-1:], stderr
    return lines[-1]


def _file_size_limit(limit: int):
    """A process whose files may not grow past ``limit`` bytes: writes fail with EFBIG, as on a
    full disk (Python ignores SIGXFSZ, so the write returns the error)."""
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_full_disk_during_ingest_is_a_clear_error_and_the_good_store_is_untouched(
        small_acquisition, small_store, tmp_path):
    acquisition = tmp_path / "acquisition"
    shutil.copytree(small_acquisition, acquisition, ignore=shutil.ignore_patterns("truth.zarr"))
    store = copy_store(small_store, tmp_path / "store.zarr")
    before, inputs = tree_digest(store), tree_digest(acquisition)
    proc = subprocess.run([BIN / "ltm", "ingest", acquisition, store, "--overwrite"],
                          capture_output=True, text=True, timeout=120,
                          preexec_fn=_file_size_limit(16 * 1024))
    assert proc.returncode == 2, proc.stderr
    assert one_error_line(proc.stderr).startswith("ltm: error: cannot write store")
    assert "File too large" in proc.stderr
    assert tree_digest(store) == before and tree_digest(acquisition) == inputs
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial left


# A store of many chunks written at once (Zarr writes them as concurrent tasks) onto a disk that
# fills part-way, in a process of its own: its exit shows what it left running.
MANY_CHUNKS = """
import sys
import numpy as np
from ltmstore.core.errors import LtmError
from ltmstore.core.store import create_variable, new_store
try:
    with new_store(sys.argv[1]) as group:
        values = np.random.default_rng(0).random((256, 4096), dtype=np.float32)
        create_variable(group, "x", ("t", "y"), values.shape, chunks=(1, 4096))[...] = values
except LtmError as exc:
    print(exc, file=sys.stderr)
    sys.exit(2)
"""


def test_a_disk_that_fills_mid_write_is_left_as_empty_as_it_was(tmp_path):
    """When one chunk write fails, Zarr raises while its other writes go on: the partial store
    is removed only after they settle (before: 2-30 chunk files left on each of 5 trials)."""
    with tmpfs(tmp_path / "disk", "2m") as disk:
        for trial in range(3):
            proc = subprocess.run([BIN / "python", "-c", MANY_CHUNKS, disk / "store.zarr"],
                                  capture_output=True, text=True, timeout=120)
            assert proc.returncode == 2, proc.stderr
            assert proc.stderr.strip().endswith("No space left on device"), proc.stderr
            assert "Task was destroyed" not in proc.stderr  # nothing left running at exit
            assert list(disk.iterdir()) == [], trial


def test_full_disk_during_reconstruct_is_a_clear_error_and_never_complete(small_store,
                                                                        tmp_path):
    """A first reconstruct (in place) on a full disk: its stage stays incomplete."""
    store = ingest_only(small_store, tmp_path / "store.zarr")
    proc = subprocess.run([BIN / "ltm", "reconstruct", store, "--lattice", "16x16"],
                          capture_output=True, text=True, timeout=120,
                          preexec_fn=_file_size_limit(8 * 1024))
    assert proc.returncode == 2, proc.stderr
    assert one_error_line(proc.stderr).startswith("ltm: error: cannot write store")
    assert stages(open_group(store))["reconstruct"]["complete"] is False
    assert "ltm" not in open_store(store)


@pytest.mark.parametrize("limit", [8 * 1024, 256 * 1024])  # fails copying / writing the ltm
def test_full_disk_during_overwrite_leaves_the_good_ltm_untouched(small_store, tmp_path, limit):
    store = copy_store(small_store, tmp_path / "store.zarr")
    before = tree_digest(store)
    proc = subprocess.run([BIN / "ltm", "reconstruct", store, "--lattice", "16x16",
                           "--overwrite"], capture_output=True, text=True, timeout=120,
                          preexec_fn=_file_size_limit(limit))
    assert proc.returncode == 2, proc.stderr
    line = one_error_line(proc.stderr)
    assert line.startswith("ltm: error: cannot write store") and "untouched" in line
    assert tree_digest(store) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no revision left


def _without_root_override():
    """As root, drop the capabilities that let root write into read-only files (the process
    then obeys the permission bits like any user); nothing to do for other users."""
    if os.geteuid() != 0:
        return None

    def apply() -> None:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_capbset_drop = 24
        for cap in (1, 2, 3):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, CAP_FOWNER
            if libc.prctl(pr_capbset_drop, cap, 0, 0, 0) != 0:
                raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) failed")
    return apply


def test_unwritable_store_is_a_clear_error_before_any_write(small_store):
    base = Path(tempfile.mkdtemp(prefix="ltm-readonly-"))
    try:
        os.chmod(base, 0o755)
        store = copy_store(small_store, base / "store.zarr")
        for path in [store, *store.rglob("*")]:
            path.chmod(0o555 if path.is_dir() else 0o444)
        before = tree_digest(store)
        proc = subprocess.run([BIN / "ltm", "reconstruct", store, "--lattice", "16x16",
                               "--overwrite"], capture_output=True, text=True, timeout=120,
                              preexec_fn=_without_root_override())
        assert proc.returncode == 2, proc.stderr
        assert "is not writable" in one_error_line(proc.stderr)
        assert tree_digest(store) == before
        assert stages(open_group(store))["reconstruct"]["complete"] is True
    finally:
        for path in base.rglob("*"):
            if path.is_dir():
                path.chmod(0o755)
        shutil.rmtree(base, ignore_errors=True)


@pytest.mark.parametrize("target", ["missing-folder/store.zarr", "file.txt/store.zarr"])
def test_store_in_an_impossible_place_is_a_clear_error(small_acquisition, tmp_path, target):
    (tmp_path / "file.txt").write_text("not a folder")
    proc = subprocess.run([BIN / "ltm", "ingest", small_acquisition, tmp_path / target],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    one_error_line(proc.stderr)
