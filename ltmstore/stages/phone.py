"""Camera B as a phone films: lens distortion, room light and exposure drift, undone at ingest.

A first pass over the video (:func:`scan_video`) measures every frame coarsely (mean linear RGB
of :data:`BLOCK_GRID` x :data:`BLOCK_GRID` blocks; of frames :data:`HALF_SCAN_MIN_SIDE` pixels
and more a side, over every second pixel of every second row:
:func:`~ltmstore.capture.yuv.half_rgb`) and keeps its first seconds. From that:

* the LED-off lead (:func:`ltmstore.capture.lead.find_lead`) gives the ambient image, the
  median of its frames (:mod:`ltmstore.stages.ambient`); its frames are not samples;
* the drift of camera B's gain per colour channel (:mod:`ltmstore.capture.drift`) is corrected
  when it is well above the estimate's noise, refused when it is too large or too poorly
  determined to correct;
* where the poses give phone A's LED axis (``axis_r, axis_s, axis_z``), the LED's ``cos^k``
  beam (over the plane's central half, where the frame is taken to lie) enters the drift
  model, so that a hand's wobble is not read as drift, and its exponent ``k`` is measured from
  how the wobble moves light across the frame (:mod:`ltmstore.capture.led_beam`, the room light
  taken off first) and recorded (``beam``; :data:`BEAM_PROFILE_EXPONENT` where the frames
  cannot tell). The frames are not divided by the beam here: at the object's centre (all
  ingest knows of the pixels' places) that brought the frames of a 64 px canvas with a 3
  degree wobble nearer those of a level LED (RMS 4.4 -> 2.3 %) but the LTM's SNR_Y down by
  1.4 dB (26.9 -> 25.5; a level LED: 27.0). The axis is stored instead (``pose_axis_*``), and
  the reconstruction's surface model, which knows each pixel's place under the light, fits each
  lattice cell's beam about the mean axis of its frames.

Each frame is then, in linear light: undistorted (:mod:`ltmstore.capture.undistort`), divided by
its gains, and the ambient image (in the same corrected units: measured at the lead's gain)
is subtracted. Gains come first because the room light reached the sensor through the same
gain as the LED's light.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.drift import DriftEstimate, beam_log_ratio, estimate_drift
from ltmstore.capture.lead import Lead, find_lead
from ltmstore.capture.led_beam import estimate_beam, object_guess
from ltmstore.capture.undistort import Undistorter
from ltmstore.capture.video import VideoReader, threaded_first
from ltmstore.capture.yuv import frame_to_rgb, half_rgb
from ltmstore.core.dims import Plane, rgb_to_ycbcr
from ltmstore.core.errors import LtmError, LtmWarning
from ltmstore.core.transfer import linearise
from ltmstore.stages.ambient import ambient_floor, ambient_image
from ltmstore.stages.frames import Lights
from ltmstore.stages.occlusion import occluded_frames

BLOCK_GRID = 8
# Frames this wide and high are scanned at every second pixel of every second row (240 frames of
# 4K H.264: 48.7 -> 41.8 s, with 32,400 pixels a block still). Smaller ones whole: a 32 x 32
# capture's drift misfit rose from under 2 % to 3.6 % on a quarter of its pixels.
HALF_SCAN_MIN_SIDE = 1024
LEAD_TAIL_FRAMES = 3  # the ambient frames nearest the step: the gain of the first lit frame
HEAD_S = 4.0  # seconds of video kept from the first pass for the ambient image
HEAD_BYTES = 256 * 1024**2  # at most this much of it
# Drift (the rule: :func:`_drift_decision`). Measured on 180 drift-free simulated captures
# (canvas, relief, icon; 16-64 px; 6-17 s; seeds 0-3): RMS log gain 0.002-0.030 (the icon's
# gold at 16 px the most), at most 1.07 of its own standard error.
DRIFT_MIN = 0.01  # below this a drift is negligible, whatever its significance
DRIFT_SIGMAS = 4.0  # a drift beyond this many standard errors is significant (P <= 6e-5)
# A drift the data cannot measure (MAX_DRIFT_STDERR) is still refused when its estimate is this
# large (a 5 % gain error caps the LTM near 26 dB), significant or not: shrunk towards zero by
# the smoothness prior, such an estimate cannot be put down to noise. Drift-free: at most 0.030
# (above); 0.12-0.31 with the simulator's auto exposure on a 16 px icon (1.5-3.9 standard errors).
DRIFT_MATTERS = 0.05
MAX_DRIFT_SPAN = math.log(4.0)  # larger gain changes are not corrected (noise, clipping)
# A drift whose data-only standard error (median over frames) is larger than this is refused:
# measured 0.006 (51 s scribble), 0.016 (17 s), 0.09 (9 s) with actual errors of the
# correction 0.005, 0.033 and 0.10 for a 25 % exposure wave.
MAX_DRIFT_STDERR = 0.02
# RMS misfit (log units, per frame) of "a static scene times a smooth gain": measured
# 0.002-0.005 on simulated canvas and relief captures with and without drift, room light,
# distortion; 0.008-0.015 on the icon at 32-64 px and up to 0.043 at 16 px (its gold's
# highlights are sharper in the light position than the model's grid: a drift-free capture,
# refused at 0.02 before issue 63); 0.068 with the simulator's auto exposure (a gain that jumps
# when the torch comes on and follows the frame's brightness with a 0.4 s lag). Above this the
# frames are not a fixed exposure's.
MAX_DRIFT_RESIDUAL = 0.05
# The LED's beam: its exponent is estimated where its standard error is at most this, else the
# profile's (a phone's flash LED behind its lens: half intensity at 45-60 degrees, k = 1-2.4).
# A 720 px simulated canvas without a beam, tracked poses (1.6 degrees of wobble), measured
# 0.70 +- 0.44: taken as it was (the limit was 0.5), it relit 0.58 dB below k = 0.
BEAM_MAX_STDERR = 0.25
BEAM_PROFILE_EXPONENT = 2.0
BEAM_EXPONENT_RANGE = (0.0, 8.0)  # estimates are clipped to this
LOCK_ADVICE = ("lock exposure and white balance on camera B (AE/AWB lock) and record again")
# Without a lead: the darkest 2 % of each block's frames over its median, median over blocks
# (:func:`ltmstore.stages.ambient.ambient_floor`). Measured 0.47 on a clean simulated canvas
# (no room light: the LED's own fall-off over the plane), 0.60 with a room light of 30 % of the
# mean lit level: the floor cannot tell a modest room light from the LED's fall-off, so the
# warning is kept for a room light about as strong as the LED (floor above 0.75), where the LTM
# would be mostly room light.
AMBIENT_FLOOR_WARN = 0.75


@dataclass
class Scan:
    """The first pass over camera B's video."""

    index: np.ndarray  # frame numbers
    blocks: np.ndarray  # (n, B, 3) mean linear RGB per block
    brightness: np.ndarray  # (n,) mean linear luminance
    head: list[np.ndarray]  # the first frames' uint8 RGB codes
    fps: float


def scan_video(path: Path, lut: np.ndarray, *, allow_dropped: bool) -> Scan:
    """Decode the video once: block means, brightness and the first frames (on FFmpeg's
    threads unless the video is damaged: :func:`ltmstore.capture.video.threaded_first`)."""
    return threaded_first(partial(_scan, path, lut, allow_dropped=allow_dropped))


def _scan(path: Path, lut: np.ndarray, threaded: bool, *, allow_dropped: bool) -> Scan:
    index, blocks, brightness, head = [], [], [], []
    keep = None
    with VideoReader(path, allow_dropped=allow_dropped, threaded=threaded) as video:
        for i, frame in video.decoded():
            if keep is None:
                size = 3 * frame.width * frame.height
                keep = max(1, min(int(HEAD_S * video.fps), HEAD_BYTES // max(size, 1)))
            large = min(frame.width, frame.height) >= HALF_SCAN_MIN_SIDE
            kept = len(head) < keep and i == len(head)
            rgb = frame_to_rgb(frame) if kept or not large else None
            linear = linearise(half_rgb(frame) if large else rgb, lut)
            small = cv2.resize(linear, (BLOCK_GRID, BLOCK_GRID), interpolation=cv2.INTER_AREA)
            index.append(i)
            blocks.append(small.reshape(-1, 3))
            brightness.append(float(rgb_to_ycbcr(small)[..., 0].mean()))
            if kept:
                head.append(rgb)
        fps = video.fps
    return Scan(np.array(index), np.array(blocks, dtype=np.float64), np.array(brightness),
                head, fps)


@dataclass
class Corrections:
    """Per-frame corrections of camera B, and their record for the ingest stage."""

    undistort: Undistorter | None
    gains: dict[int, np.ndarray] | None  # frame number -> (3,) gain to divide by
    ambient: np.ndarray | None  # (H, W, 3) linear RGB, corrected units
    lead_end: int | None  # frames numbered below this are the LED-off lead (not samples)
    record: dict

    def linear(self, i: int, rgb: np.ndarray, lut: np.ndarray, video: Path) -> np.ndarray:
        """Corrected linear Y, Cb, Cr ``(H, W, 3)`` float32 of frame ``i``."""
        linear = linearise(rgb, lut)
        if self.undistort is not None:
            self.undistort.check_size(rgb, video)
            linear = self.undistort.apply(linear)
        if self.gains is not None:
            linear = linear / self.gains[i].astype(np.float32)
        if self.ambient is not None:
            linear = linear - self.ambient
        return rgb_to_ycbcr(linear)


def plan_corrections(scan: Scan, lights: Lights, plane: Plane, *,
                     undistort: Undistorter | None, lut: np.ndarray,
                     exposure_locked: bool = False) -> Corrections:
    """Decide the corrections of a scanned video (see the module docstring);
    ``exposure_locked``: the user says camera B's exposure was locked (:func:`_drift_decision`).

    Raises
    ------
    LtmError
        When camera B's gain drifts more than can be corrected, or too uncertainly.
    """
    t = scan.index / scan.fps
    lead = find_lead(scan.brightness, scan.fps)
    lead_end = None if lead is None else int(scan.index[lead.excluded[1] - 1]) + 1
    lit = lights.valid if lead_end is None else lights.valid & (scan.index >= lead_end)
    # A hand's shadow is no change of exposure: the frames ingest rejects as occluded stay out.
    lit = lit & ~occluded_frames(scan.brightness, lights.r, lights.s, lights.z, lit)
    extent = object_guess(plane)
    beam = None if lights.axis is None else beam_log_ratio(
        lights.r, lights.s, lights.z, lights.axis, extent)
    drift = estimate_drift(scan.blocks, t, lights.r, lights.s, lights.z, lit, plane, beam=beam)
    gains, drift_record = _drift_decision(drift, exposure_locked=exposure_locked)
    per_frame = None if gains is None else dict(zip(scan.index.tolist(), gains, strict=True))
    ambient, ambient_record = _ambient(scan, lead, lit, gains, undistort, lut)
    record = {"undistort": None if undistort is None else undistort.to_json(),
              "ambient": ambient_record, "drift": drift_record}
    if beam is not None:
        measured = estimate_beam(_without_room_light(scan.blocks, lead), lights.r, lights.s,
                                 lights.z, lights.axis, lit, plane, extent)
        record["beam"] = _beam_record(measured, lights)
    return Corrections(undistort, per_frame, ambient, lead_end, record)


def _without_room_light(blocks: np.ndarray, lead: Lead | None) -> np.ndarray:
    """Camera B's block means ``(n, B, 3)`` less the room light's, where the LED-off ``lead``
    measured it: a constant added to each block flattens the log brightness's response to
    the beam, and an exponent fitted to it comes out low."""
    if lead is None:
        return blocks
    return blocks - blocks[slice(*lead.ambient)].mean(axis=0)


def _beam_record(measured: tuple[np.ndarray, np.ndarray] | None, lights: Lights) -> dict:
    """The LED's beam: its exponent (``measured`` from the frames per channel, with standard
    errors; the profile's where they cannot tell it to :data:`BEAM_MAX_STDERR`) and the RMS
    tilt of its axis from straight down over the frames the poses cover."""
    estimated = None if measured is None else measured[0]
    k, stderr, source = BEAM_PROFILE_EXPONENT, None, "profile"
    if estimated is not None:
        stderr = float(np.mean(measured[1]))
        # 0: the beam's term was all zeros (the LED held level), which tells nothing of k
        if 0 < stderr <= BEAM_MAX_STDERR:
            k, source = float(np.clip(np.mean(estimated), *BEAM_EXPONENT_RANGE)), "estimated"
    known = np.isfinite(lights.axis).all(axis=1)
    tilt = np.degrees(np.arccos(np.clip(-lights.axis[known, 2], -1, 1)))
    return {"exponent": k, "source": source, "stderr": stderr,
            "exponent_rgb": None if estimated is None else estimated.tolist(),
            "tilt_deg_rms": float(np.sqrt(np.mean(tilt**2))) if tilt.size else None}


def _drift_decision(drift: DriftEstimate | None, *,
                    exposure_locked: bool = False) -> tuple[np.ndarray | None, dict]:
    """Camera B's gains per frame (None: left unchanged) and the record of the decision.

    With ``a`` the RMS log gain of the estimate and ``sigma`` the RMS of its standard error:

    * the frames are refused when the model's misfit exceeds :data:`MAX_DRIFT_RESIDUAL` (no
      fixed exposure explains them: auto exposure);
    * the drift is *significant* when ``a > DRIFT_MIN`` and ``a > DRIFT_SIGMAS * sigma``. The
      estimate is a ridge (smoothness-prior) estimate, whose sampling covariance under no drift
      is at most its posterior covariance, so that ``E[a^2] <= sigma^2``; for a Gaussian
      estimate ``P(a^2 > 16 E[a^2]) <= P(chi2_1 > 16) = 6e-5`` whatever the correlation between
      frames (Szekely and Bakirov 2003: a one-term quadratic form has the heaviest tail beyond
      1.54 times its mean). The misfit's correlation in time is not in ``sigma``: measured
      ``a / sigma`` at most 1.07 on 180 drift-free simulated captures;
    * it *cannot be ruled out and matters* when the data alone do not measure it (median
      data-only standard error above :data:`MAX_DRIFT_STDERR`) and ``a >= DRIFT_MATTERS``;
    * otherwise it is consistent with none (or negligible): the frames are left unchanged.

    A significant drift is corrected where the data measure it and refused where they do not;
    one that cannot be ruled out is refused. Refused either way: a change by more than a factor
    ``exp(MAX_DRIFT_SPAN)``. ``exposure_locked`` (the user's word that camera B was locked)
    leaves a drift the data cannot measure uncorrected instead of refused (the record says so);
    a measured one is corrected either way.
    """
    if drift is None:
        return None, {"judged": False, "reason": "too few lit frames at known positions to judge",
                      "corrected": False}
    amplitude, noise, span = drift.amplitude(), drift.noise(), drift.span()
    determination = drift.determination()
    record = {"judged": True, "rms_log_gain": amplitude, "stderr_log_gain": noise,
              "stderr_data_log_gain": determination, "span_log_gain": span,
              "residual": drift.residual,
              "threshold": max(DRIFT_MIN, DRIFT_SIGMAS * noise)}
    if drift.residual > MAX_DRIFT_RESIDUAL:
        raise LtmError(f"camera B's frames change in a way a fixed exposure cannot explain (RMS "
                       f"misfit {drift.residual:.1%} per frame, expected at most "
                       f"{MAX_DRIFT_RESIDUAL:.0%}: auto exposure?); {LOCK_ADVICE}")
    measurable = determination <= MAX_DRIFT_STDERR
    significant = amplitude > record["threshold"]
    if not significant and (measurable or amplitude < DRIFT_MATTERS):
        return None, {**record, "corrected": False}
    if span > MAX_DRIFT_SPAN:
        raise LtmError(f"camera B's exposure or white balance drifts during the capture (RMS "
                       f"{amplitude:.1%}) and changes by a factor {math.exp(span):.2f}, more "
                       f"than {math.exp(MAX_DRIFT_SPAN):g}; {LOCK_ADVICE}")
    if not measurable:
        if exposure_locked:
            return None, {**record, "corrected": False, "exposure_locked": True}
        raise LtmError(f"camera B's exposure or white balance may drift during the capture (RMS "
                       f"{amplitude:.1%}), and it cannot be measured to better than "
                       f"{determination:.1%} (the light path comes back to the same places too "
                       f"rarely); {LOCK_ADVICE}, or, if they were locked, ingest with "
                       "--exposure-locked")
    gains = np.exp(drift.log_gain)
    lit = drift.lit
    channel_rms = np.sqrt(np.mean(drift.log_gain[lit] ** 2, axis=0))
    return gains, {**record, "corrected": True, "rms_log_gain_rgb": channel_rms.tolist(),
                   "gain_range": [float(gains[lit].min()), float(gains[lit].max())]}


def _ambient(scan: Scan, lead: Lead | None, lit: np.ndarray, gains: np.ndarray | None,
             undistort: Undistorter | None, lut: np.ndarray) -> tuple[np.ndarray | None, dict]:
    if lead is None:
        floor = ambient_floor(scan.blocks, lit)
        record = {"measured": False, "floor_fraction": floor,
                  "note": "no LED-off lead at the start of video B: any room light is part of "
                          "the LTM"}
        if floor is not None and floor > AMBIENT_FLOOR_WARN:
            warnings.warn(f"video B never gets darker than {floor:.0%} of its usual brightness "
                          "and has no LED-off lead: the LTM includes the room light (start "
                          "both recordings with the LED off for a second, or darken the room)",
                          LtmWarning, stacklevel=3)
        return None, record
    frames = [f for k, f in enumerate(scan.head) if lead.ambient[0] <= k < lead.ambient[1]]
    image = ambient_image(frames, lut)
    if undistort is not None:
        image = undistort.apply(image)
    lead_gain = None
    if gains is not None:
        lead_gain = _lead_gain(scan, lead, gains)
        image = image / lead_gain.astype(np.float32)
    return image, {"measured": True, **lead.to_json(), "frames_used": len(frames),
                   "level_rgb": image.reshape(-1, 3).mean(axis=0).tolist(),
                   "lead_gain": None if lead_gain is None else lead_gain.tolist()}


def _lead_gain(scan: Scan, lead: Lead, gains: np.ndarray) -> np.ndarray:
    """Camera B's gain per channel over the ambient frames, in the units of ``gains``.

    The gain is continuous at the step (a camera's exposure control lags the light): the last
    ambient frames have the gain of the first lit frame. Within the lead only the gain changes
    (the room light is steady), so the ambient frames' median over the last ones is the gain's
    change across the lead.
    """
    colour = scan.blocks[slice(*lead.ambient)].mean(axis=1)  # (k, 3)
    last = np.median(colour[-LEAD_TAIL_FRAMES:], axis=0)
    trend = np.divide(np.median(colour, axis=0), last, out=np.ones(3), where=last > 0)
    return gains[lead.excluded[1]] * trend
