"""``reprocess_archive``: bring every new, stale or failed acquisition of an archive up to date.

Thin wiring of :mod:`ltmstore.archive`: one task per acquisition (retried on transient I/O
errors), at most ``max_concurrent`` at a time, sharing one Dask cluster; a failure of one
acquisition is recorded and never stops the others. The run's summary is a Prefect table
artifact (key ``archive-summary``) and the archive's ``.ltm-archive.json``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from prefect import flow, task
from prefect.artifacts import create_table_artifact
from prefect.task_runners import ThreadPoolTaskRunner

from flows.process import transient_io
from ltmstore.archive import (
    ArchiveParams,
    archive_lock,
    archive_status,
    record_runs,
    reprocess,
    summary_row,
)
from ltmstore.core.cluster import dask_client
from ltmstore.core.errors import LtmError
from ltmstore.solve import DEFAULT_METHOD

ARTIFACT_KEY = "archive-summary"
FLOW_NAME = "reprocess-archive"


@task(retries=2, retry_delay_seconds=1, retry_condition_fn=transient_io,
      task_run_name="reprocess-{name}")
def reprocess_task(name: str, folder: str, store: str, params: dict,
                   scheduler: str | None) -> dict:
    return reprocess(folder, store, ArchiveParams(**params), scheduler=scheduler)


def _params(lattice, delta_rs, method, auto, tile) -> ArchiveParams:
    return ArchiveParams(lattice=None if lattice is None else tuple(int(n) for n in lattice),
                         delta_rs=delta_rs, method=method, auto=auto, tile=tile)


@flow(name=FLOW_NAME)
def reprocess_archive(root: str, lattice: list[int] | None = None, delta_rs: float | None = None,
                      method: str = DEFAULT_METHOD, auto: bool = True, tile: int = 32,
                      max_concurrent: int = 2, scheduler: str | None = None) -> list[dict]:
    """Reprocess the new, stale and failed acquisitions under ``root`` (never up-to-date ones).

    Parameters
    ----------
    root : str
        The archive root (see :mod:`ltmstore.archive`).
    lattice, delta_rs, method, auto, tile
        The requested reconstruction parameters (:class:`ltmstore.archive.ArchiveParams`).
    max_concurrent : int
        Acquisitions processed at the same time.
    scheduler : str, optional
        A Dask scheduler address; default: a local cluster for the run.

    Returns
    -------
    list of dict
        The summary rows (acquisition, status, seconds, K/M, held-out error, reason).
    """
    if max_concurrent < 1:
        raise LtmError(f"max_concurrent {max_concurrent!r} must be a positive integer")
    params = _params(lattice, delta_rs, method, auto, tile)
    with archive_lock(root):  # one run per archive root
        entries = archive_status(root, params)
        todo = [e for e in entries if e.status != "up to date"]
        rows = [summary_row(e.name, "up to date", sampling_ratio=e.summary.get("sampling_ratio"))
                for e in entries if e.status == "up to date"]
        blocked = [e for e in todo if "leaves the archive root" in e.reason]
        rows += [summary_row(e.name, "failed", reason=e.reason) for e in blocked]
        todo = [e for e in todo if e not in blocked]
        if todo:
            with dask_client(scheduler) as client:
                rows += _run_all(todo, params, client.scheduler.address, max_concurrent)
        record_runs(root, [r for r in rows if r["status"] != "up to date"])
    rows.sort(key=lambda r: r["acquisition"])
    create_table_artifact(table=rows, key=ARTIFACT_KEY,
                          description=f"reprocess-archive of {root}: "
                          f"{sum(r['status'] == 'reprocessed' for r in rows)} reprocessed, "
                          f"{sum(r['status'] == 'failed' for r in rows)} failed")
    return rows


def _run_all(entries, params: ArchiveParams, address: str, limit: int) -> list[dict]:
    """Run one task per entry, at most ``limit`` at a time; collect a row per entry."""
    with ThreadPoolTaskRunner(max_workers=limit) as runner:
        futures = [(e, runner.submit(reprocess_task, {
            "name": e.name, "folder": str(e.folder), "store": str(e.store),
            "params": params.options(), "scheduler": address})) for e in entries]
        return [_row(e.name, fut.result(raise_on_failure=False)) for e, fut in futures]


def _row(name: str, result) -> dict:
    """The summary row of one task's result (an exception when it failed)."""
    if not isinstance(result, BaseException):
        return summary_row(name, "reprocessed", seconds=result["seconds"],
                           sampling_ratio=result["sampling_ratio"],
                           heldout_error=result["heldout_error"])
    reason = " ".join(str(result).split()) or type(result).__name__
    if not isinstance(result, LtmError):
        reason = f"{type(result).__name__}: {reason}"
    return summary_row(name, "failed", reason=reason)


def serve_archive(root: str, *, cron: str, name: str = "archive", parameters: dict) -> None:
    """Serve ``reprocess_archive`` as deployment ``reprocess-archive/NAME`` on ``cron``.

    Uses the server of ``PREFECT_API_URL``; without one, starts ``prefect server start`` on
    127.0.0.1 for as long as it serves (stopped on exit).
    """
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from ltmstore.archive import _root

    root = str(_root(root))
    parameters = {"root": root, **parameters}
    if PREFECT_API_URL.value():
        reprocess_archive.serve(name=name, cron=cron, parameters=parameters, limit=1)
        return
    with prefect_server() as url, temporary_settings(updates={PREFECT_API_URL: url}):
        print(f"started a Prefect server at {url}", flush=True)
        reprocess_archive.serve(name=name, cron=cron, parameters=parameters, limit=1)


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def prefect_server(port: int | None = None, home: str | os.PathLike | None = None, *,
                   timeout: float = 120) -> Iterator[str]:
    """Run ``prefect server start`` on 127.0.0.1 (its own ``PREFECT_HOME``); yield its API URL.

    The server's process group is terminated (then killed) on exit.
    """
    port = port or free_port()
    own_home = home is None
    home = Path(tempfile.mkdtemp(prefix="ltm-prefect-server-") if own_home else home)
    home.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PREFECT_HOME": str(home), "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
           "PREFECT_UI_ENABLED": "false"}
    env.pop("PREFECT_API_URL", None)
    prefect = Path(sys.executable).with_name("prefect")
    log = open(home / "server.log", "wb")  # noqa: SIM115 - closed in finally
    proc = subprocess.Popen([str(prefect), "server", "start", "--host", "127.0.0.1", "--port",
                             str(port)], env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}/api"
    try:
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None:
                raise LtmError(f"prefect server start exited with status {proc.returncode}; "
                               f"see {str(home / 'server.log')!r}")
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2) as resp:
                    if resp.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise LtmError(f"prefect server on port {port} not healthy after {timeout} s")
            time.sleep(0.5)
        yield url
    finally:
        _stop(proc)
        log.close()
        if own_home:
            shutil.rmtree(home, ignore_errors=True)


def _stop(proc: subprocess.Popen) -> None:
    import signal

    for sig, wait in ((signal.SIGTERM, 15), (signal.SIGKILL, 10)):
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
