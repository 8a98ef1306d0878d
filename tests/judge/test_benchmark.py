"""The bench machinery on a tiny sweep: records, Pareto front, charts."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from locations import ROOT

from ltmstore.judge import benchmark


def test_pareto_front_keeps_only_unbeaten_points():
    points = [(1.0, 10.0), (2.0, 9.0), (3.0, 12.0), (0.5, 5.0), (4.0, 12.0)]
    assert benchmark.pareto_front(points) == [3, 0, 2]


def test_a_tiny_sweep_writes_json_and_charts(tmp_path):
    records = benchmark.run(scenes=("canvas",), densities=(27.0,), lattices=(8, 32), size=8,
                            pixels=16, slow_pixels=4, repeats=1, progress=lambda line: None)
    methods = {r["method"] for r in records if r["lattice"] == 32}
    assert methods == set(benchmark.METHODS)
    assert {r["method"] for r in records if r["lattice"] == 8} == {"cs"}
    assert all(np.isfinite(r["snr_db"]) and r["ms_per_pixel"] > 0 for r in records)
    default = {r["lattice"]: r for r in records if r["method"] == "cs" and not r["params"]}
    assert default[32]["sampling_ratio"] == pytest.approx(0.296, rel=0.05)  # measured 0.296
    assert default[32]["snr_db"] > 25.2  # measured 26.21 dB (the sweep is seeded)
    assert default[8]["snr_db"] > 22.0  # measured 23.06 dB
    assert {r["pixels"] for r in records} == {16, 4}  # lars and svt on slow_pixels only
    result = benchmark.write(records, tmp_path, command="test")
    assert json.loads((tmp_path / "bench.json").read_text())["summary"]
    for path in result["charts"].values():
        assert (tmp_path / path.split("/")[-1]).stat().st_size > 10_000


def test_ltm_bench_writes_outside_the_published_results_by_default():
    """``ltm bench`` without ``--out`` writes to a folder git ignores, never to bench/results
    (the tracked results that ``python -m bench run bench`` publishes)."""
    from ltmstore.cli import build_parser

    out = build_parser().parse_args(["bench"]).out
    assert Path(out) == Path("bench-out")
    ignored = subprocess.run(["git", "check-ignore", "--no-index", f"{out}/"], cwd=ROOT,
                             capture_output=True, text=True)
    assert ignored.stdout.strip() == f"{out}/", "the default --out is not ignored by git"
