"""Reading and validating acquisition folders and pose files."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from ingest_helpers import PLANE, make_acquisition, pose_times, r_of

from ltmstore.capture.acquisition import load_acquisition, load_poses
from ltmstore.core.errors import LtmError


@pytest.fixture(scope="module")
def acq_dir(tmp_path_factory):
    return make_acquisition(tmp_path_factory.mktemp("acq") / "acq", n=12)


@pytest.fixture
def edit_json(tmp_path):
    """A fresh small acquisition folder and a function that rewrites its acquisition.json."""
    folder = make_acquisition(tmp_path / "acq", n=3)

    def edit(**changes):
        meta = json.loads((folder / "acquisition.json").read_text())
        meta.update(changes)
        meta = {k: v for k, v in meta.items() if v is not None}
        (folder / "acquisition.json").write_text(json.dumps(meta))
        return folder

    return edit


def test_load_acquisition(acq_dir):
    acq = load_acquisition(acq_dir)
    assert acq.video == (acq_dir / "video.mkv").resolve()
    assert acq.poses == (acq_dir / "poses.csv").resolve()
    assert acq.plane == PLANE
    assert acq.transfer == "srgb"
    assert acq.time_offset == 0.0
    assert acq.view_plane is None
    assert acq.raw["format"] == "ltm-acquisition/1"


def test_optional_keys(edit_json):
    acq = load_acquisition(edit_json(time_offset=0.25, view_plane={"p": [-1, 1], "q": [0, 2]}))
    assert acq.time_offset == 0.25
    assert acq.view_plane == {"p": [-1.0, 1.0], "q": [0.0, 2.0]}
    acq = load_acquisition(edit_json(object={"x": [-0.5, 0.5], "y": [-0.25, 0.25]}))
    assert acq.object_extent == {"x": [-0.5, 0.5], "y": [-0.25, 0.25]}


def test_missing_folder(tmp_path):
    with pytest.raises(LtmError, match="acquisition folder '.*nowhere' does not exist"):
        load_acquisition(tmp_path / "nowhere")


def test_missing_json(tmp_path):
    with pytest.raises(LtmError, match="has no acquisition.json"):
        load_acquisition(tmp_path)


def test_malformed_json(edit_json):
    folder = edit_json()
    (folder / "acquisition.json").write_text('{"format": "ltm-acquisition/1",\n "video" "x"}')
    with pytest.raises(LtmError, match="not valid JSON: Expecting ':' delimiter at line 2, column"):
        load_acquisition(folder)


def test_json_not_an_object(edit_json):
    folder = edit_json()
    (folder / "acquisition.json").write_text("[1, 2]")
    with pytest.raises(LtmError, match="holds a list; expected a JSON object"):
        load_acquisition(folder)


@pytest.mark.parametrize("fmt", ["ltm-acquisition/2", 1])
def test_wrong_format(edit_json, fmt):
    with pytest.raises(LtmError, match=f"format {fmt!r} is not supported; expected "
                                       "'ltm-acquisition/1'"):
        load_acquisition(edit_json(format=fmt))


@pytest.mark.parametrize("key", ["format", "plane", "transfer"])
def test_missing_key(edit_json, key):
    with pytest.raises(LtmError, match=rf"missing key\(s\) \['{key}'\]"):
        load_acquisition(edit_json(**{key: None}))


@pytest.mark.parametrize("name", ["../video.mkv", "sub/../../video.mkv"])
def test_path_leaving_folder(edit_json, name):
    with pytest.raises(LtmError, match=f"video '{name}' leaves the folder"):
        load_acquisition(edit_json(video=name))


def test_absolute_path(edit_json):
    folder = edit_json()
    name = str(folder / "video.mkv")
    with pytest.raises(LtmError, match="is an absolute path; expected a path relative"):
        load_acquisition(edit_json(video=name))


def test_symlink_outside(edit_json, tmp_path):
    outside = tmp_path / "elsewhere.csv"
    outside.write_text("t,r,s,z\n0,0,0,1\n1,0,0,1\n")
    folder = edit_json(poses="link.csv")
    os.symlink(outside, folder / "link.csv")
    with pytest.raises(LtmError, match="poses 'link.csv' leaves the folder"):
        load_acquisition(folder)


def test_symlink_inside_is_fine(edit_json):
    folder = edit_json(video="link.mkv")
    os.symlink(folder / "video.mkv", folder / "link.mkv")
    assert load_acquisition(folder).video == (folder / "video.mkv").resolve()


@pytest.mark.parametrize("name", [3, "", None])
def test_path_not_a_name(edit_json, name):
    folder = edit_json()
    meta = json.loads((folder / "acquisition.json").read_text())
    meta["video"] = name
    (folder / "acquisition.json").write_text(json.dumps(meta))
    with pytest.raises(LtmError, match=f"video {name!r} must be a file name relative to"):
        load_acquisition(folder)


def test_missing_video(edit_json):
    with pytest.raises(LtmError, match="video file 'other.mkv' does not exist"):
        load_acquisition(edit_json(video="other.mkv"))


@pytest.mark.parametrize("plane", [{"r": [1, 0], "s": [0, 1], "height": 1},
                                   {"r": [0, 1], "s": [0, 1], "height": -2},
                                   {"r": [0, 1], "height": 1}, [0, 1]])
def test_bad_plane(edit_json, plane):
    with pytest.raises(LtmError, match=r"acquisition.json: plane .*(must|min < max)"):
        load_acquisition(edit_json(plane=plane))


def test_unknown_transfer(edit_json):
    with pytest.raises(LtmError, match="transfer 'gamma22' is unknown; expected one of"):
        load_acquisition(edit_json(transfer="gamma22"))


@pytest.mark.parametrize("offset", ["1s", True, [0]])
def test_bad_time_offset(edit_json, offset):
    with pytest.raises(LtmError, match="time_offset .* must be a finite number of seconds"):
        load_acquisition(edit_json(time_offset=offset))


@pytest.mark.parametrize("view", [{"p": [0, 1]}, {"p": [1, 0], "q": [0, 1]}, "x",
                                  {"p": [0, 10**400], "q": [0, 1]}])
def test_bad_view_plane(edit_json, view):
    with pytest.raises(LtmError, match="view_plane .* must look like"):
        load_acquisition(edit_json(view_plane=view))


@pytest.mark.parametrize("extent", [{"x": [0, 1]}, {"x": [1, 0], "y": [0, 1]},
                                    {"x": [0, 1], "y": [0, float("inf")]},
                                    {"x": [0, "1"], "y": [0, 1]}, {"x": [0, 10**400], "y": [0, 1]},
                                    {"x": [-1e308, 1e308], "y": [0, 1]}, [0, 1]])
def test_bad_object_extent(edit_json, extent):
    with pytest.raises(LtmError, match="object .* must look like"):
        load_acquisition(edit_json(object=extent))


# --- poses -----------------------------------------------------------------------------------


def test_load_poses(acq_dir):
    poses = load_poses(acq_dir / "poses.csv")
    np.testing.assert_allclose(poses.t, pose_times(), rtol=1e-8)
    np.testing.assert_allclose(poses.r, r_of(poses.t), atol=1e-8)
    assert poses.p is None and poses.q is None
    assert len(poses) == len(pose_times())


def test_load_poses_6d(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_text("t, r, s, z, p, q\n0,0,0,1,0.5,0.6\n1,0,0,1,0.7,0.8\n\n")
    poses = load_poses(path)
    np.testing.assert_array_equal(poses.q, [0.6, 0.8])


def write(tmp_path, text):
    path = tmp_path / "poses.csv"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, match", [
    ("t,r,s\n0,0,0\n", "header 't,r,s' must be 't,r,s,z' or 't,r,s,z,p,q'"),
    ("", "header '' must be"),
    ("t,r,s,z\n0,0,0,1\n1,nan,0,1\n", "line 3: r = 'nan' is not a finite number"),
    ("t,r,s,z\n0,0,0,1\n1,0,inf,1\n", "line 3: s = 'inf' is not a finite number"),
    ("t,r,s,z\n0,0,0,1\n1,0,0,abc\n", "line 3: z = 'abc' is not a finite number"),
    ("t,r,s,z\n0,0,0,1\n1,0,0\n", r"line 3: 3 value\(s\); expected 4"),
    ("t,r,s,z\n0,0,0,1\n1,0,0,1\n1,0,0,1\n", "line 4: time 1.0 does not come after 1.0"),
    ("t,r,s,z\n0,0,0,1\n2,0,0,1\n\n1,0,0,1\n", "line 5: time 1.0 does not come after 2.0"),
    ("t,r,s,z\n0,0,0,1\n", r"1 pose sample\(s\); expected at least 2"),
])
def test_bad_poses(tmp_path, text, match):
    with pytest.raises(LtmError, match=match):
        load_poses(write(tmp_path, text))


def test_poses_not_text(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_bytes(b"t,r,s,z\n\xff\xfe\x00")
    with pytest.raises(LtmError, match="is not UTF-8 text"):
        load_poses(path)


def test_poses_min_samples(tmp_path):
    with pytest.raises(LtmError, match=r"2 pose sample\(s\); expected at least 3"):
        load_poses(write(tmp_path, "t,r,s,z\n0,0,0,1\n1,0,0,1\n"), min_samples=3)


# --- strict inputs (issue 14) ----------------------------------------------------------------


@pytest.mark.parametrize("value", ["1_0", "\u0661", "\u0661.\u0665", "1e_5", "0x10", "\u00bd"])
def test_pose_values_are_ascii_decimals(tmp_path, value):
    """``float()`` takes underscores and other scripts' digits (here Arabic-Indic); no
    tracker writes them, so they are refused with the file, line and value."""
    path = write(tmp_path, f"t,r,s,z\n0,0,0,1\n1,{value},0,1\n")
    with pytest.raises(LtmError, match=f"{path} line 3: r = '{value}' is not a finite number"):
        load_poses(path)


def test_ordinary_decimals_are_read(tmp_path):
    poses = load_poses(write(tmp_path, "t,r,s,z\n0,-.5,+1.,1E-3\n 2 ,0.25,3e+0,1\n"))
    np.testing.assert_array_equal(poses.r, [-0.5, 0.25])
    np.testing.assert_array_equal(poses.z, [1e-3, 1])


def test_a_bom_in_poses_is_dropped(tmp_path):
    path = tmp_path / "poses.csv"
    path.write_bytes(b"\xef\xbb\xbft,r,s,z\r\n0,0.1,0,1\r\n1,0.2,0,1\r\n")
    np.testing.assert_array_equal(load_poses(path).r, [0.1, 0.2])


@pytest.mark.parametrize("plane", [
    {"r": [-0.5, 0.5], "s": [-0.5, 0.5], "height": 0.5, "tilt": 3},
    {"r": ["-0.5", 0.5], "s": [-0.5, 0.5], "height": 0.5},
    {"r": [-0.5, 0.5], "s": [-0.5, 0.5], "height": "0.5"},
    {"r": [-0.5, 0.5, 0.7], "s": [-0.5, 0.5], "height": 0.5},
    {"r": [-0.5, 0.5], "s": [-0.5, 0.5], "height": True},
    {"r": [-0.5, 0.5], "s": [-0.5, 0.5], "height": 0.5, "unit": 1},
])
def test_plane_fields_are_numbers_and_nothing_else(edit_json, plane):
    with pytest.raises(LtmError, match="plane .* must look like .* no other key"):
        load_acquisition(edit_json(plane=plane))


def test_view_plane_values_are_numbers(edit_json):
    with pytest.raises(LtmError, match="view_plane .* must look like"):
        load_acquisition(edit_json(view_plane={"p": ["0", 1], "q": [0, 1]}))


def test_acquisition_json_may_not_link_out_of_the_folder(edit_json, tmp_path):
    folder = edit_json()
    outside = tmp_path / "elsewhere.json"
    (folder / "acquisition.json").rename(outside)
    os.symlink(outside, folder / "acquisition.json")
    with pytest.raises(LtmError, match="'acquisition.json' leaves the folder"):
        load_acquisition(folder)


def test_sha256_reads_the_whole_file(tmp_path):
    """Inputs larger than the read block (1 MiB): a change after the first block changes the
    hash (every test input used to be smaller, so hashing only the first block went unseen)."""
    import hashlib

    from ltmstore.capture.acquisition import sha256_file

    path = tmp_path / "video.bin"
    data = bytearray(np.random.default_rng(0).bytes(3 * 2**20 // 2))
    path.write_bytes(data)
    assert sha256_file(path) == hashlib.sha256(data).hexdigest()
    before = sha256_file(path)
    data[-1] ^= 1
    path.write_bytes(data)
    assert sha256_file(path) != before
