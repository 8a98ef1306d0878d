"""Ingest copes with camera B as a phone films: gain drift, room light with an LED-off lead,
lens distortion (issue 29 item 3).

Each effect is put on a clean simulated capture with a known size (:mod:`phone_helpers`); the
ingested frames are compared with the clean capture's, and the whole chain's SNR_Y with the
truth. Bounds sit near the values measured when these tests were written (noted beside them).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from phone_helpers import (
    camera,
    distort,
    drift_gains,
    read_linear,
    room_light,
    with_lead,
    write_variant,
)

from ltmstore.capture.sync import sync_acquisition  # noqa: E402
from ltmstore.core.errors import LtmError  # noqa: E402
from ltmstore.judge.evaluate import snr_db  # noqa: E402
from ltmstore.stages.ingest import ingest  # noqa: E402

LEAD = 30  # LED-off frames (1 s at 30 fps)


def _simulate(folder: Path, **kw) -> Path:
    from ltmstore.synthetic.simulate import simulate_acquisition

    simulate_acquisition(folder, size=32, lattice=(16, 16), progress=False, **kw)
    return folder


@pytest.fixture(scope="module")
def long_capture(tmp_path_factory):
    """A 38 s scribble over a canvas (1140 frames): long enough to pin a drift down."""
    return _simulate(tmp_path_factory.mktemp("phone") / "long", scene="canvas", seed=2,
                     path_density=60.0)


@pytest.fixture(scope="module")
def short_capture(tmp_path_factory):
    """A 9 s capture of the relief (263 frames)."""
    return _simulate(tmp_path_factory.mktemp("phone") / "short", scene="relief", seed=1,
                     path_density=14.0)


def _frames(store: Path) -> np.ndarray:
    return xr.open_zarr(store, consolidated=False)["frames"].values


def _relative_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def _read_only(folder: Path) -> tuple[np.ndarray, float]:
    """:func:`read_linear`, its frames made read-only: decoded once per module and shared by
    the tests, which make their variants from it (a test that wrote into it would fail)."""
    frames, fps = read_linear(folder)
    frames.setflags(write=False)
    return frames, fps


@pytest.fixture(scope="module")
def long_linear(long_capture):
    """``long_capture``'s linear frames and frame rate (:func:`read_linear`), read-only."""
    return _read_only(long_capture)


@pytest.fixture(scope="module")
def short_linear(short_capture):
    """``short_capture``'s linear frames and frame rate (:func:`read_linear`), read-only."""
    return _read_only(short_capture)


@pytest.fixture(scope="module")
def clean_long(long_capture, tmp_path_factory):
    """``long_capture`` ingested: its record, its frames and the store (which tests copy
    before they change it)."""
    store = tmp_path_factory.mktemp("phone") / "clean.zarr"
    return ingest(long_capture, store, progress=False), _frames(store), store


@pytest.fixture(scope="module")
def clean_short(short_capture, tmp_path_factory):
    """``short_capture`` ingested: its record and its frames."""
    store = tmp_path_factory.mktemp("phone") / "clean.zarr"
    return ingest(short_capture, store, progress=False), _frames(store)


def test_locked_exposure_comes_out_unchanged(short_capture, clean_short):
    from ltmstore.capture.video import VideoReader
    from ltmstore.core.dims import rgb_to_ycbcr
    from ltmstore.core.transfer import transfer_lut

    record, stored = clean_short
    drift = record["drift"]
    # measured: RMS log gain 0.0015-0.003 on clean captures, threshold >= 0.01
    assert drift["judged"] and not drift["corrected"], drift
    assert drift["rms_log_gain"] < 0.006, drift
    assert record["ambient"]["measured"] is False and record["undistort"] is None
    assert "led_off" not in record["rejected"]
    lut = transfer_lut("srgb")
    with VideoReader(short_capture / "video.mkv") as video:
        plain = np.stack([rgb_to_ycbcr(lut[rgb])[..., 0] for _, rgb in video.frames()])
    # unchanged: what ingest stores (float16) of the plain linear luminance
    np.testing.assert_array_equal(stored, plain.astype(np.float16))


def test_drift_is_estimated_and_corrected(long_capture, long_linear, clean_long, tmp_path):
    frames, fps = long_linear
    gains = drift_gains(len(frames), fps, exposure=0.25, white_balance=0.06)
    folder = write_variant(long_capture, tmp_path / "drift", frames * gains[:, None, None], fps)
    record = ingest(folder, tmp_path / "d.zarr", progress=False)
    drift = record["drift"]
    assert drift["corrected"], drift
    true_rms = float(np.sqrt(np.mean(np.log(gains) ** 2)))  # 0.183; measured estimate 0.179
    assert abs(drift["rms_log_gain"] - true_rms) < 0.01, (drift, true_rms)
    got = _frames(tmp_path / "d.zarr")
    clean = clean_long[1]
    scale = float(np.sum(got * clean) / np.sum(got * got))  # the gauge: mean log gain 0
    # measured: 0.0107 corrected, 0.177 without the correction
    assert _relative_rms(got * scale, clean) < 0.02
    assert abs(np.log(scale)) < 0.02  # measured -0.011


def test_uncorrectable_drift_is_refused(long_capture, short_capture, long_linear, short_linear,
                                        tmp_path):
    frames, fps = long_linear
    gains = drift_gains(len(frames), fps, exposure=1.0, white_balance=0.0)  # 7.5x span
    folder = write_variant(long_capture, tmp_path / "big", frames * gains[:, None, None], fps)
    with pytest.raises(LtmError, match=r"factor .*AE/AWB lock"):
        ingest(folder, tmp_path / "big.zarr", progress=False)
    assert not (tmp_path / "big.zarr").exists()
    frames, fps = short_linear  # 9 s: the path comes back too rarely
    gains = drift_gains(len(frames), fps, exposure=0.25, white_balance=0.0)
    folder = write_variant(short_capture, tmp_path / "short", frames * gains[:, None, None], fps)
    with pytest.raises(LtmError, match=r"cannot be measured.*lock exposure"):
        ingest(folder, tmp_path / "short.zarr", progress=False)
    assert not (tmp_path / "short.zarr").exists()


def test_a_user_who_locked_the_exposure_is_not_turned_away(short_capture, short_linear,
                                                            tmp_path):
    """A drift the path cannot measure (9 s, 25 % exposure wave: the refusal above) is refused
    with one line that names ``--exposure-locked``; with it, the user's word is taken: the
    store is made, the frames left uncorrected, and the record says so."""
    from pipeline_helpers import run_ltm

    frames, fps = short_linear
    gains = drift_gains(len(frames), fps, exposure=0.25, white_balance=0.0)
    folder = write_variant(short_capture, tmp_path / "short", frames * gains[:, None, None], fps)
    refused = run_ltm("ingest", folder, tmp_path / "refused.zarr")
    assert refused.returncode == 2, refused.stderr
    assert refused.stderr.count("\n") == 1 and "--exposure-locked" in refused.stderr
    assert not (tmp_path / "refused.zarr").exists()
    taken = run_ltm("ingest", folder, tmp_path / "locked.zarr", "--exposure-locked")
    assert taken.returncode == 0, taken.stderr
    drift = json.loads(taken.stdout)["drift"]
    assert drift["exposure_locked"] and not drift["corrected"], drift
    assert drift["stderr_data_log_gain"] > 0.02, drift  # what made it unmeasurable


def test_room_light_is_measured_in_the_lead_and_removed(long_capture, long_linear, clean_long,
                                                        tmp_path):
    frames, fps = long_linear
    ambient = room_light(frames, 0.3)
    lit = with_lead(frames, ambient, LEAD, np.random.default_rng(0))
    folder = write_variant(long_capture, tmp_path / "amb", lit, fps, time_offset=LEAD / fps)
    record = ingest(folder, tmp_path / "a.zarr", progress=False)
    assert record["ambient"]["measured"] and record["ambient"]["step_frame"] == LEAD
    assert record["ambient"]["excluded_frames"][1] > LEAD
    got = _frames(tmp_path / "a.zarr")
    valid = xr.open_zarr(tmp_path / "a.zarr", consolidated=False)["pose_valid"].values
    assert not valid[:record["ambient"]["excluded_frames"][1]].any()
    # measured: 0.0049; with the room light left in (no lead): 0.29
    assert _relative_rms(got[LEAD:], clean_long[1]) < 0.01


def test_sync_finds_the_offset_with_the_lead(long_capture, long_linear, tmp_path):
    frames, fps = long_linear
    lit = with_lead(frames, room_light(frames, 0.3), LEAD, np.random.default_rng(1))
    folder = write_variant(long_capture, tmp_path / "sync", lit, fps)
    est = sync_acquisition(folder, progress=False)
    assert est["led_off_frames"] == LEAD + 3
    # measured: 0.9 ms off; fitting the lead's frames too: 27 ms off (stderr 0.5 ms)
    assert abs(est["time_offset"] - LEAD / fps) < 0.004, est


def test_distortion_is_undone_with_the_calibration(short_capture, short_linear, clean_short,
                                                  tmp_path):
    frames, fps = short_linear
    intr = camera(frames.shape[2], frames.shape[1], k1=-0.15)  # the sim's camera B k1
    bent = distort(frames, intr)
    folder = write_variant(short_capture, tmp_path / "dist", bent, fps,
                           extra={"camera_calibration": "cam.json"})
    intr.write(folder / "cam.json")
    record = ingest(folder, tmp_path / "u.zarr", progress=False)
    assert record["undistort"]["file"].endswith("cam.json")
    clean = clean_short[1]
    plain = write_variant(short_capture, tmp_path / "plain", bent, fps)
    ingest(plain, tmp_path / "p.zarr", progress=False)
    fixed = snr_db(clean, _frames(tmp_path / "u.zarr"))
    left = snr_db(clean, _frames(tmp_path / "p.zarr"))
    # measured: 25.8 dB undistorted (the bicubic round trip on pixel-scale texture), 18.6 bent
    assert fixed > 24.5 and fixed > left + 5, (fixed, left)


def test_calibration_of_another_size_is_refused(short_capture, short_linear, tmp_path):
    folder = write_variant(short_capture, tmp_path / "size", short_linear[0],
                           30.0, extra={"camera_calibration": "cam.json"})
    camera(64, 48, k1=-0.1).write(folder / "cam.json")
    with pytest.raises(LtmError, match=r"64x48 pixel frames but video .* has 32x32"):
        ingest(folder, tmp_path / "x.zarr", progress=False)
    assert not (tmp_path / "x.zarr").exists()
    meta = json.loads((folder / "acquisition.json").read_text())
    meta["camera_calibration"] = "missing.json"
    (folder / "acquisition.json").write_text(json.dumps(meta))
    with pytest.raises(LtmError, match="camera_calibration file 'missing.json' does not exist"):
        ingest(folder, tmp_path / "x.zarr", progress=False)


def test_reconstruction_of_a_drifting_capture_with_room_light(long_capture, long_linear,
                                                              clean_long, tmp_path, client):
    """The whole chain: a 25 % exposure wave (running through the lead too), a white-balance
    wander and a room light of 30 % of the lit level with its LED-off lead, against the same
    capture clean. A drifting camera has no true exposure: SNR_Y after one best scale."""
    from ltmstore.stages.reconstruct import reconstruct

    frames, fps = long_linear
    lit = with_lead(frames, room_light(frames, 0.3), LEAD, np.random.default_rng(2))
    gains = drift_gains(len(lit), fps, exposure=0.25, white_balance=0.06)
    folder = write_variant(long_capture, tmp_path / "phone", lit * gains[:, None, None], fps,
                           time_offset=LEAD / fps)
    truth = xr.open_zarr(long_capture / "truth.zarr", consolidated=False)["ltm"].values
    snr = {}
    # the clean capture's ingest is the module's (copied: reconstruct writes into the store)
    shutil.copytree(clean_long[2], tmp_path / "clean.zarr")
    for name, source in (("clean", None), ("phone", folder)):
        if source is not None:
            record = ingest(source, tmp_path / f"{name}.zarr", progress=False)
        reconstruct(tmp_path / f"{name}.zarr", client=client, lattice=(16, 16), progress=False)
        ltm = xr.open_zarr(tmp_path / f"{name}.zarr", consolidated=False)["ltm"].values
        snr[name] = snr_db(truth, ltm * (np.sum(ltm * truth) / np.sum(ltm * ltm)))
    assert record["drift"]["corrected"] and record["ambient"]["measured"], record
    # measured: clean 48.2 dB, phone 32.6 dB (the lead's gain is extrapolated across the step
    # from the drift estimate at the first lit frames: 3-7 % off here, times a 30 % room
    # light); without the corrections: see the report. With single cells hidden to choose the
    # residual's weight (0.5 kept unless another did 2 % better): clean 46.2, phone 33.3 dB.
    assert snr["phone"] > 32.2 and snr["clean"] > 47.7, snr


@pytest.mark.parametrize(("series", "step"), [
    ([0.05] * 30 + [0.30, 0.25, 0.35] * 40, 30),  # room light, then the torch
    ([0.0] * 20 + [0.30, 0.25, 0.35] * 40, 20),  # a dark room: noise around zero
    ([0.05] * 30 + [0.095, 0.09, 0.1] * 40, 30),  # auto exposure compresses the step to 1.9x
    (list(0.15 + 0.8 * ((np.arange(120) * 7) % 60) / 59), None),  # no steady dark start
    ([0.2] * 120, None),  # never dark
    ([0.05] * 2 + [0.3] * 100, None),  # too short to be a lead
    # the light moving from the plane's dark edge onto the painting: a gradual rise, no torch
    # step (the simulated 400 px canvas's first frames: once taken for a lead, its 70 % of the
    # lit level subtracted as room light, SNR_Y 3.8 dB)
    (list(0.068 + 0.059 * np.clip(np.arange(120) / 45, 0, 1)), None),
])
def test_lead_is_found_from_the_brightness_alone(series, step):
    from ltmstore.capture.lead import find_lead

    lead = find_lead(np.array(series), 30.0)
    assert (lead is None if step is None else lead.step == step), lead
    if lead is not None:
        assert lead.ambient == (0, step - 3) and lead.excluded == (0, step + 3)


def test_frames_no_fixed_exposure_explains_are_refused():
    from ltmstore.capture.drift import DriftEstimate
    from ltmstore.stages.phone import _drift_decision

    n = 200
    lit = np.ones(n, dtype=bool)
    estimate = DriftEstimate(log_gain=np.zeros((n, 3)), stderr=np.full((n, 3), 0.01),
                             stderr_data=np.full((n, 3), 0.01), lit=lit, residual=0.068)
    with pytest.raises(LtmError, match=r"fixed exposure cannot explain .*AE/AWB lock"):
        _drift_decision(estimate)
    gains, record = _drift_decision(DriftEstimate(
        log_gain=np.zeros((n, 3)), stderr=np.full((n, 3), 0.005),
        stderr_data=np.full((n, 3), 0.005), lit=lit, residual=0.004))
    assert gains is None and record["corrected"] is False


def test_a_drift_the_data_cannot_measure_is_not_taken_as_locked():
    """Camera B's auto exposure with poses that sync put 3 frames off (a simulated ultrawide
    capture) measured as a 5.7 % RMS drift with a 1.5 % standard error, but a data-only standard
    error of 29 %: within four of its own standard errors, it was taken as locked and ingested
    with exit 0. A drift the data cannot measure is refused unless it is below 1 %."""
    from ltmstore.capture.drift import DriftEstimate
    from ltmstore.stages.phone import DRIFT_MIN, _drift_decision

    n = 200
    wave = np.sin(np.linspace(0, 6, n))[:, None] * np.ones(3)

    def estimate(rms: float, stderr_data: float) -> DriftEstimate:
        return DriftEstimate(log_gain=rms * np.sqrt(2) * wave, stderr=np.full((n, 3), 0.015),
                             stderr_data=np.full((n, 3), stderr_data), lit=np.ones(n, bool),
                             residual=0.0045)

    with pytest.raises(LtmError, match="cannot be measured to better than 29.0%.*lock exposure"):
        _drift_decision(estimate(0.057, 0.29))
    gains, record = _drift_decision(estimate(0.057, 0.01))  # measurable: within its noise
    assert gains is None and not record["corrected"]
    gains, record = _drift_decision(estimate(0.8 * DRIFT_MIN, 0.29))  # negligible
    assert gains is None and not record["corrected"]
    # the user says it was locked: left uncorrected, not refused; a measured drift still
    # corrected, and a factor-4 change still refused
    gains, record = _drift_decision(estimate(0.057, 0.29), exposure_locked=True)
    assert gains is None and record["exposure_locked"] and not record["corrected"]
    gains, record = _drift_decision(estimate(0.2, 0.01), exposure_locked=True)
    assert gains is not None and record["corrected"] and "exposure_locked" not in record
    with pytest.raises(LtmError, match="factor"):
        _drift_decision(estimate(1.0, 0.01), exposure_locked=True)


def test_a_large_frame_is_scanned_on_a_quarter_of_its_pixels(tmp_path):
    """Frames of HALF_SCAN_MIN_SIDE pixels a side and more are scanned at every second pixel of
    every second row: each block's mean differs from the whole frame's by a nearly fixed factor
    (which the drift model's static scene takes up), the same from frame to frame to a small
    fraction of the 2 % misfit the drift check allows."""
    import cv2

    from ltmstore.capture.video import VideoReader
    from ltmstore.core.transfer import encode, linearise, transfer_lut
    from ltmstore.stages.phone import BLOCK_GRID, HALF_SCAN_MIN_SIDE, scan_video
    from ltmstore.synthetic.writer import write_h264

    side = HALF_SCAN_MIN_SIDE
    rng = np.random.default_rng(0)
    paint = cv2.GaussianBlur(rng.uniform(0.1, 1, (side, side, 3)).astype(np.float32), (0, 0), 1)
    ramp = np.linspace(0, 1, side, dtype=np.float32)
    frames = [encode(paint * (0.2 + 0.6 * np.abs(ramp[:, None, None] - a)), "srgb")
              for a in np.linspace(0, 1, 8)]
    path = tmp_path / "large.mp4"
    write_h264(path, iter(frames), bitrate=40_000_000)
    lut = transfer_lut("srgb", bits=8)
    scan = scan_video(path, lut, allow_dropped=False)
    with VideoReader(path) as video:
        whole = np.array([cv2.resize(linearise(rgb, lut), (BLOCK_GRID, BLOCK_GRID),
                                     interpolation=cv2.INTER_AREA).reshape(-1, 3)
                          for _, rgb in video.frames()])
    ratio = np.log(scan.blocks / whole)
    assert 1e-4 < np.abs(ratio).max() < 0.003  # measured 0.0022: a quarter of the pixels
    assert ratio.std(axis=0).max() < 0.0013  # measured 0.00099
    assert len(scan.head) == len(frames) and scan.head[0].shape == (side, side, 3)
