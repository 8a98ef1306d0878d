"""A real Prefect server, `ltm archive serve` with a cron schedule, a triggered deployment run:
exactly the stale acquisition is reprocessed."""

from __future__ import annotations

import os
import shutil
import subprocess
import time

import pytest
from archive_helpers import ARGS, PARAMS, build_archive, make_good_store, tree_digest
from pipeline_helpers import BIN, beyond_loopback, tcp_listeners

from flows.archive import FLOW_NAME, _stop, prefect_server
from ltmstore.archive import archive_status
from ltmstore.core.store import store_summary

CRON = "0 2 * * *"
DEPLOYMENT = "nightly"


@pytest.fixture(scope="module")
def good_store(small_store, tmp_path_factory, dask_cluster):
    return make_good_store(small_store, tmp_path_factory, dask_cluster)


def wait_for(fn, what: str, timeout: float, alive: subprocess.Popen | None = None):
    deadline = time.monotonic() + timeout
    while True:
        try:
            value = fn()
        except Exception:  # noqa: BLE001 - not there yet
            value = None
        if value:
            return value
        assert alive is None or alive.poll() is None, f"the serve process exited before {what}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.5)


def test_served_deployment_reprocesses_exactly_the_stale_acquisitions(tmp_path,
                                                                      small_acquisition,
                                                                      good_store):
    from prefect.client.orchestration import get_client
    from prefect.settings import PREFECT_API_URL, temporary_settings

    root = tmp_path / "archive"
    build_archive(root, small_acquisition, good_store)
    for name in ("c", "d", "e"):  # keep one up-to-date and one stale acquisition
        path = root / name
        if path.is_symlink():
            path.unlink()
        else:
            shutil.rmtree(path)
    assert {e.name: e.status for e in archive_status(root, PARAMS)} == {
        "a": "up to date", "b": "stale"}
    untouched, stale_before = tree_digest(root / "a.zarr"), tree_digest(root / "b.zarr")

    with prefect_server(home=tmp_path / "server") as url:
        env = {**os.environ, "PREFECT_API_URL": url, "PREFECT_HOME": str(tmp_path / "client"),
               "PREFECT_RUNNER_POLL_FREQUENCY": "1"}  # pick the triggered run up at once
        log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115
        serve = subprocess.Popen([BIN / "ltm", "archive", "serve", root, "--cron", CRON,
                                  "--name", DEPLOYMENT, *ARGS], env=env, stdout=log,
                                 stderr=subprocess.STDOUT, start_new_session=True,
                                 cwd=tmp_path)
        try:
            with temporary_settings(updates={PREFECT_API_URL: url}), \
                    get_client(sync_client=True) as client:
                deployment = wait_for(
                    lambda: client.read_deployment_by_name(f"{FLOW_NAME}/{DEPLOYMENT}"),
                    "the deployment", 120, serve)
                crons = [s.schedule.cron for s in deployment.schedules]
                assert crons == [CRON] and deployment.parameters["lattice"] == [12, 12]
                run = client.create_flow_run_from_deployment(deployment.id)
                state = wait_for(lambda: (s := client.read_flow_run(run.id).state).is_final()
                                 and s, "the flow run", 240, serve)
                assert state.is_completed(), (state, (tmp_path / "serve.log").read_text())
                listeners = tcp_listeners()  # the server, `ltm archive serve` and its runner
                assert not beyond_loopback(listeners), listeners
        finally:
            _stop(serve)
            log.close()

    assert tree_digest(root / "a.zarr") == untouched  # up to date: never touched
    assert tree_digest(root / "b.zarr") != stale_before  # stale: reprocessed
    assert store_summary(root / "b.zarr")["complete"]
    assert {e.name: e.status for e in archive_status(root, PARAMS)} == {
        "a": "up to date", "b": "up to date"}
