"""``ltm reconstruct --scheduler`` on a cluster started as a user starts one (`dask scheduler` and
`dask worker` processes), and one ``ltm: error:`` line, exit 2, for an address that does not
answer (issue 25, item 5)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pipeline_helpers import dask_processes, only_error_line, run_ltm

from ltmstore.core.cluster import SCHEDULER_TIMEOUT_S, dask_client
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store


def test_reconstruct_runs_its_tiles_on_the_named_scheduler(small_store, tmp_path):
    from distributed import Client

    store = shutil.copytree(small_store, tmp_path / "store.zarr")
    with dask_processes(1) as address:
        proc = run_ltm("reconstruct", store, "--lattice", "16x16", "--overwrite",
                       "--scheduler", address)
        with Client(address, timeout=30) as client:  # what ran there: resampling, the tiles
            prefixes = client.run_on_scheduler(lambda dask_scheduler: sorted(
                dask_scheduler.task_prefixes))
    assert proc.returncode == 0, proc.stderr
    assert {"resample_region", "solve_tiles_task"} <= set(prefixes), prefixes
    expected = open_store(small_store)["ltm"].values  # the session's LocalCluster, same input
    np.testing.assert_allclose(open_store(store)["ltm"].values, expected, rtol=1e-5, atol=1e-7)


@pytest.fixture
def silent_address():
    """An address whose listener never accepts: connections complete in the kernel and nothing
    ever answers (a stalled process). ``Client(address, timeout=...)`` waited there forever."""
    with socket.socket() as mute:
        mute.bind(("127.0.0.1", 0))
        mute.listen(0)
        yield f"tcp://127.0.0.1:{mute.getsockname()[1]}"


def test_a_silent_scheduler_fails_within_the_timeout(silent_address):
    start = time.perf_counter()
    with pytest.raises(LtmError, match=f"cannot reach Dask scheduler '{silent_address}' "
                                       "within 1 s: no answer"):
        with dask_client(silent_address, timeout=1):
            pass
    assert time.perf_counter() - start < 10  # measured 1.0 s


def test_reconstruct_at_a_silent_scheduler_fails_in_one_line(small_store, tmp_path,
                                                              silent_address):
    """Exit 2 and one line naming the address, within the connect timeout; nothing written."""
    store = shutil.copytree(small_store, tmp_path / "store.zarr")
    before = open_store(store)["ltm"].values
    proc = run_ltm("reconstruct", store, "--lattice", "16x16", "--overwrite",
                   "--scheduler", silent_address, timeout=120)
    only_error_line(proc, repr(silent_address), "cannot reach Dask scheduler", "no answer")
    assert proc.seconds < SCHEDULER_TIMEOUT_S + 30, proc.seconds  # measured 12.3 s at load 10
    np.testing.assert_array_equal(open_store(store)["ltm"].values, before)
    assert [p.name for p in tmp_path.iterdir()] == ["store.zarr"]  # no revision copy left


def test_a_worker_address_is_not_taken_for_a_scheduler(dask_cluster):
    worker = next(iter(dask_cluster.scheduler_info["workers"]))
    with pytest.raises(LtmError, match="a Dask Worker answered, not a scheduler"):
        with dask_client(worker, timeout=5):
            pass
    with dask_client(dask_cluster.scheduler_address, timeout=5) as client:  # the scheduler is
        assert client.scheduler_info()["workers"]


def test_the_local_cluster_workers_keep_glibcs_own_memory_thresholds():
    """A fresh process (as ``ltm``) starts worker processes without Dask's
    MALLOC_TRIM_THRESHOLD_ (which fixes glibc's mmap threshold: a tile's solve 1.35-1.4x
    slower), with one BLAS thread each."""
    script = ("import os\nfrom ltmstore.core.cluster import dask_client\n"
              "if __name__ == '__main__':\n"
              "    with dask_client(n_workers=1) as c:\n"
              "        env = c.run(lambda: [os.environ.get(k) for k in\n"
              "                             ('MALLOC_TRIM_THRESHOLD_', 'OMP_NUM_THREADS')])\n"
              "    print(list(env.values()))\n")
    assert _fresh_process(script, timeout=120).strip().splitlines()[-1] == "[[None, '1']]"


def test_a_task_gives_its_freed_heap_back_to_the_system():
    """Without Dask's trim threshold a worker's freed heap stays resident (the tiles'
    temporaries carried into the next tile and the light-major copy); ``memory.trim``, called
    after each tile and around each band of the copy, gives it back. A fresh process frees
    256 MiB of small blocks below one it keeps (so the heap cannot shrink by itself): its
    resident memory falls by all of them (0 MiB without the trim)."""
    script = ("import psutil\nfrom ltmstore.core import memory\n"
              "blocks = [bytearray(64 << 10) for _ in range(4096)]\n"
              "keep = blocks[-1]\n"
              "del blocks\n"
              "before = psutil.Process().memory_info().rss\n"
              "trimmed = memory.trim()\n"
              "print(trimmed, (before - psutil.Process().memory_info().rss) >> 20)\n")
    trimmed, freed_mib = _fresh_process(script, timeout=60).split()
    assert trimmed == "True"  # glibc, as on every machine this runs on
    assert int(freed_mib) >= 240


HEAP_GROWTH = """
import ctypes
from ltmstore.core import memory
libc = ctypes.CDLL(None)  # glibc's own allocator, as libavcodec and NumPy use it
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
def heap() -> int:
    for line in open("/proc/self/maps"):
        if line.rstrip().endswith("[heap]"):
            start, end = (int(x, 16) for x in line.split()[0].split("-"))
            return end - start
    return 0
mapped = memory.map_large_buffers() if {mapped} else None
libc.free(libc.malloc(25 << 20))  # a 4K frame's RGB codes, freed
before = heap()
held = [libc.malloc(25 << 20) for _ in range(20)]  # the next frames' buffers
print(mapped, (heap() - before) >> 20)
"""


def test_frame_sized_buffers_are_mapped_on_their_own_while_ingest_decodes():
    """glibc raises its mmap threshold to the size of a freed mapped buffer, so the buffers of
    the frames after it come from the heap (where ``ltm ingest`` of a 4K video grew by 14-23 GB
    in 3 bench runs); a ``VideoReader`` calls ``memory.map_large_buffers`` first. A fresh
    process frees one 25 MB buffer and then holds 20 more: the heap grows by all of them
    (500 MiB) without the setting, by none with it."""
    default = _fresh_process(HEAP_GROWTH.format(mapped=False), timeout=60).split()
    assert default == ["None", "500"]
    mapped, grown_mib = _fresh_process(HEAP_GROWTH.format(mapped=True), timeout=60).split()
    assert mapped == "True"  # glibc, as on every machine this runs on
    assert int(grown_mib) == 0


def _fresh_process(script: str, *, timeout: float) -> str:
    """The standard output of ``script`` run by a fresh Python (as ``ltm`` starts), without a
    MALLOC_TRIM_THRESHOLD_ of this process's environment; it must exit 0."""
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=timeout, env=env)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_a_dropped_comm_future_prints_nothing_after_the_error_line():
    """A cluster's dropped future with a ``TimeoutError`` (seen once after a full disk ended a
    reconstruct) is not printed at exit, after the command's one error line: ``ltm`` filters
    asyncio's record of it."""
    code = ("import asyncio, gc\n"
            "from ltmstore.cli import main\n"
            "main(['info', '/nonexistent/store.zarr'])\n"
            "async def drop():\n"
            "    f = asyncio.get_running_loop().create_future()\n"
            "    f.set_exception(TimeoutError('Timeout'))\n"
            "asyncio.run(drop()); gc.collect()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "never retrieved" not in proc.stderr, proc.stderr
