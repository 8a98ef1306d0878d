"""Prefect's temporary server, started by ``ltm demo`` and ``ltm archive run``: waited for
generously, and a start that fails is one line, never a traceback."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

import pytest

from ltmstore.cli import PREFECT_STARTUP_ENV, PREFECT_STARTUP_TIMEOUT_S, _run

PROBE = """
import sys
from ltmstore.cli import main
try:
    main(["check", "--help"])
except SystemExit:
    pass
assert "prefect" not in sys.modules, "the CLI imported Prefect before setting its environment"
from prefect.settings import PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS as T
print(T.value())
"""


def _prefect_wait(env_value: str | None) -> int:
    env = {k: v for k, v in os.environ.items() if k != PREFECT_STARTUP_ENV}
    if env_value is not None:
        env[PREFECT_STARTUP_ENV] = env_value
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return int(done.stdout.split()[-1])


def test_the_cli_waits_long_for_prefects_temporary_server_unless_told_otherwise():
    assert PREFECT_STARTUP_TIMEOUT_S >= 300  # Prefect's own 20 s failed on a busy machine
    assert _prefect_wait(None) == PREFECT_STARTUP_TIMEOUT_S
    assert _prefect_wait("45") == 45  # the user's setting is kept


def _fails(exc: BaseException) -> argparse.Namespace:
    def func(_):
        raise exc
    return argparse.Namespace(func=func)


def test_a_server_that_does_not_start_is_one_line(capsys, monkeypatch):
    monkeypatch.setenv(PREFECT_STARTUP_ENV, "300")
    prefect = RuntimeError("Timed out while attempting to connect to ephemeral Prefect API "
                           "server. Ephemeral server process exited with code 1. stdout: a\nb "
                           "stderr: Traceback (most recent call last):\n  ...")
    assert _run(_fails(prefect)) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "ltm: error: Prefect's temporary server did not start within 300 s (its process exited "
        f"with code 1); set {PREFECT_STARTUP_ENV} higher, or PREFECT_API_URL to a running "
        "server (prefect server start)"]

    try:  # wrapped by the flow engine: found in the chain
        raise RuntimeError("engine") from prefect
    except RuntimeError as exc:
        assert _run(_fails(exc)) == 2
    assert "did not start within 300 s" in capsys.readouterr().err


def test_another_runtime_error_is_not_taken_for_prefects():
    with pytest.raises(RuntimeError, match="something else"):
        _run(_fails(RuntimeError("something else")))
