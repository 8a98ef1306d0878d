"""Phone A tracking: pose from the board, LED placement, frame checks, the poses files."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.capture.acquisition import load_poses
from ltmstore.capture.board import BoardDetector, board_spec
from ltmstore.capture.calibrate import Intrinsics, load_intrinsics
from ltmstore.capture.track import (
    FramePose,
    TrackConfig,
    estimate_pose,
    flag_out_of_plane,
    led_position,
    track_frame,
    track_video,
    write_tracks,
)
from ltmstore.core.errors import LtmError
from ltmstore.synthetic.raw import (
    BOARD_PAPER,
    BOARD_SQUARE_MM,
    DOWN,
    BoardView,
    PhoneCamera,
    camera_extrinsics,
    led_to_camera,
    rotation,
)

CAMERA = PhoneCamera(size=(640, 360), focal_px=500.0, led_offset=(0.012, -0.004, 0.002))


@pytest.fixture(scope="module")
def scene():
    spec = board_spec(BOARD_PAPER, square_mm=BOARD_SQUARE_MM)
    view = BoardView(spec, CAMERA)
    intr = Intrinsics(CAMERA.size, CAMERA.matrix, np.zeros(5))
    return spec, view, intr, BoardDetector(spec)


def render(view, led, r_wc, seed=0):
    centre = led_to_camera(np.asarray(led)[None], r_wc[None], CAMERA.led_offset)[0]
    return view.render([(centre, r_wc)], np.random.default_rng(seed))


def test_estimate_pose_recovers_exact_projection(scene):
    spec, _, intr, _ = scene
    r_wc = rotation(2, 0.3) @ rotation(0, 0.05) @ DOWN
    r_cb, t = camera_extrinsics(spec, np.array([0.05, -0.02, 0.3]), r_wc)
    xy = np.stack(np.meshgrid(np.linspace(0.4, 0.7, 5), np.linspace(0.3, 0.5, 4)), -1)
    obj = np.column_stack([xy.reshape(-1, 2), np.zeros(20)])
    img = (intr.matrix @ (r_cb @ obj.T + t[:, None])).T
    img = img[:, :2] / img[:, 2:]
    r_est, t_est, rms = estimate_pose(obj, img, intr)
    assert rms < 1e-6
    np.testing.assert_allclose(r_est, r_cb, atol=1e-8)
    np.testing.assert_allclose(t_est, t, atol=1e-8)


def test_led_offset_axes_straight_down(scene):
    """Looking straight down: camera x is +r, camera y (image down) is -s."""
    spec, *_ = scene
    r_cb, t = camera_extrinsics(spec, np.array([0.1, 0.05, 0.3]), DOWN)
    led, tilt, axis = led_position(spec, r_cb, t, (0.01, 0.02, 0.003))
    np.testing.assert_allclose(led, [0.11, 0.03, 0.297], atol=1e-12)
    assert tilt == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(axis, [0.0, 0.0, -1.0], atol=1e-12)  # the LED shines down


@pytest.mark.parametrize(("led", "yaw", "tilt"), [
    ((0.0, 0.0, 0.3), 0.0, 0.0), ((0.17, -0.12, 0.31), 0.4, 3.0), ((-0.19, 0.18, 0.28), -0.3, 5.0),
])
def test_track_frame_is_sub_millimetre(scene, led, yaw, tilt):
    spec, view, intr, det = scene
    r_wc = (rotation(2, yaw) @ rotation(0, np.radians(tilt))
            @ rotation(1, np.radians(tilt / 2)) @ DOWN)
    pose = track_frame(det, render(view, led, r_wc), 0.0, intr,
                       TrackConfig(led_offset=CAMERA.led_offset))
    assert pose.status == "ok" and pose.corners >= 10
    assert pose.reprojection_px < 0.3
    assert np.linalg.norm(pose.led - led) < 3e-4, pose.led - led  # < 0.3 mm
    assert pose.tilt_deg == pytest.approx(np.degrees(np.arccos(np.cos(np.radians(tilt))
                                                               * np.cos(np.radians(tilt / 2)))),
                                          abs=0.1)
    # the LED's axis is the camera's optical axis, in plane coordinates (measured 0.004-0.021
    # degrees from the true one)
    off = np.degrees(np.arccos(np.clip(pose.axis @ r_wc[:, 2], -1, 1)))
    assert off < 0.05, (pose.axis, r_wc[:, 2])


def test_flags_tilted_and_boardless_frames(scene):
    spec, view, intr, det = scene
    config = TrackConfig(led_offset=CAMERA.led_offset, max_tilt_deg=15.0)
    tilted = track_frame(det, render(view, (0, 0, 0.3), rotation(0, np.radians(25)) @ DOWN), 0.0,
                         intr, config)
    assert tilted.status == "tilted"
    blank = track_frame(det, np.full((360, 640), 128, np.uint8), 0.0, intr, config)
    assert blank.status == "no_board" and np.isnan(blank.led).all()


def test_poor_pose_is_flagged(scene):
    spec, view, intr, det = scene
    wrong = Intrinsics(intr.image_size, intr.matrix, np.array([0.3, 0, 0, 0, 0]))
    pose = track_frame(det, render(view, (0.05, 0.05, 0.3), DOWN), 0.0, wrong,
                       TrackConfig(max_reprojection_px=0.5))
    assert pose.status == "poor_pose" and pose.reprojection_px > 0.25


def test_out_of_plane_and_files_follow_the_contract(tmp_path):
    def fp(t, z, status="ok"):
        led = np.full(3, np.nan) if status == "no_board" else np.array([0.01 * t, 0.0, z])
        return FramePose(t, led, 20, 0.1, 1.0, status)

    frames = [fp(i / 30, 0.3) for i in range(6)] + [fp(0.2, 0.25), fp(7 / 30, 0, "no_board"),
                                                     fp(8 / 30, 0.301)]
    flagged = flag_out_of_plane(frames, TrackConfig())
    assert [f.status for f in flagged][6:] == ["out_of_plane", "no_board", "ok"]
    paths = write_tracks(tmp_path / "poses.csv", flagged)
    poses = load_poses(paths["poses"])  # ingest's reader accepts it unchanged
    assert len(poses) == 8 and not np.isin(7 / 30, poses.t)
    lines = (tmp_path / "poses.frames.csv").read_text().splitlines()
    assert len(lines) == 10 and lines[8].endswith("no_board")
    assert poses.axis is None  # frames without an axis: the columns are left out
    # with each frame's LED axis (a tracker's poses), the poses carry it for ingest's beam
    tilted = np.array([0.05, -0.02, -1.0]) / np.linalg.norm([0.05, -0.02, -1.0])
    aimed = [FramePose(f.t, f.led, 20, 0.1, 1.0, f.status, tilted if f.status != "no_board"
                       else np.full(3, np.nan)) for f in flagged]
    poses = load_poses(write_tracks(tmp_path / "aimed.csv", aimed)["poses"])
    assert len(poses) == 8
    np.testing.assert_allclose(poses.axis, np.tile(tilted, (8, 1)), atol=1e-7)


def test_track_video_without_board_is_an_error(tmp_path, scene):
    from ltmstore.synthetic.writer import write_video

    spec, _, intr, _ = scene
    write_video(tmp_path / "a.mkv", [np.full((360, 640, 3), 90, np.uint8)] * 4)
    with pytest.raises(LtmError, match=r"found in 0 and posed in 0 of 4 frames"):
        track_video(tmp_path / "a.mkv", spec, intr, TrackConfig(), progress=False)


@pytest.mark.parametrize(("text", "pattern"), [
    ("{", "is malformed"),
    ('{"format": "ltm-intrinsics/1", "camera_matrix": [[1, 0], [0, 1]], "image_size": [4, 3],'
     ' "dist_coeffs": [0, 0, 0, 0]}', "must be 3x3"),
    ('{"format": "other"}', "has format 'other'"),
])
def test_bad_intrinsics(tmp_path, text, pattern):
    (tmp_path / "i.json").write_text(text)
    with pytest.raises(LtmError, match=pattern):
        load_intrinsics(tmp_path / "i.json")
