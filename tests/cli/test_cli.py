"""The `ltm` command as a user meets it: help, one-line errors, exit codes, nothing overwritten."""

from __future__ import annotations

import hashlib
import json

import pytest
from pipeline_helpers import one_line_error, run_ltm


@pytest.mark.parametrize("command", ["demo", "simulate", "ingest", "ingest-rti", "reconstruct",
                                     "relight", "compact", "evaluate", "info", "bench"])
def test_every_command_has_help(command):
    proc = run_ltm(command, "--help")
    assert proc.returncode == 0 and "usage: ltm" in proc.stdout


@pytest.mark.parametrize(("args", "pattern"), [
    (["simulate", "{tmp}/a", "--scene", "mona-lisa"], "unknown scene 'mona-lisa'"),
    (["simulate", "{tmp}/a", "--scene", "canvas", "--path-density", "-1"], "-1"),
    (["simulate", "/proc/nope/a", "--scene", "canvas"], "/proc/nope"),
    (["reconstruct", "{tmp}/missing.zarr"], "does not exist"),
    (["reconstruct", "{tmp}/missing.zarr", "--lattice", "12"], "--lattice '12'"),
    (["reconstruct", "{tmp}/missing.zarr", "--method", "magic"], "invalid choice: 'magic'"),
    (["relight", "{tmp}/missing.zarr", "--light", "1;2"], "'1;2' must look like R,S"),
    (["relight", "{tmp}/missing.zarr", "--light", "-0.1"], "'-0.1' must look like R,S"),
    (["compact", "{tmp}/missing.zarr"], "does not exist"),
    (["ingest", "{tmp}/nowhere", "{tmp}/s.zarr"], "nowhere"),
])
def test_bad_arguments_give_one_line_errors(args, pattern, tmp_path):
    one_line_error(run_ltm(*[a.format(tmp=tmp_path) for a in args]), pattern)


def test_simulate_refuses_existing_output_without_overwrite(small_acquisition):
    digest = hashlib.sha256((small_acquisition / "poses.csv").read_bytes()).hexdigest()
    one_line_error(run_ltm("simulate", small_acquisition, "--scene", "canvas"), "--overwrite")
    assert hashlib.sha256((small_acquisition / "poses.csv").read_bytes()).hexdigest() == digest


def _edit_json(acq, **changes):
    meta = json.loads((acq / "acquisition.json").read_text())
    meta.update(changes)
    (acq / "acquisition.json").write_text(json.dumps(meta))


def _truncate_video(acq):
    data = (acq / "video.mkv").read_bytes()
    (acq / "video.mkv").write_bytes(data[: len(data) // 2])


# Every bad input of the ingest contract (issue: missing or malformed acquisition.json, a path
# that leaves the folder, poses with NaN, times not increasing, too few samples, a video that
# cannot be opened or decoded), through the installed command.
INGEST_DAMAGE = {
    "missing json": (lambda acq: (acq / "acquisition.json").unlink(), "acquisition.json"),
    "malformed json": (lambda acq: (acq / "acquisition.json").write_text("{not json"),
                       "acquisition.json"),
    "path leaves folder": (lambda acq: _edit_json(acq, poses="../poses.csv"), "leaves"),
    "absolute path": (lambda acq: _edit_json(acq, video="/etc/passwd"), "/etc/passwd"),
    "NaN pose": (lambda acq: (acq / "poses.csv").write_text("t,r,s,z\n0,nan,0,0.3\n1,0,0,0.3\n"),
                 "r = 'nan' is not a finite"),
    "times not increasing": (
        lambda acq: (acq / "poses.csv").write_text("t,r,s,z\n0,0,0,0.3\n1,0,0,0.3\n1,0,0,0.3\n"),
        "increasing"),
    "too few samples": (lambda acq: (acq / "poses.csv").write_text("t,r,s,z\n0,0,0,0.3\n"),
                        "expected at least 2"),
    "not a video": (lambda acq: (acq / "video.mkv").write_bytes(b"not a video at all"),
                    "cannot be decoded"),
    "truncated video": (_truncate_video, "cannot be decoded"),
}


@pytest.mark.parametrize("case", sorted(INGEST_DAMAGE))
def test_ingest_errors_reach_the_user_as_one_line(case, tmp_path):
    from ingest_helpers import make_acquisition, tree_hashes

    damage, pattern = INGEST_DAMAGE[case]
    acq = make_acquisition(tmp_path / "acq")
    damage(acq)
    before = tree_hashes(acq)
    one_line_error(run_ltm("ingest", acq, tmp_path / "store.zarr"), pattern)
    assert tree_hashes(acq) == before
    assert not (tmp_path / "store.zarr").exists()


def test_relight_takes_negative_values_and_writes_one_image_per_light(small_store, tmp_path):
    """``--light -0.1,0`` and ``--light=-0.1,0`` (argparse alone reads the first as an option);
    several lights: one image each, named by the ``{i}`` pattern."""
    import imageio.v3 as iio

    proc = run_ltm("relight", small_store, "--light", "-0.1,0", "--light=-0.1,0", "--light",
                   "0.05,-0.02", "-o", tmp_path / "relit-{i}.png")
    assert proc.returncode == 0, proc.stderr
    images = [iio.imread(tmp_path / f"relit-{i}.png") for i in range(3)]
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"relit-{i}.png" for i in range(3)]
    assert (images[0] == images[1]).all() and not (images[0] == images[2]).all()


def test_relight_sum_and_negative_directions(small_store, tmp_path):
    proc = run_ltm("relight", small_store, "--direction", "-0.3,0.2,1", "--direction=0.2,-0.1,1",
                   "--sum", "-o", tmp_path / "both.png")
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["both.png"]


def test_physical_needs_a_placeable_object(small_store, tmp_path):
    """A near-light store that declares no object extent and whose lights stay on one side of
    the object (a tenth of it under the path): the capture cannot place it, --method physical
    is refused in one line and the previous ltm stays (auto falls back to the classic methods,
    tests/solve/test_placement.py)."""
    import shutil

    import zarr

    store = tmp_path / "no-object.zarr"
    shutil.copytree(small_store, store)
    group = zarr.open_group(store, mode="r+")
    acquisition = dict(group.attrs["acquisition"])
    del acquisition["object"]
    group.attrs["acquisition"] = acquisition
    group["pose_valid"][:] = group["pose_valid"][:] & (group["pose_r"][:] < -0.06)
    before = hashlib.sha256((store / "ltm" / "zarr.json").read_bytes()).hexdigest()
    proc = run_ltm("reconstruct", store, "--method", "physical", "--overwrite")
    one_line_error(proc, "the object's place on the light plane cannot be estimated from this "
                         "capture: the lights")
    assert hashlib.sha256((store / "ltm" / "zarr.json").read_bytes()).hexdigest() == before
