"""Occluded frames are found at ingest, rejected and counted (issue 13, item 4): the phone passes
between camera B and the painting for a run of frames, which go dark."""

from __future__ import annotations

import json
import shutil

import numpy as np
from ingest_helpers import make_acquisition
from pipeline_helpers import run_ltm

from ltmstore.capture.video import VideoReader
from ltmstore.core.store import open_store
from ltmstore.stages.ingest import ingest
from ltmstore.stages.occlusion import occluded_frames
from ltmstore.synthetic.writer import write_video

DARK_CODE = 6  # sRGB code of about 0.2 % linear light: what is left behind the phone


def occlude(acq, start: int, stop: int) -> None:
    """Rewrite the acquisition's video with frames ``start:stop`` dark."""
    video = acq / "video.mkv"
    with VideoReader(video) as reader:
        frames = list(reader)
    for i in range(start, stop):
        frames[i] = np.full_like(frames[i], DARK_CODE)
    video.unlink()
    write_video(video, frames)


def test_occluded_frames_are_rejected_and_shown(small_acquisition, small_store, tmp_path):
    acq = tmp_path / "acq"
    shutil.copytree(small_acquisition, acq)
    clean = open_store(small_store)
    n = clean.sizes["t"]
    start, stop = n // 3, n // 3 + n // 5  # 20 % of the frames in a row
    occlude(acq, start, stop)
    store = tmp_path / "store.zarr"
    record = ingest(acq, store, progress=False)
    valid_before = clean["pose_valid"].values
    expected = int(valid_before[start:stop].sum())
    assert expected > 50 and record["rejected"]["occluded"] == expected
    valid = open_store(store)["pose_valid"].values
    assert not valid[start:stop].any()
    np.testing.assert_array_equal(valid[:start], valid_before[:start])
    np.testing.assert_array_equal(valid[stop:], valid_before[stop:])
    info = run_ltm("info", store)
    assert json.loads(info.stdout)["frames"]["rejected"]["occluded"] == expected


def test_no_frame_of_a_clean_capture_is_occluded(small_store):
    assert open_store(small_store).attrs["stages"]["ingest"]["rejected"]["occluded"] == 0


def test_too_few_frames_are_not_judged(tmp_path):
    record = ingest(make_acquisition(tmp_path / "acq"), tmp_path / "s.zarr", progress=False)
    assert record["rejected"]["occluded"] == 0


def test_bright_highlights_are_not_occlusion():
    rng = np.random.default_rng(0)
    r, s = rng.uniform(-1, 1, (2, 400))
    brightness = 1 / (1 + r**2 + s**2)
    brightness[::37] *= 3  # glints
    brightness[100:140] = 0.01  # the phone
    flagged = occluded_frames(brightness, r, s, np.ones(400), np.ones(400, bool))
    assert np.flatnonzero(flagged).tolist() == list(range(100, 140))
