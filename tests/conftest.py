"""Session fixtures: an isolated Prefect, one simulated acquisition, one local Dask cluster."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import pytest
from threadpoolctl import threadpool_limits

# Two xdist workers share two cores: one BLAS/OpenMP thread each (one A/B run: 30 s of 11 min). The
# plugins have loaded NumPy's BLAS already, hence threadpoolctl; the variables reach libraries
# loaded later and every subprocess.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
threadpool_limits(1)

_PREFECT_HOME = tempfile.mkdtemp(prefix="ltm-prefect-")
atexit.register(shutil.rmtree, _PREFECT_HOME, ignore_errors=True)  # each run left one behind
os.environ.setdefault("PREFECT_HOME", _PREFECT_HOME)
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "90")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")


@pytest.fixture(scope="session")
def prefect_harness():
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=90):
        yield


@pytest.fixture(scope="session")
def dask_cluster():
    """A real LocalCluster with 2 single-threaded worker processes, shared by the session."""
    from distributed import LocalCluster

    from ltmstore.core.cluster import WORKER_ENV

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address="127.0.0.1:0", env=WORKER_ENV) as cluster:
        yield cluster


@pytest.fixture
def client(dask_cluster):
    from distributed import Client

    with Client(dask_cluster) as c:
        yield c


@pytest.fixture(scope="session")
def small_acquisition(tmp_path_factory):
    """A small simulated acquisition (relief scene: hard cast shadows) with truth.zarr
    on a 16 x 16 lattice; the path density gives K/M near the paper's 0.29."""
    from ltmstore.synthetic.simulate import simulate_acquisition

    out = tmp_path_factory.mktemp("sim") / "acquisition"
    simulate_acquisition(out, scene="relief", size=32, seed=1, lattice=(16, 16),
                         path_density=SMALL_PATH_DENSITY, progress=False)
    return out


SMALL_PATH_DENSITY = 14.0


@pytest.fixture(scope="session")
def small_store(small_acquisition, tmp_path_factory, dask_cluster):
    """``small_acquisition`` ingested and reconstructed on the session's LocalCluster."""
    from distributed import Client

    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct

    store = tmp_path_factory.mktemp("store") / "store.zarr"
    # its frames' chroma kept: colour fixtures force a colour LTM from it (the relief's colour is
    # illumination invariant, so ingest would otherwise remove it)
    ingest(small_acquisition, store, progress=False, keep_chroma=True)
    with Client(dask_cluster) as client:
        reconstruct(store, client=client, lattice=(16, 16), progress=False)
    return store


@pytest.fixture(scope="session")
def far_store(tmp_path_factory):
    """A dome capture of a flickering flash: its surface model and exposures are fitted."""
    import json

    from dome_helpers import RINGS, flash, write_capture

    from ltmstore.stages.ingest_rti import ingest_rti
    from ltmstore.stages.reconstruct import reconstruct

    root = tmp_path_factory.mktemp("far")
    lp = write_capture(root / "capture", flash(sum(RINGS.values())))
    ingest_rti(lp, root / "s.zarr", progress=False)
    reconstruct(root / "s.zarr", progress=False)
    record = json.loads((root / "s.zarr" / "zarr.json").read_text())["attributes"]
    assert record["stages"]["reconstruct"]["exposure_fitted"]
    return root / "s.zarr"
