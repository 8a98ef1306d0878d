"""Small shared pieces of the pipeline tests."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

BIN = Path(sys.executable).parent


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def dask_processes(n_workers: int = 2, cwd: Path | None = None):
    """A `dask scheduler` and `dask worker` processes on loopback, started in ``cwd``; yields
    the address."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen([BIN / "dask", "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env, cwd=cwd,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(n_workers):
            procs.append(subprocess.Popen(
                [BIN / "dask", "worker", address, "--nthreads", "1", "--no-dashboard",
                 "--host", "127.0.0.1"], env=env, cwd=cwd,
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(n_workers, timeout=60)
        yield address
    finally:
        for proc in procs[::-1]:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()


def run_ltm(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run the installed ``ltm`` command; returns the completed process (text output)."""
    start = time.perf_counter()
    proc = subprocess.run([BIN / "ltm", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)
    proc.seconds = time.perf_counter() - start
    return proc


def ltm_here(capsys, *args) -> subprocess.CompletedProcess:
    """Run ``ltm`` in this process (quicker than :func:`run_ltm` where no separate process is
    under test); returns the same kind of result."""
    from ltmstore.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(["ltm", *map(str, args)], code, out, err)
