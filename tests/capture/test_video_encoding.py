"""Camera B's codec and bitrate, as `ltm ingest` reads them from the file and records them, and
its warning where a lossy video's bitrate costs the LTM (real FFV1 and libx264 files)."""

from __future__ import annotations

import json
import os
import shutil

import av
import numpy as np
import pytest
from pipeline_helpers import run_ltm

from ltmstore.capture.video import FAIR_BITS_PER_PIXEL, VideoReader, codec_warning
from ltmstore.synthetic.writer import FPS, write_h264, write_video


def frames(n: int = 60, size: int = 64):
    """``n`` frames of a textured gradient that brightens: a codec must spend bits on them."""
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 60, (size, size, 3))
    ramp = np.linspace(60, 160, size)[None, :, None]
    for k in range(n):
        yield np.clip(texture + ramp + k, 0, 255).astype(np.uint8)


def test_an_h264_videos_bits_per_pixel_are_read_from_the_file(tmp_path):
    """What the file holds (its stream's bytes over its pixels), whatever x264's rate control
    made of the request (these easy frames take less than asked)."""
    found = {}
    for asked in (0.3, 4.0):
        path = tmp_path / f"b{asked}.mp4"
        write_h264(path, frames(), bitrate=int(asked * 64 * 64 * FPS))
        with VideoReader(path) as video:
            found[asked] = video.encoding()
        assert found[asked]["codec"] == "h264"
        with av.open(str(path)) as container:  # the stream's own bytes, not the container's
            held = 8 * sum(p.size for p in container.demux(video=0)) / (64 * 64 * 60)
        assert found[asked]["bits_per_pixel"] == pytest.approx(held, rel=0.05)
        warning = codec_warning(found[asked])
        assert (warning is not None) == (found[asked]["bits_per_pixel"] < FAIR_BITS_PER_PIXEL)
    assert found[0.3]["bits_per_pixel"] < found[4.0]["bits_per_pixel"] / 3  # 0.17 and 1.31


def test_a_lossless_video_is_never_warned_about(tmp_path):
    path = tmp_path / "b.mkv"
    write_video(path, frames(10))
    with VideoReader(path) as video:
        found = video.encoding()
    assert found["codec"] == "ffv1" and codec_warning(found) is None
    assert codec_warning({"codec": "h264", "bits_per_pixel": None}) is None  # unknown: silent


def test_ingest_records_the_codec_and_warns_below_a_fair_bitrate(small_acquisition, tmp_path):
    """The session's acquisition with its video re-encoded as H.264 at 0.3 bits per pixel:
    ingested (exit 0), the codec recorded, one warning line naming the bitrate."""
    folder = tmp_path / "acquisition"
    meta = json.loads((small_acquisition / "acquisition.json").read_text())
    folder.mkdir()
    os.link(small_acquisition / meta["poses"], folder / meta["poses"])
    with VideoReader(small_acquisition / meta["video"]) as video:
        source, fps = video.encoding(), video.fps
        write_h264(folder / "video.mp4", iter(video), fps=fps,
                   bitrate=int(0.3 * 32 * 32 * fps))
    assert source["codec"] == "ffv1"
    (folder / "acquisition.json").write_text(json.dumps({**meta, "video": "video.mp4"}))
    done = run_ltm("ingest", folder, tmp_path / "s.zarr")
    assert done.returncode == 0, done.stderr
    record = json.loads(done.stdout)
    assert record["video"]["codec"] == "h264" and record["video"]["bits_per_pixel"] < 1.0
    lines = [line for line in done.stderr.splitlines() if line.startswith("ltm: warning:")]
    assert len(lines) == 1 and "h264 at" in lines[0] and "bits per pixel" in lines[0]
    shutil.rmtree(tmp_path / "s.zarr")
