"""Phone effects of the raw two-phone simulation (issue 29, item 2): each one, alone, changes the
videos the way it should, and off leaves them as before. Small renders, fixed seeds."""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from pipeline_helpers import one_line_error, run_ltm

from ltmstore.capture.board import BoardDetector, board_spec, load_board
from ltmstore.capture.calibrate import calibrate_video
from ltmstore.core.dims import LUMA
from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import decode
from ltmstore.synthetic import phone_effects as pe
from ltmstore.synthetic import phone_view
from ltmstore.synthetic.camera_b import ambient_term, camera_b_frames
from ltmstore.synthetic.raw import DOWN, PhoneCamera, RawSetup, board_texture, simulate_raw
from ltmstore.synthetic.render import GGX, Shading, render_ltm
from ltmstore.synthetic.simulate import PLANE, plan_simulation, video_frames

CAMERA = PhoneCamera(size=(640, 360), focal_px=500.0)
EXPOSURE = 0.2


@pytest.fixture(scope="module")
def plan():
    return plan_simulation(scene="canvas", path_density=4.0, seed=2, size=24, lattice=(8, 8),
                           plane=PLANE)


def b_frames(plan, effects: str) -> tuple[np.ndarray, np.ndarray, RawSetup]:
    """Camera B's frames (linear RGB, decoded) and per-frame records for ``effects``."""
    setup = RawSetup(plan, CAMERA, pe.parse_effects(effects), False, 0.0, 0, False)
    _, line = setup.timeline()
    records: list = []
    frames = [decode(f, "srgb") for f in camera_b_frames(plan, line, exposure=EXPOSURE,
                                                         effects=setup.effects,
                                                         records=records)]
    return np.stack(frames), np.asarray(records), setup


@pytest.fixture(scope="module")
def b_none(plan):
    return b_frames(plan, "none")


def test_parse_effects():
    assert pe.parse_effects("all").on == frozenset(pe.EFFECTS)
    assert pe.parse_effects("none").on == frozenset()
    assert pe.parse_effects("h264, ambient").on == {"h264", "ambient"}
    for bad in ("fog", "", "h264,fog"):
        with pytest.raises(LtmError, match="expected all, none or a comma list"):
            pe.parse_effects(bad)


def test_cli_effects_errors(tmp_path):
    one_line_error(run_ltm("simulate", tmp_path / "a", "--scene", "canvas", "--raw",
                           "--effects", "fog"), "--effects 'fog'")
    one_line_error(run_ltm("simulate", tmp_path / "b", "--scene", "canvas", "--board"),
                   "need --raw")
    one_line_error(run_ltm("simulate", tmp_path / "c", "--scene", "canvas", "--shading",
                           "mismatched"), "need --raw")
    assert not any((tmp_path / name).exists() for name in "abc")


def test_camera_b_without_effects_is_as_before(plan, b_none):
    """Every effect off: camera B's frames are exactly those of the ideal simulation."""
    frames, records, _ = b_none
    before = np.stack([decode(f, "srgb") for f in video_frames(plan, exposure=EXPOSURE)])
    np.testing.assert_array_equal(frames, before)
    np.testing.assert_array_equal(records, 1.0)


def still(view, centre, rng_seed=0):
    return view.still(np.asarray(centre, float), DOWN, np.random.default_rng(rng_seed))


@pytest.fixture()
def noiseless(monkeypatch):
    monkeypatch.setattr(phone_view, "NOISE_DN", 0.0)
    monkeypatch.setattr(phone_view, "SHOT_DN", 0.0)


def test_distortion_bends_the_board_as_the_lens_model(noiseless):
    """Board corners seen through phone A's lens sit where OpenCV's model puts them (k1 = -0.04:
    2.5 px at the board's outer corners, 8 px at the frame's corners), and straight rows of
    corners bend by the predicted sagitta; without distortion they stay straight."""
    spec = board_spec("A4")
    tex = board_texture(spec)
    det = BoardDetector(spec)
    views = {d: phone_view.PhoneView(CAMERA.matrix, d, CAMERA.size, tex, None, distance=0.22)
             for d in ((0.0, 0.0), pe.DISTORTION_A)}
    found = {d: det.detect(still(v, (0.0, 0.0, 0.22))) for d, v in views.items()}
    (_, ideal, ids0), (obj, bent, ids1) = found[(0.0, 0.0)], found[pe.DISTORTION_A]
    common = np.intersect1d(ids0, ids1)
    assert len(common) >= 20  # measured 24
    ideal = ideal[np.searchsorted(ids0, common)].astype(np.float64)
    bent = bent[np.searchsorted(ids1, common)].astype(np.float64)
    k = CAMERA.matrix
    norm = (ideal - k[[0, 1], [2, 2]]) / k[0, 0]
    predicted, _ = cv2.projectPoints(np.column_stack([norm, np.ones(len(norm))]), np.zeros(3),
                                     np.zeros(3), k, np.array([*pe.DISTORTION_A, 0, 0, 0]))
    predicted = predicted.reshape(-1, 2)
    shift = np.linalg.norm(bent - ideal, axis=1)
    assert shift.max() > 2.0, shift.max()  # measured 2.5 px (the board's outer corners)
    assert np.abs(bent - predicted).max() < 0.25  # measured 0.07 px
    # the longest row of corners: its sagitta, measured against predicted
    rows = obj[np.searchsorted(ids1, common), 1]
    row = rows == rows[np.argmax(np.abs(bent[:, 1] - k[1, 2]))]
    sag = [np.ptp(np.polyfit(p[row, 0], p[row, 1], 1)[0] * p[row, 0] - p[row, 1])
           for p in (bent, predicted, ideal)]
    # measured: 0.69 px bent, 0.67 px predicted, 0.10 px through the ideal lens
    assert sag[0] > 0.5 and abs(sag[0] - sag[1]) < 0.1 and sag[2] < 0.2, sag


def moving(v: float):
    """Poses moving along r at ``v`` m/s, looking straight down from 0.25 m."""
    def poses(times):
        c = np.column_stack([v * times, np.zeros_like(times), np.full_like(times, 0.25)])
        return c, np.repeat(DOWN[None], len(times), 0), c
    return poses


def test_rolling_shutter_reads_rows_at_their_own_time(noiseless):
    """Row y is the global-shutter image at t + readout (y / (h - 1) - 1/2): the first row at
    t - 8 ms, the middle row at t; without it every row is read at t."""
    tex = board_texture(board_spec("A4"))
    args = (CAMERA.matrix, (0.0, 0.0), CAMERA.size, tex, None)
    rs = phone_view.PhoneView(*args, readout_s=pe.READOUT_S, distance=0.25)
    gs = phone_view.PhoneView(*args, distance=0.25)
    poses, rng = moving(0.5), np.random.default_rng
    t = 0.02  # the camera over the board's centre
    frame = rs.frame(t, poses, rng(0)).astype(float)
    h = CAMERA.size[1]
    top = gs.frame(t - pe.READOUT_S / 2, poses, rng(0)).astype(float)
    mid = gs.frame(t + pe.READOUT_S * ((h // 2) / (h - 1) - 0.5), poses, rng(0)).astype(float)
    assert np.abs(frame[1] - top[1]).mean() < 1.0  # measured 0.3 DN
    assert np.abs(frame[h // 2] - mid[h // 2]).mean() < 1.0
    assert np.abs(frame[1] - mid[1]).mean() > 10  # 8 mm of motion: a 16 px shift, measured 60
    off = phone_view.PhoneView(*args, readout_s=0.0, distance=0.25).frame(t, poses, rng(0))
    np.testing.assert_array_equal(off, gs.frame(t, poses, rng(0)))


def test_motion_blur_is_the_shutter_long_smear(noiseless):
    """With the shutter open 1/120 s at 0.5 m/s, the frame is the sharp one smeared along the
    motion by v S f / Z = 8.3 px; an instant shutter leaves it sharp."""
    tex = board_texture(board_spec("A4"))
    args = (CAMERA.matrix, (0.0, 0.0), CAMERA.size, tex, None)
    blurred = phone_view.PhoneView(*args, shutter_s=pe.SHUTTER_S, samples=pe.BLUR_SAMPLES,
                                   distance=0.25).frame(0.0, moving(0.5), np.random.default_rng(0))
    sharp = phone_view.PhoneView(*args, distance=0.25).frame(0.0, moving(0.5),
                                                               np.random.default_rng(0))
    length = 0.5 * pe.SHUTTER_S * CAMERA.focal_px / 0.25
    smear = np.mean([cv2.warpAffine(sharp.astype(np.float32), np.float32([[1, 0, -dx], [0, 1, 0]]),
                                    CAMERA.size, borderMode=cv2.BORDER_REPLICATE)
                     for dx in length * (np.arange(5) / 4 - 0.5)], axis=0)
    inner = np.s_[20:-20, 20:-20]
    err_smear = np.abs(blurred[inner] - smear[inner]).mean()
    err_sharp = np.abs(blurred[inner].astype(float) - sharp[inner]).mean()
    assert err_smear < 0.25 * err_sharp, (err_smear, err_sharp)  # measured 0.5 against 11 DN


def test_auto_exposure_gain_follows_brightness(plan, b_none):
    """Camera B's frames are the locked-exposure frames times the recorded AE gain, which moves
    against the scene's brightness (60 % compensation, 0.4 s lag)."""
    frames, records, _ = b_frames(plan, "auto-exposure")
    locked = b_none[0]
    gain = records[:, 0]
    ratio = (frames @ LUMA).mean(axis=(1, 2)) / (locked @ LUMA).mean(axis=(1, 2))
    np.testing.assert_allclose(ratio, gain, rtol=0.02)  # measured within 0.6 %
    assert 1.15 < gain.max() / gain.min() < 3.0, gain  # measured 1.5
    brightness = (locked @ LUMA).mean(axis=(1, 2))
    assert np.corrcoef(np.log(gain[15:]), np.log(brightness[:-15]))[0, 1] < -0.5


def test_white_balance_wanders_per_channel(plan, b_none):
    frames, records, _ = b_frames(plan, "white-balance")
    locked = b_none[0]
    ratio = frames.mean(axis=(1, 2)) / locked.mean(axis=(1, 2))
    np.testing.assert_allclose(ratio, records[:, 1:], rtol=0.02)
    np.testing.assert_array_equal(records[:, 2], 1.0)  # green is the reference
    assert 0.02 < np.log(records[:, [1, 3]]).std() < 0.04  # WB_STD = 3 %


def test_ambient_lead_frames_are_the_room_light(plan, b_none):
    """With ambient on, video B starts with 1.0 s of LED-off frames showing the room light alone;
    after it, every frame is the LED's plus the same ambient image."""
    frames, _, setup = b_frames(plan, "ambient")
    lead = int(round(pe.LED_OFF_LEAD_S * 30))
    assert len(frames) == len(b_none[0]) + lead
    amb = ambient_term(plan, EXPOSURE)
    assert np.abs(frames[:lead].mean(0) - amb).max() < 0.01  # noise averaged over 30 frames
    extra = (frames[lead:] - b_none[0]).mean(0)
    assert abs(extra.mean() / amb.mean() - 1) < 0.05, extra.mean() / amb.mean()
    _, line = setup.timeline()
    assert not line.led_on[:lead].any() and line.led_on[lead:].all()


def test_led_falloff_darkens_oblique_light_by_cos_m(plan, b_none):
    """The LED emits cos^2 of the angle from phone A's optical axis: video B is darker by that
    factor (0.78-0.95 per frame here, down to 0.5 at single pixels); the truth LTM is the
    level LED's (cos^2 of the angle from straight down), nothing else changes."""
    frames, _, setup = b_frames(plan, "led-falloff")
    _, line = setup.timeline()
    points = np.asarray(plan.scene.pixel_centres() + (np.zeros(plan.scene.shape),))
    expected = np.stack([pe.led_profile(a, light, points)
                         for a, light in zip(line.axes, line.lights, strict=True)])
    lum, ref = frames @ LUMA, b_none[0] @ LUMA
    measured = lum.sum(axis=(1, 2)) / ref.sum(axis=(1, 2))
    predicted = (ref * expected).sum(axis=(1, 2)) / ref.sum(axis=(1, 2))
    np.testing.assert_allclose(measured, predicted, rtol=0.01)  # measured within 0.3 %
    assert measured.min() < 0.8 and measured.max() < 0.96  # measured 0.78-0.95 over frames
    assert expected.min() < 0.6  # oblique pixels: darker by about half
    lattice_light = render_ltm(plan.scene, plan.lattice, PLANE.height,
                               shading=Shading(led_exponent=pe.LED_EXPONENT))
    level = render_ltm(plan.scene, plan.lattice, PLANE.height, shading=GGX)
    r, s = np.meshgrid(plan.lattice.centres(0), plan.lattice.centres(1), indexing="ij")
    x, y = plan.scene.pixel_centres()
    dz = PLANE.height - np.asarray(plan.scene.height)[..., None, None]
    d2 = (r - x[..., None, None]) ** 2 + (s - y[..., None, None]) ** 2 + dz**2
    np.testing.assert_allclose(lattice_light[..., 1], level[..., 1] * (dz**2 / d2), rtol=1e-4,
                               atol=1e-9)


@pytest.fixture(scope="module")
def capture_all(tmp_path_factory):
    """A boardless capture with every effect on (the default), tiny."""
    out = tmp_path_factory.mktemp("raw_all") / "capture"
    info = simulate_raw(out, scene="canvas", path_density=3.0, seed=4, size=24, lattice=(8, 8),
                        camera=CAMERA, time_offset=0.3, calibration_views=10, progress=False)
    return out, info


def test_everything_on_by_default(capture_all):
    out, info = capture_all
    assert set(info["effects"]) == set(pe.EFFECTS) and all(info["effects"].values())
    meta = json.loads((out / "acquisition.json").read_text())
    assert meta["video"] == "video.mp4" and meta["phone_a"]["video"] == "phone_a.mp4"
    assert meta["camera_calibration"] == "intrinsics_b.json"
    assert meta["phone_a"]["painting_width"] == pytest.approx(0.2)
    raw = json.loads((out / "truth" / "raw.json").read_text())
    assert raw["painting_width_m"] == pytest.approx(0.2) and raw["tracking"] == "painting"
    intr = json.loads((out / "truth" / "intrinsics.json").read_text())
    assert intr["dist_coeffs"][:2] == list(pe.DISTORTION_A)
    for name in ("calibration.mkv", "calibration_b.mkv", "board.json", "board_b.json",
                 "truth.zarr", "truth/camera_b.csv", "truth/intrinsics_b.json"):
        assert (out / name).exists(), name


def test_photograph_is_the_painting_at_phone_a_detail(capture_all):
    """``painting.jpg``, the user's front-on photograph (``ltm track --painting``'s map), is the
    painting phone A films: the scene rebuilt at phone A's detail, not camera B's 24 pixels."""
    from ltmstore.capture.painting_track import PaintingMap
    from ltmstore.core.transfer import srgb_to_linear
    from ltmstore.synthetic.raw import PAINTING_DETAIL_PX, painting_detail
    from ltmstore.synthetic.scenes import make_scene

    out, info = capture_all
    meta = json.loads((out / "acquisition.json").read_text())
    assert meta["phone_a"]["painting"] == "painting.jpg" == Path(info["paths"]["photograph"]).name
    pmap = PaintingMap.load(out / "painting.jpg", meta["phone_a"]["painting_width"])
    assert pmap.image.shape == (PAINTING_DETAIL_PX, PAINTING_DETAIL_PX)
    detail = painting_detail(make_scene("canvas", size=24, seed=4)) @ LUMA
    photo = srgb_to_linear(pmap.image / 255.0)
    corr = np.corrcoef(photo.ravel(), detail.ravel())[0, 1]
    coarse = cv2.resize(cv2.resize(detail, (24, 24), interpolation=cv2.INTER_AREA),
                        detail.shape[::-1], interpolation=cv2.INTER_CUBIC)
    fine = np.corrcoef((photo - cv2.GaussianBlur(photo, (0, 0), 4)).ravel(),
                       (detail - coarse).ravel())[0, 1]
    assert corr > 0.98 and fine > 0.7, (corr, fine)  # measured: 0.995, 0.80


def decode_all(path):
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        frames = [f.to_ndarray(format="gray") for f in c.decode(video=0)]
        return stream.codec_context.name, frames, stream.bit_rate


def test_h264_videos_at_a_phone_bitrate(capture_all):
    out, info = capture_all
    for name, size in (("phone_a.mp4", CAMERA.size), ("video.mp4", (24, 24))):
        codec, frames, rate = decode_all(out / name)
        assert codec == "h264" and len(frames) == info["frames"], (codec, len(frames))
        assert frames[0].shape == size[::-1]
    _, frames, _ = decode_all(out / "phone_a.mp4")
    seconds = len(frames) / 30
    bits = (out / "phone_a.mp4").stat().st_size * 8
    target = pe.h264_bitrate(CAMERA.size, 30)
    assert 0.3 * target < bits / seconds < 1.5 * target, (bits / seconds, target)


def test_lead_and_poses_on_camera_b_clock(capture_all):
    """Phone A's first second is LED-off (ambient only: darker); the true poses list every frame
    of phone A, on video B's clock (t = 0 at B's first, LED-off, frame)."""
    out, info = capture_all
    _, frames, _ = decode_all(out / "phone_a.mp4")
    mean = np.array([f.mean() for f in frames])
    assert mean[:25].mean() < 0.75 * mean[35:].mean(), (mean[:25].mean(), mean[35:].mean())
    poses = np.loadtxt(out / "truth" / "poses_true.csv", delimiter=",", skiprows=1)
    assert len(poses) == info["frames"]
    np.testing.assert_allclose(poses[0, 0], info["time_offset"], atol=1e-6)


def test_calibration_recovers_phone_a_distortion(capture_all):
    out, _ = capture_all
    intr, report = calibrate_video(out / "calibration.mkv", load_board(out / "board.json"),
                                   progress=False)
    assert abs(intr.distortion[0] - pe.DISTORTION_A[0]) < 0.006, intr.distortion  # measured
    assert abs(intr.matrix[0, 0] - CAMERA.focal_px) < 5, intr.matrix


def test_camera_b_films_the_physics_it_is_given(plan, b_none, tmp_path):
    """``shading="mismatched"`` (a Beckmann lobe, a 2 % floor, a clear coat: physics the
    product does not assume): each of camera B's frames is that physics' render of its light
    (the LED's beam left to the effects), compared through the GGX frames: the brightness
    ratio of the two videos per frame is the noise-free renders' within 1 % (measured 0.02 %)."""
    from dataclasses import replace

    from ltmstore.synthetic.render import MISMATCHED, render_frame

    _, line = RawSetup(plan, CAMERA, pe.parse_effects("none"), False, 0.0, 0, False).timeline()
    frames = np.stack([decode(f, "srgb") for f in camera_b_frames(
        plan, line, exposure=EXPOSURE, effects=pe.parse_effects("none"), records=[],
        shading=MISMATCHED)])
    lit = np.flatnonzero(line.led_on)[::10]
    measured = (frames[lit] @ LUMA).sum(axis=(1, 2)) / (b_none[0][lit] @ LUMA).sum(axis=(1, 2))
    flat = replace(MISMATCHED, led_exponent=0.0)
    predicted = np.array([(render_frame(plan.scene, line.lights[k], shading=flat) @ LUMA).sum()
                          / (render_frame(plan.scene, line.lights[k]) @ LUMA).sum() for k in lit])
    np.testing.assert_allclose(measured, predicted, rtol=0.01)
    assert np.ptp(predicted) > 0.05  # the physics differ with the light's place: measured 0.076
    with pytest.raises(LtmError, match="shading 'phong' must be one of ggx, mismatched"):
        simulate_raw(tmp_path / "x", scene="canvas", size=24, shading="phong", progress=False)
