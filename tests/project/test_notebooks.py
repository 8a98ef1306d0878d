"""Notebooks are narratives that must run: execute each on the small session store."""

from __future__ import annotations

from pathlib import Path

import nbformat
import numpy as np
import pytest
from locations import ROOT
from nbclient import NotebookClient

from ltmstore.core.store import open_store

NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def run_notebook(path: Path, store: Path, monkeypatch) -> str:
    """Execute the notebook at ``path`` on ``store``; what it printed. Fails on any error."""
    monkeypatch.setenv("LTM_STORE", str(store))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert all(c.execution_count for c in nb.cells if c.cell_type == "code")
    return "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, small_store, monkeypatch):
    printed = run_notebook(path, small_store, monkeypatch)
    # the notebook read the store it was given: it prints that store's lattice and K/M
    resample = open_store(small_store).attrs["stages"]["resample"]
    assert (f"lattice {resample['lattice']['shape']} K/M "
            f"{round(resample['sampling_ratio'], 3)}") in printed, printed
    assert f"path density {resample['path_density']:.1f}/m" in printed, printed


@pytest.fixture(scope="module")
def far_store(tmp_path_factory) -> Path:
    """A small classic RTI capture (18 lights on three rings), ingested and reconstructed."""
    from ingest_helpers import write_capture

    from ltmstore.core.lights import elevation_azimuth
    from ltmstore.stages.ingest_rti import ingest_rti
    from ltmstore.stages.reconstruct import reconstruct

    root = tmp_path_factory.mktemp("far")
    lights = elevation_azimuth(np.repeat([30, 50, 75], 6), np.tile(np.arange(0, 360, 60), 3))
    ingest_rti(write_capture(root / "cap", dirs=lights), root / "s.zarr", progress=False)
    reconstruct(root / "s.zarr", progress=False)
    return root / "s.zarr"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_on_a_far_light_store(path, far_store, monkeypatch):
    """A classic RTI capture's store: no binned samples, no path density (it stopped with
    KeyError 'sampling_ratio' before)."""
    printed = run_notebook(path, far_store, monkeypatch)
    stages = open_store(far_store).attrs["stages"]
    assert (f"lattice {stages['resample']['lattice']['shape']} K/M "
            f"{round(stages['reconstruct']['sampling_ratio'], 3)} far lights") in printed, printed
