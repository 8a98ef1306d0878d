"""A phone's 4:2:0 video decoded to RGB: the chroma interpolated, the frame's own matrix and range
(ltmstore.capture.yuv). Real H.264 files written here by libx264 and read by the product's
VideoReader."""

from __future__ import annotations

import av
import cv2
import numpy as np
import pytest

from ltmstore.capture.video import VideoReader
from ltmstore.capture.yuv import frame_to_rgb, half_rgb, ycbcr_matrix
from ltmstore.core.dims import LUMA
from ltmstore.core.transfer import encode, linearise, transfer_lut
from ltmstore.synthetic.render import iter_frames
from ltmstore.synthetic.scenes import make_scene
from ltmstore.synthetic.writer import write_h264

LUT = transfer_lut("srgb", bits=8)
PATCHES = np.array([[200, 60, 40], [40, 160, 220], [90, 200, 80], [128, 128, 128]], np.uint8)


def luminance(rgb8: np.ndarray) -> np.ndarray:
    return linearise(rgb8, LUT) @ LUMA.astype(np.float32)


def snr_db(truth: np.ndarray, estimate: np.ndarray) -> float:
    return float(10 * np.log10((truth**2).sum() / ((estimate - truth) ** 2).sum()))


@pytest.fixture(scope="module")
def painted(tmp_path_factory):
    """Eight frames of the simulator's colour canvas (96 x 96, lit from eight places) and the
    same frames as an H.264 file at a phone's rate for its size."""
    scene = make_scene("canvas", size=96, seed=0)
    lights = [(0.12 * np.cos(a), 0.12 * np.sin(a), 0.3) for a in np.linspace(0, 6, 8)]
    frames = [encode(f * 0.4, "srgb") for f in iter_frames(scene, lights)]
    path = tmp_path_factory.mktemp("yuv") / "painted.mp4"
    write_h264(path, iter(frames), bitrate=20_000_000)
    return np.stack(frames), path


def test_painted_colour_keeps_its_luminance_through_a_phones_4_2_0_video(painted):
    frames, path = painted
    with VideoReader(path) as reader:
        decoded = np.stack([rgb for _, rgb in reader.frames()])
    with av.open(str(path)) as container:  # FFmpeg's own conversion, for comparison
        blocky = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
    truth = luminance(frames)
    ours, ffmpegs = snr_db(truth, luminance(decoded)), snr_db(truth, luminance(blocky))
    # measured 2026-11-28: 38.27 dB here, 32.62 dB by FFmpeg's conversion
    assert ours > 37.8, ours
    assert ours > ffmpegs + 5.2, (ours, ffmpegs)


def _tagged_frame(kr: float, kb: float, colorspace: int, full: bool) -> av.VideoFrame:
    """Flat colour patches as a 4:2:0 frame, its Y'CbCr computed here by the standard's forward
    equations (Y' = Kr R + Kg G + Kb B, Cb = (B - Y') / 2 (1 - Kb), Cr = (R - Y') / 2 (1 - Kr);
    studio swing 16-235 and 16-240), and tagged with its matrix and range."""
    rgb = PATCHES.astype(float)
    luma = rgb @ [kr, 1 - kr - kb, kb]
    cb, cr = (rgb[:, 2] - luma) / (2 * (1 - kb)), (rgb[:, 0] - luma) / (2 * (1 - kr))
    if not full:
        luma, cb, cr = 16 + luma * 219 / 255, cb * 224 / 255, cr * 224 / 255
    codes = [np.rint(v).astype(np.uint8) for v in (luma, cb + 128, cr + 128)]
    frame = av.VideoFrame(32 * len(PATCHES), 32, "yuv420p")
    for plane, values, side in zip(frame.planes, codes, (32, 16, 16), strict=True):
        block = np.repeat(np.repeat(values[None], side, 0), side, 1)
        padded = np.zeros((plane.height, plane.line_size), np.uint8)
        padded[:, : block.shape[1]] = block
        plane.update(padded.tobytes())
    frame.colorspace, frame.color_range = colorspace, 2 if full else 1
    return frame


@pytest.mark.parametrize("kr, kb, colorspace, full", [
    (0.2126, 0.0722, 1, False),  # a phone's HD video: BT.709, studio swing
    (0.299, 0.114, 6, False),  # BT.601
    (0.2126, 0.0722, 1, True),  # full swing
    (0.299, 0.114, 2, False),  # untagged: BT.601, as FFmpeg reads it
])
def test_each_frame_is_converted_with_its_own_matrix_and_range(kr, kb, colorspace, full):
    rgb = frame_to_rgb(_tagged_frame(kr, kb, colorspace, full))
    np.testing.assert_allclose(rgb[16, 16::32].astype(int), PATCHES.astype(int), atol=1)


def test_the_matrix_is_the_standard_one():
    """Full-swing BT.601 is JPEG's Y'CbCr, which OpenCV converts on its own."""
    rng = np.random.default_rng(0)
    ycc = rng.integers(16, 240, (64, 64, 3), dtype=np.uint8)
    ours = cv2.transform(ycc, ycbcr_matrix(0.299, 0.114, full=True))
    theirs = cv2.cvtColor(ycc[..., [0, 2, 1]], cv2.COLOR_YCrCb2RGB)  # OpenCV orders Y, Cr, Cb
    assert np.abs(ours.astype(int) - theirs.astype(int)).max() <= 1


def test_a_frame_in_another_format_keeps_ffmpegs_conversion():
    image = np.ascontiguousarray(np.repeat(np.repeat(PATCHES[None], 8, 0), 8, 1))
    frame = av.VideoFrame.from_ndarray(image, format="rgb24")
    np.testing.assert_array_equal(frame_to_rgb(frame), image)
    semi_planar = frame.reformat(format="nv12")
    np.testing.assert_array_equal(frame_to_rgb(semi_planar),
                                  semi_planar.to_ndarray(format="rgb24"))


@pytest.mark.parametrize("fmt", ["yuv444p", "yuv420p", "rgb24"])
def test_half_rgb_is_the_frame_at_every_second_pixel(fmt):
    """Where chroma is sampled at every pixel (4:4:4, RGB) it is exactly the full conversion's
    even pixels; in 4:2:0 each pixel takes its 2 x 2 block's chroma, so inside a patch of one
    colour it is the full conversion's value there."""
    rng = np.random.default_rng(1)
    image = np.repeat(np.repeat(PATCHES[None], 16, 0), 16, 1)  # 16 x 64, patches 16 wide
    image = np.ascontiguousarray(np.concatenate([image, rng.integers(0, 256, image.shape,
                                                                     dtype=np.uint8)]))
    frame = av.VideoFrame.from_ndarray(image, format="rgb24")
    if fmt != "rgb24":
        frame = frame.reformat(format=fmt)
    half, full = half_rgb(frame), frame_to_rgb(frame)[::2, ::2]
    assert half.shape == full.shape == (16, 32, 3)
    if fmt == "yuv420p":
        half, full = half[2:6, 1:7], full[2:6, 1:7]  # inside the first patch
    np.testing.assert_array_equal(half, full)
