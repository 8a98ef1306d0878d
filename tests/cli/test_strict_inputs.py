"""Strict inputs and one-line errors (issue 14): what a user or another program can hand to ``ltm``
is refused with exactly one ``ltm: error:`` line and exit status 2, never a traceback."""

from __future__ import annotations

import re
import shutil
import signal
import subprocess

import numpy as np
import pytest
import zarr
from ingest_helpers import PLANE, H, W, make_acquisition, write_pose_file
from pipeline_helpers import (
    BIN,
    beyond_loopback,
    dask_processes,
    free_port,
    only_error_line,
    run_ltm,
    tcp_listeners,
)

from ltmstore.core.cluster import dask_client
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_store
from ltmstore.synthetic.writer import write_acquisition_json, write_video


@pytest.fixture
def foreign_store(tmp_path):
    """A Zarr v3 store written by another program: no ltmstore attributes, no dimension names."""
    group = zarr.open_group(str(tmp_path / "foreign.zarr"), mode="w", zarr_format=3)
    group.create_array("ltm", shape=(4, 4, 2, 2), dtype="f4")[...] = 1
    return tmp_path / "foreign.zarr"


@pytest.mark.parametrize("command", [["info"], ["reconstruct"], ["relight", "--light", "0,0"],
                                     ["evaluate"]])
def test_a_store_of_another_program_is_refused(foreign_store, command):
    proc = run_ltm(command[0], foreign_store, *command[1:])
    only_error_line(proc, str(foreign_store), "not an ltmstore store")


def test_evaluate_refuses_a_foreign_truth(small_store, foreign_store):
    proc = run_ltm("evaluate", small_store, "--truth", foreign_store, "--pixels", "16")
    only_error_line(proc, str(foreign_store), "not an ltmstore store")


def test_a_scheduler_that_is_no_address_is_refused(small_store, tmp_path):
    store = shutil.copytree(small_store, tmp_path / "store.zarr")
    proc = run_ltm("reconstruct", store, "--overwrite", "--scheduler", "nonsense")
    only_error_line(proc, "'nonsense'", "tcp://HOST:PORT")


def test_an_unreachable_scheduler_fails_fast_naming_it():
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    with pytest.raises(LtmError, match=f"cannot reach Dask scheduler '{address}' within 1 s"):
        with dask_client(address, timeout=1):
            pass


def test_a_black_video_is_refused_before_any_solver(tmp_path):
    """An all-black video made ``--method svt`` raise in ARPACK ("starting vector is zero"):
    ingest now refuses it in one line, so no solver meets it."""
    folder = tmp_path / "black"
    folder.mkdir()
    write_video(folder / "video.mkv", [np.zeros((H, W, 3), np.uint8)] * 60)
    write_pose_file(folder / "poses.csv")
    write_acquisition_json(folder, video="video.mkv", plane=PLANE)
    proc = run_ltm("ingest", folder, tmp_path / "black.zarr")
    last = proc.stderr.strip().splitlines()[-1]  # after the progress bar
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert last.startswith("ltm: error: ") and "black" in last, proc.stderr


def test_svt_on_an_all_zero_tile_gives_zeros():
    """A black tile inside a lit capture reaches svt as an all-zero matrix: zeros, no raise."""
    from ltmstore.solve import Geometry, get_method

    samples = np.zeros((16, 8, 8))
    samples[:, ::3, ::2] = np.nan
    out = get_method("svt")(samples, Geometry.from_shape((8, 8)))
    assert out.shape == samples.shape and not out.any()


def test_a_closed_pipe_is_no_traceback(small_store):
    """``ltm info STORE | head -1``: the reader leaves before ``ltm`` writes."""
    proc = subprocess.Popen([BIN / "ltm", "info", str(small_store)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.stdout.close()
    stderr = proc.stderr.read()
    assert proc.wait(timeout=60) in (0, 128 + signal.SIGPIPE), stderr
    assert stderr == "", stderr


def test_ingest_names_a_pose_value_float_would_take(tmp_path):
    """``float("1_0") == 10.0``; tests/capture/test_acquisition.py covers the other spellings."""
    value = "1_0"
    folder = make_acquisition(tmp_path / "acq", n=3)
    text = (folder / "poses.csv").read_text().splitlines()
    text[2] = f"{text[2].split(',')[0]},{value},0,0.5"
    (folder / "poses.csv").write_text("\n".join(text) + "\n")
    proc = run_ltm("ingest", folder, tmp_path / "s.zarr")
    only_error_line(proc, "poses.csv line 3", f"r = '{value}'")
    assert not (tmp_path / "s.zarr").exists()


def test_an_absurd_lattice_is_refused_naming_one_that_works(small_store, tmp_path,
                                                            dask_cluster):
    """1000 x 1000 cells for a 32 x 32 px capture of 262 observed cells: K/M 0.0003."""
    store = shutil.copytree(small_store, tmp_path / "store.zarr")
    before = open_store(store)["ltm"].values
    proc = run_ltm("reconstruct", store, "--overwrite", "--lattice", "1000x1000", "--scheduler",
                   dask_cluster.scheduler_address, timeout=120)
    only_error_line(proc, "lattice 1000x1000 gives K/M 0.0003", "below 0.02", "--force")
    suggested = re.search(r"--lattice (\d+)x(\d+) gives K/M (\S+) ", proc.stderr)
    assert suggested and float(suggested[3]) >= 0.29, proc.stderr
    np.testing.assert_array_equal(open_store(store)["ltm"].values, before)


def test_nothing_started_listens_beyond_loopback(dask_cluster, prefect_harness):
    """The session's LocalCluster and Prefect server, the library's own LocalCluster and the
    suite's `dask scheduler` / `dask worker` processes (HTTP servers included)."""
    with dask_client(n_workers=1), dask_processes(1):
        found = tcp_listeners()
    assert len({name for name in found.values() if "dask" in name}) >= 2, found
    assert not beyond_loopback(found), found
