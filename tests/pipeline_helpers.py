"""Small shared pieces of the pipeline tests."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

BIN = Path(sys.executable).parent
# `dask scheduler` and `dask worker` on loopback only: without --dashboard-address their HTTP
# servers (health, metrics) listen on 0.0.0.0 even with --no-dashboard.
LOOPBACK = ["--host", "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0"]


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
    procs = [subprocess.Popen([BIN / "dask", "scheduler", "--port", str(port), *LOOPBACK],
                              env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        for _ in range(n_workers):
            procs.append(subprocess.Popen(
                [BIN / "dask", "worker", address, "--nthreads", "1", *LOOPBACK], env=env, cwd=cwd,
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


def tcp_listeners() -> dict[tuple[str, int], str]:
    """Every TCP address this process and its descendants listen on, with the command line."""
    import psutil

    me = psutil.Process()
    found = {}
    for proc in [me, *me.children(recursive=True)]:
        try:
            for conn in proc.net_connections(kind="tcp"):
                if conn.status == psutil.CONN_LISTEN:
                    found[conn.laddr.ip, conn.laddr.port] = " ".join(proc.cmdline()[:3])
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return found


def beyond_loopback(listeners: dict[tuple[str, int], str]) -> dict[tuple[str, int], str]:
    """The listeners of :func:`tcp_listeners` that another machine could reach."""
    return {addr: cmd for addr, cmd in listeners.items() if addr[0] not in ("127.0.0.1", "::1")}


def only_error_line(proc: subprocess.CompletedProcess, *words: str) -> None:
    """Exit status 2 and stderr exactly one ``ltm: error:`` line holding every word."""
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert len(lines) == 1 and lines[0].startswith("ltm: error: "), proc.stderr
    assert all(w in lines[0] for w in words), proc.stderr


def ltm_here(capsys, *args) -> subprocess.CompletedProcess:
    """Run ``ltm`` in this process (quicker than :func:`run_ltm` where no separate process is
    under test); returns the same kind of result."""
    from ltmstore.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(["ltm", *map(str, args)], code, out, err)


@contextmanager
def tmpfs(folder: Path, size: str):
    """``folder`` as a real disk of ``size`` (a tmpfs, ``64k``, ``3m``), unmounted after; the
    test is skipped where mounting needs root or is not allowed."""
    import pytest

    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                          capture_output=True, text=True)
    if proc.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=False)


def one_line_error(proc, pattern: str) -> None:
    """Exit status 2 and exactly one error line, the last one (a progress bar may precede it)."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    errors = [line for line in lines if line.startswith("ltm") and "error" in line]
    assert errors == [lines[-1]], proc.stderr
    assert pattern in lines[-1], proc.stderr
    assert "Traceback" not in proc.stderr


def default_sigint() -> None:
    """In the child, before exec: Ctrl-C's default disposition. A suite started in the
    background (``nohup pytest ... &``) ignores SIGINT and a child would inherit that; the
    product keeps it so (``nohup ltm ... &`` should ignore Ctrl-C), the test wants a Ctrl-C."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@contextmanager
def served_view(store: Path):
    """``ltm view STORE`` as a real process: yields (process, URL); killed at the end."""
    proc = subprocess.Popen([BIN / "ltm", "view", str(store)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        line = proc.stdout.readline()
        assert "http://127.0.0.1:" in line, (line, proc.poll() and proc.stderr.read())
        yield proc, line.split(" at ")[1].split()[0]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
