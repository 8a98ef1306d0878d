"""Shared pieces of the archive, resume and fault tests (imported as a plain module)."""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import signal
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import psutil
import zarr
from pipeline_helpers import BIN, LOOPBACK, free_port

from ltmstore.archive import ArchiveParams
from ltmstore.core.store import STAGE_VARIABLES, STAGES_ATTR
from ltmstore.stages.reconstruct import reconstruct, tiles_name

# A slow solver on a small lattice: 16 tiles of ~0.2-0.5 s each, so a kill lands mid-run.
SLOW = {"lattice": (8, 8), "tile": 8, "method": "lars"}
SLOW_ARGS = ["--lattice", "8x8", "--tile", "8", "--method", "lars"]
N_TILES = 16


def tree_digest(path: Path) -> dict[str, str]:
    """sha256 of every file under ``path`` (or of ``path`` itself), by relative name."""
    path = Path(path)
    if path.is_file():
        return {"": hashlib.sha256(path.read_bytes()).hexdigest()}
    return {str(f.relative_to(path)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(path.rglob("*")) if f.is_file() and not f.is_symlink()}


def tiles_done(store: Path, variable: str = "ltm") -> int:
    """How many tiles an (interrupted) reconstruct marked done; 0 while none can be read."""
    try:
        marks = zarr.open_group(str(store), mode="r")[tiles_name(variable)][...]
    except Exception:  # noqa: BLE001 - not created yet, or being written
        return 0
    return int((np.asarray(marks, dtype=object) != "").sum())


def start_reconstruct(store: Path, *args: str, env: dict | None = None) -> subprocess.Popen:
    """`ltm reconstruct STORE ARGS` in its own process group."""
    return subprocess.Popen([BIN / "ltm", "reconstruct", store, *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True, env=env)


def wait_for_tiles(proc: subprocess.Popen, store: Path, n: int = 1, timeout: float = 400) -> None:
    """Poll until ``n`` tiles are marked done (the process must still run). The timeout only
    catches a hung run: a clean clone's first run compiles the kernels in each Dask worker, and
    beside the other xdist worker's tests one took over 120 s to its first tile."""
    deadline = time.monotonic() + timeout
    while tiles_done(store) < n:
        assert proc.poll() is None, "the run ended before the kill"
        assert time.monotonic() < deadline, "no tile finished in time"
        time.sleep(0.02)


def kill_group(proc: subprocess.Popen, timeout: float = 30) -> None:
    """SIGKILL ``proc``'s process group and wait until none of it runs: a Dask worker of the
    group can outlive its reaped leader by a system call (a chunk's rename, a tile's mark)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=timeout)
    deadline = time.monotonic() + timeout
    while any(_in_group(p, proc.pid) for p in psutil.process_iter()):
        assert time.monotonic() < deadline, f"process group {proc.pid} outlived SIGKILL"
        time.sleep(0.01)


def _in_group(process: psutil.Process, pgid: int) -> bool:
    """Whether ``process`` runs, not a zombie, in process group ``pgid``."""
    try:
        return os.getpgid(process.pid) == pgid and process.status() != psutil.STATUS_ZOMBIE
    except (ProcessLookupError, psutil.NoSuchProcess):
        return False


@contextmanager
def dask_cluster_processes(n_workers: int = 2):
    """`dask scheduler` + ``n_workers`` `dask worker` processes, each in its own process group.

    Yields ``(address, workers)``; every group is killed on exit.
    """
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env,
             "start_new_session": True}
    procs = [subprocess.Popen([BIN / "dask", "scheduler", "--port", str(port), *LOOPBACK],
                              **quiet)]
    try:
        workers = [subprocess.Popen([BIN / "dask", "worker", address, "--nthreads", "1",
                                     *LOOPBACK], **quiet)
                   for _ in range(n_workers)]
        procs += workers
        with Client(address, timeout=60) as client:
            client.wait_for_workers(n_workers, timeout=60)
        yield address, workers
    finally:
        for proc in procs[::-1]:
            kill_group(proc)


_REFERENCE: dict[str, Path] = {}


def slow_reference(small_store: Path, dask_cluster) -> Path:
    """The uninterrupted :data:`SLOW` reconstruction of ``small_store`` (made once a session)."""
    import tempfile

    from distributed import Client

    if str(small_store) not in _REFERENCE:
        folder = tempfile.mkdtemp(prefix="ltm-ref-")
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        store = copy_store(small_store, Path(folder) / "ref.zarr")
        with Client(dask_cluster) as client:
            info = reconstruct(store, client=client, overwrite=True, progress=False, **SLOW)
        assert info["tiles_solved"] == N_TILES and info["tiles_resumed"] == 0
        _REFERENCE[str(small_store)] = store
    return _REFERENCE[str(small_store)]


def copy_store(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def ingest_only(src: Path, dst: Path) -> Path:
    """A copy of ``src`` as ingest left it (no resample or reconstruct): reconstruct writes it in
    place, where an ``--overwrite`` of a complete store works on a revision beside it."""
    shutil.copytree(src, dst)
    group = zarr.open_group(str(dst), mode="r+")
    for name in (*STAGE_VARIABLES["resample"], *STAGE_VARIABLES["reconstruct"]):
        if name in group:
            del group[name]
    group.attrs[STAGES_ATTR] = {"ingest": group.attrs[STAGES_ATTR]["ingest"]}
    return dst


PARAMS = ArchiveParams(lattice=(12, 12), tile=16)
ARGS = ["--lattice", "12x12", "--tile", "16"]


def make_stale(store) -> None:
    """Pretend an older ltmstore made the store (what an upgrade leaves behind)."""
    group = zarr.open_group(str(store), mode="r+")
    stages = group.attrs["stages"]
    stages["reconstruct"]["software"] = "ltmstore 0.0.1"
    stages["reconstruct"]["run"]["software"] = "0.0.1"
    group.attrs["stages"] = stages


def build_archive(root, acquisition, good_store) -> None:
    """a: up to date, b: stale, c: new, d: broken acquisition.json, e: symlink out of the root."""
    root.mkdir()
    for name in "abcd":
        shutil.copytree(acquisition, root / name, ignore=shutil.ignore_patterns("truth.zarr"))
    shutil.copytree(good_store, root / "a.zarr")
    shutil.copytree(good_store, root / "b.zarr")
    make_stale(root / "b.zarr")
    (root / "d" / "acquisition.json").write_text('{"format": "ltm-acquisition/1", "video": ')
    (root / "e").symlink_to(acquisition)


def make_good_store(small_store, tmp_path_factory, dask_cluster) -> Path:
    """The small acquisition reconstructed with the archive's parameters (once a session)."""
    from distributed import Client

    key = f"good:{small_store}"
    if key not in _REFERENCE:
        store = tmp_path_factory.mktemp("good") / "store.zarr"
        shutil.copytree(small_store, store)
        with Client(dask_cluster) as client:
            reconstruct(store, client=client, overwrite=True, progress=False,
                        **PARAMS.options())
        _REFERENCE[key] = store
    return _REFERENCE[key]
