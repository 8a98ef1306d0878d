"""No impossible values (issue 13, item 5): light transport is never negative in the store, a black
video is an error, the JSON the command prints is strict."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ingest_helpers import PLANE, H, N, make_acquisition, write_pose_file
from pipeline_helpers import run_ltm

from ltmstore.cli.args import print_json
from ltmstore.core.store import open_store
from ltmstore.stages.ingest import ingest
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.synthetic.writer import write_acquisition_json, write_video


def flat_acquisition(folder, value: int):
    """The helpers' line path (2 % of a 16 x 16 lattice) over a video of one code value."""
    folder.mkdir()
    write_video(folder / "video.mkv", [np.full((H, 20, 3), value, np.uint8)] * N)
    write_pose_file(folder / "poses.csv")
    write_acquisition_json(folder, video="video.mkv", plane=PLANE)
    return folder


@pytest.fixture(scope="module")
def line_store(tmp_path_factory):
    out = tmp_path_factory.mktemp("line")
    ingest(make_acquisition(out / "acq"), out / "store.zarr", progress=False)
    return out / "store.zarr"


def test_hsh_on_a_sparse_path_is_never_negative(line_store, client):
    info = reconstruct(line_store, client=client, lattice=(16, 16), method="hsh",
                       overwrite=True, progress=False)
    assert info["sampling_ratio"] < 0.05
    ltm = open_store(line_store)["ltm"].values
    assert np.isfinite(ltm).all() and ltm.min() >= 0 and ltm.max() > 0


def test_a_black_video_is_an_error(tmp_path):
    proc = run_ltm("ingest", flat_acquisition(tmp_path / "acq", 0), tmp_path / "s.zarr")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == (
        "ltm: error: all 19 valid frames are black (no light reached the camera); expected a "
        "capture lit by the moving light")
    assert not (tmp_path / "s.zarr").exists()


def test_evaluate_prints_strict_json_on_a_saturated_video(tmp_path, client):
    store = tmp_path / "s.zarr"
    ingest(flat_acquisition(tmp_path / "acq", 255), store, progress=False)
    reconstruct(store, client=client, lattice=(16, 16), progress=False)
    assert not np.isnan(open_store(store)["expected_error"].values).all()
    proc = run_ltm("evaluate", store, "--folds", "2", "--method", "hsh")
    assert proc.returncode == 0, proc.stderr

    def no_constants(name):
        raise AssertionError(f"{name} in the JSON")
    assert json.loads(proc.stdout, parse_constant=no_constants)["heldout"]


def test_json_output_has_no_nan(capsys):
    print_json({"relative_error": float("nan"), "snr": [np.float32("inf"), 1.5]})
    assert json.loads(capsys.readouterr().out) == {"relative_error": None, "snr": [None, 1.5]}
