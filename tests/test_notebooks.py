"""Notebooks are narratives that must run: execute each on the small session store."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from ltmstore.core.store import open_store

NOTEBOOKS = sorted((Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, small_store, monkeypatch):
    monkeypatch.setenv("LTM_STORE", str(small_store))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert all(c.execution_count for c in nb.cells if c.cell_type == "code")
    # the notebook read the store it was given: it prints that store's lattice and K/M
    resample = open_store(small_store).attrs["stages"]["resample"]
    printed = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    assert (f"lattice {resample['lattice']['shape']} K/M "
            f"{round(resample['sampling_ratio'], 3)}") in printed, printed
