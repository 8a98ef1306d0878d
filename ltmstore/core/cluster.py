"""The Dask cluster a run uses: a throwaway local one, or an existing scheduler."""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager

from distributed import Client, LocalCluster

from ltmstore.core.errors import LtmError

# One BLAS/FFT thread per worker process: the parallelism is across pixel tiles.
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def dask_client(scheduler: str | None = None, *, n_workers: int | None = None,
                timeout: float = 30, small: bool = False) -> Iterator[Client]:
    """A :class:`distributed.Client` for the run, closed afterwards.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``). Without it a
        :class:`~distributed.LocalCluster` of single-threaded worker processes is started
        (one per core, at most 4) and closed at the end.
    small : bool
        The work is small (:func:`is_small`): without ``scheduler``, run it on threads in this
        process (a :class:`~distributed.LocalCluster` with ``processes=False``, started in a
        fraction of a second) instead of starting worker processes.
    """
    if scheduler:
        try:
            client = Client(scheduler, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise LtmError(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from exc
        with client:
            yield client
        return
    n = n_workers or max(1, min(4, os.cpu_count() or 1))
    if small:
        with LocalCluster(n_workers=1, threads_per_worker=n, processes=False,
                          dashboard_address=None, silence_logs=logging.CRITICAL
                          ) as cluster, Client(cluster) as client:
            yield client
        return
    # The scheduler's HTTP port on any free port (never a collision warning); worker logs
    # quiet: a task's error reaches the client, which reports it as one line, so the worker's
    # own traceback log is noise.
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                      dashboard_address="127.0.0.1:0", env=WORKER_ENV,
                      silence_logs=logging.CRITICAL
                      ) as cluster, Client(cluster) as client:
        yield client


SMALL_BYTES = 256 * 2**20  # inputs below this run on threads: a process cluster costs seconds


def is_small(nbytes: int) -> bool:
    """Whether work on ``nbytes`` of input is small enough for threads in this process."""
    return nbytes < SMALL_BYTES
