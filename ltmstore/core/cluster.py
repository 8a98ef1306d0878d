"""The Dask cluster a run uses: a throwaway local one, or an existing scheduler.

A local cluster listens on loopback only (127.0.0.1): its comms, its scheduler's and workers'
HTTP servers (``/health``, ``/metrics``, the dashboard). Another machine reaches a cluster only
through one the user started and named (``--scheduler``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import dask
from distributed import Client, LocalCluster

from ltmstore.core.errors import LtmError

# One BLAS/FFT thread per worker process: the parallelism is across pixel tiles.
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
# What a nanny sets before it starts its worker, left out: Dask's MALLOC_TRIM_THRESHOLD_=65536
# also fixes glibc's mmap threshold, so every array over 128 KB is mapped and unmapped afresh, and
# a tile's solve (tens of MB of temporaries) costs 1.35-1.4x the CPU (0.96-1.03 against 0.71-0.74 s
# for a Toys tile, one process).
PRE_SPAWN_UNSET = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
SCHEDULER_TIMEOUT_S = 10.0  # an unreachable scheduler fails within this many seconds
LOOPBACK = "127.0.0.1"
# Every HTTP server of a local cluster on a free loopback port: Dask's defaults (":8787", or the
# comm's host, which an in-process cluster has none of) listen on every interface.
LOOPBACK_HTTP = {"dashboard_address": f"{LOOPBACK}:0", "worker_dashboard_address": f"{LOOPBACK}:0"}


@contextmanager
def dask_client(scheduler: str | None = None, *, n_workers: int | None = None,
                timeout: float = SCHEDULER_TIMEOUT_S, small: bool = False) -> Iterator[Client]:
    """A :class:`distributed.Client` for the run, closed afterwards.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``). Without it a
        :class:`~distributed.LocalCluster` of single-threaded worker processes is started
        (one per core, at most 4) and closed at the end.
    n_workers : int, optional
        Workers of the local cluster (default: one per core, at most 4).
    timeout : float
        Seconds to wait for ``scheduler`` before giving up.
    small : bool
        The work is small (:func:`is_small`): without ``scheduler``, run it on threads in this
        process (a :class:`~distributed.LocalCluster` with ``processes=False``, started in a
        fraction of a second) instead of starting worker processes.
    """
    if scheduler:
        client = _connect(scheduler, timeout)
        with client:
            yield client
        return
    n = n_workers or max(1, min(4, os.cpu_count() or 1))
    if small:
        # in-process comms (no socket); the HTTP servers on loopback
        with LocalCluster(n_workers=1, threads_per_worker=n, processes=False,
                          silence_logs=logging.CRITICAL, **LOOPBACK_HTTP
                          ) as cluster, Client(cluster) as client:
            yield client
        return
    # The HTTP servers on any free port (never a collision warning); worker logs quiet: a
    # task's error reaches the client, which reports it as one line, so the worker's own
    # traceback log is noise.
    with dask.config.set(PRE_SPAWN_UNSET), LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK, env=WORKER_ENV,
            silence_logs=logging.CRITICAL, **LOOPBACK_HTTP) as cluster, Client(cluster) as client:
        yield client


def _connect(scheduler: str, timeout: float) -> Client:
    """A client of the scheduler at ``scheduler``, or one :class:`LtmError` line naming it."""
    from distributed.comm import parse_address, parse_host_port

    try:
        parse_host_port(parse_address(scheduler)[1])
    except ValueError as exc:
        raise LtmError(f"--scheduler {scheduler!r} is not a Dask scheduler address ({exc}); "
                       "expected tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786") from None
    try:
        # Client's own timeout does not bound a peer that accepts the connection and never
        # answers (a stalled process, another service): it waits forever. Ask first, bounded.
        kind = _identity(scheduler, timeout)
        if kind != "Scheduler":
            raise ValueError(f"a Dask {kind} answered, not a scheduler")
        return Client(scheduler, timeout=timeout)
    except Exception as exc:  # noqa: BLE001 - whatever answers there, it is not a usable scheduler
        reason = ("no answer" if isinstance(exc, TimeoutError)
                  else " ".join(str(exc).split()) or type(exc).__name__)
        raise LtmError(f"cannot reach Dask scheduler {scheduler!r} within {timeout:g} s: "
                       f"{reason}") from None


def _identity(address: str, timeout: float) -> str:
    """The ``type`` the Dask server at ``address`` reports (``"Scheduler"``), within
    ``timeout`` seconds in all (connection and answer); :class:`TimeoutError` otherwise."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    args = Security().get_connection_args("client")  # TLS from Dask's config, as Client does

    async def ask() -> str:
        comm = await connect(address, timeout=timeout, **args)
        try:
            await comm.write({"op": "identity", "reply": True})
            return str((await comm.read()).get("type"))
        finally:
            comm.abort()

    async def bounded() -> str:
        return await asyncio.wait_for(ask(), timeout)

    with ThreadPoolExecutor(1) as pool:  # its own event loop, even inside a running one
        return pool.submit(asyncio.run, bounded()).result()


SMALL_BYTES = 256 * 2**20  # inputs below this run on threads: a process cluster costs seconds


def is_small(nbytes: int) -> bool:
    """Whether work on ``nbytes`` of input is small enough for threads in this process."""
    return nbytes < SMALL_BYTES
