"""Light positions from phone A's own video: ``ltm track``.

Per frame: detect the ChArUco board, estimate the camera pose (IPPE on the matched corners,
refined by Levenberg-Marquardt), check it (enough corners, RMS reprojection error, tilt of the
optical axis from the board normal), place the LED at its offset from the camera and express it
in plane coordinates (:meth:`~ltmstore.capture.board.BoardSpec.to_plane`: ``r, s`` from the board
centre, ``z`` the height above the board). Times are the frame timestamps of the video.

Outputs, so that ``ltm ingest`` takes them unchanged:

* ``poses.csv`` (``t,r,s,z,axis_r,axis_s,axis_z``): one row per frame with a trustworthy pose,
  the LED's position and its axis (the camera's optical axis: the LED beside the lens shines
  along it; ingest models the beam about it). Frames without one are
  left out, never interpolated here. Frames whose LED is off the plane height are kept: they are
  measurements, and ingest rejects them with its z tolerance.
* ``<poses>.frames.csv`` beside it: every frame with its status (``ok``, ``no_board``,
  ``poor_pose``, ``tilted``, ``out_of_plane``), corner count, reprojection error and tilt.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import write_text_atomic
from ltmstore.capture.board import MIN_CORNERS, BoardDetector, BoardSpec, video_frames
from ltmstore.capture.calibrate import Intrinsics
from ltmstore.core.errors import LtmError
from ltmstore.core.paths import check_output

MAX_REPROJECTION_PX = 1.5  # RMS, at 1280 px wide (scaled with the image width)
MAX_TILT_DEG = 20.0
Z_TOLERANCE_FRACTION = 0.05  # as ingest: of the plane height
MIN_TRACKED_FRACTION = 0.2
STATUSES = ("ok", "no_board", "poor_pose", "tilted", "out_of_plane")
WRITTEN = ("ok", "out_of_plane")  # statuses of the frames written to poses.csv


@dataclass(frozen=True)
class TrackConfig:
    """Checks applied to every frame's pose.

    Attributes
    ----------
    led_offset : (float, float, float)
        LED position in the camera frame (x right, y down, z along the optical axis), metres.
    max_reprojection_px : float
        Largest RMS reprojection error of a pose, pixels at 1280 px wide.
    max_tilt_deg : float
        Largest angle between the optical axis and the board normal.
    height : float, optional
        Plane height; default the median LED height of the good frames.
    z_tolerance : float, optional
        Largest ``|z - height|``; default 5 % of the height (as ingest).
    min_corners : int
        Fewest ChArUco corners for a pose.
    """

    led_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_reprojection_px: float = MAX_REPROJECTION_PX
    max_tilt_deg: float = MAX_TILT_DEG
    height: float | None = None
    z_tolerance: float | None = None
    min_corners: int = MIN_CORNERS


@dataclass(frozen=True)
class FramePose:
    """One frame's result: LED in plane coordinates (NaN when no pose) and diagnostics;
    ``axis``: the direction the camera, and so the LED beside it, points (unit, plane
    coordinates; NaN when no pose)."""

    t: float
    led: np.ndarray
    corners: int
    reprojection_px: float
    tilt_deg: float
    status: str
    axis: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))


def estimate_pose(obj: np.ndarray, img: np.ndarray,
                  intr: Intrinsics) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Board-to-camera rotation, translation and RMS reprojection error (pixels), or None.

    IPPE (planar) gives both candidate poses; the better is refined by Levenberg-Marquardt.
    """
    obj = np.ascontiguousarray(obj, np.float64)
    img = np.ascontiguousarray(img, np.float64)
    try:
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, intr.matrix, intr.distortion,
                                                    flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return None
    if not n:
        return None
    best = int(np.argmin(np.ravel(errs)))
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, intr.matrix, intr.distortion,
                                      rvecs[best].copy(), tvecs[best].copy())
    proj, _ = cv2.projectPoints(obj, rvec, tvec, intr.matrix, intr.distortion)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), rms


def camera_led(r_co: np.ndarray, t: np.ndarray, led_offset,
               normal_sign: float = 1.0) -> tuple[np.ndarray, float]:
    """LED position in the target's own coordinates and the tilt of the optical axis
    (its direction there: ``r_co[2]``, the camera's ``z`` axis, along which the LED shines).

    Parameters
    ----------
    r_co, t : ndarray
        Target-to-camera rotation (3, 3) and translation (3,).
    led_offset : (float, float, float)
        LED in camera axes, metres.
    normal_sign : float
        ``+1`` when the target's ``z`` axis points away from the camera (a board: into the
        page), ``-1`` when it points towards it (plane coordinates: ``z`` above the plane).

    Returns
    -------
    (ndarray, float)
        LED in target coordinates and the tilt (degrees) of the optical axis from the normal.
    """
    centre = -r_co.T @ t
    led = centre + r_co.T @ np.asarray(led_offset, np.float64)
    tilt = float(np.degrees(np.arccos(np.clip(normal_sign * r_co[2, 2], -1.0, 1.0))))
    return led, tilt


def led_position(spec: BoardSpec, r_cb: np.ndarray, t: np.ndarray,
                 led_offset) -> tuple[np.ndarray, float, np.ndarray]:
    """LED in plane coordinates, the tilt (degrees) of the optical axis from the normal and
    the axis's direction in plane coordinates."""
    led_board, tilt = camera_led(r_cb, t, led_offset)
    led = spec.to_plane(led_board)
    return led, tilt, spec.to_plane(led_board + r_cb[2]) - led


def checked_pose(t: float, led: np.ndarray, points: int, rms: float, tilt: float,
                 intr: Intrinsics, config: TrackConfig,
                 axis: np.ndarray | None = None) -> FramePose:
    """A frame's pose with its status from the reprojection and tilt limits (``ok``,
    ``poor_pose`` or ``tilted``; ``out_of_plane`` is decided over the whole video)."""
    limit = config.max_reprojection_px * intr.image_size[0] / 1280
    status = "poor_pose" if rms > limit else "tilted" if tilt > config.max_tilt_deg else "ok"
    return FramePose(t, led, points, rms, tilt, status,
                     np.full(3, np.nan) if axis is None else np.asarray(axis, float))


def track_frame(detector: BoardDetector, gray: np.ndarray, t: float, intr: Intrinsics,
                config: TrackConfig) -> FramePose:
    """Detect, estimate and check one frame (``out_of_plane`` is decided later)."""
    nan = np.full(3, np.nan)
    obj, img, _ = detector.detect(gray)
    if len(obj) < config.min_corners:
        return FramePose(t, nan, len(obj), np.nan, np.nan, "no_board")
    pose = estimate_pose(obj, img, intr)
    if pose is None:
        return FramePose(t, nan, len(obj), np.nan, np.nan, "poor_pose")
    r_cb, tvec, rms = pose
    led, tilt, axis = led_position(detector.spec, r_cb, tvec, config.led_offset)
    return checked_pose(t, led, len(obj), rms, tilt, intr, config, axis)


def check_frame_size(gray: np.ndarray, intr: Intrinsics, what: str) -> None:
    """Refuse a frame (of ``what``, e.g. ``"video A 'a.mp4'"``) whose size is not the
    intrinsics' image size."""
    if tuple(gray.shape[::-1]) != tuple(intr.image_size):
        raise LtmError(f"{what} is {gray.shape[1]}x{gray.shape[0]} but the "
                       f"intrinsics are for {intr.image_size[0]}x{intr.image_size[1]}; "
                       "expected intrinsics calibrated for this camera and resolution")


def enough_posed(results: list[FramePose]) -> bool:
    """Whether at least :data:`MIN_TRACKED_FRACTION` of the frames (and 2) have a good pose."""
    good = sum(r.status == "ok" for r in results)
    return good >= max(2, MIN_TRACKED_FRACTION * len(results))


def track_video(video: str | os.PathLike, spec: BoardSpec, intr: Intrinsics,
                config: TrackConfig, *, progress: bool = True) -> list[FramePose]:
    """Track every frame of phone A's video.

    Raises
    ------
    LtmError
        If the video's frame size differs from the intrinsics' image size, or the board is
        found in fewer than :data:`MIN_TRACKED_FRACTION` of the frames.
    """
    detector = BoardDetector(spec)
    results = []
    for i, t, gray in video_frames(video, what="video A", progress=progress, desc="track"):
        if i == 0:
            check_frame_size(gray, intr, f"video A {str(video)!r}")
        results.append(track_frame(detector, gray, t, intr, config))
    if not enough_posed(results):
        good = sum(r.status == "ok" for r in results)
        found = sum(r.status != "no_board" for r in results)
        raise LtmError(f"board {spec.squares[0]}x{spec.squares[1]} ({spec.dictionary}) found in "
                       f"{found} and posed in {good} of {len(results)} frames of video A "
                       f"{str(video)!r}; expected it in view in at least "
                       f"{MIN_TRACKED_FRACTION:.0%} of the frames (wrong --board spec, or board "
                       "not in view?)")
    return flag_out_of_plane(results, config)


def flag_out_of_plane(results: list[FramePose], config: TrackConfig) -> list[FramePose]:
    """Flag the good frames whose LED is off the plane height (``config.height``, default the
    median of the good frames) by more than the tolerance as ``out_of_plane``."""
    z = np.array([r.led[2] for r in results if r.status == "ok"])
    height = float(np.median(z)) if config.height is None else float(config.height)
    tol = Z_TOLERANCE_FRACTION * abs(height) if config.z_tolerance is None else config.z_tolerance
    return [replace(r, status="out_of_plane")
            if r.status == "ok" and abs(r.led[2] - height) > tol else r for r in results]


def frames_path(out: str | os.PathLike) -> Path:
    """The per-frame tracking file written beside the poses file ``out``."""
    out = Path(out)
    return out.with_name(out.stem + ".frames.csv")


def write_tracks(out: str | os.PathLike, results: list[FramePose], *,
                 count_column: str = "corners") -> dict:
    """Write ``poses.csv`` (good and out-of-plane frames) and ``<stem>.frames.csv`` (all).

    ``count_column`` names the per-frame point count (board corners, painting matches). Both
    are written beside and moved into place, so a failure leaves no half-written file.
    """
    out = Path(out)
    frames_csv = frames_path(out)
    keep = [r for r in results if r.status in WRITTEN]
    with_axis = bool(keep) and all(np.isfinite(r.axis).all() for r in keep)
    rows = "".join(f"{r.t:.6f},{r.led[0]:.7f},{r.led[1]:.7f},{r.led[2]:.7f}"
                   + ("".join(f",{v:.7f}" for v in r.axis) if with_axis else "") + "\n"
                   for r in keep)
    detail = "".join(f"{i},{r.t:.6f},{r.led[0]:.7f},{r.led[1]:.7f},{r.led[2]:.7f},{r.corners},"
                     f"{r.reprojection_px:.4f},{r.tilt_deg:.3f},{r.status}\n"
                     for i, r in enumerate(results))
    header = "t,r,s,z" + (",axis_r,axis_s,axis_z" if with_axis else "")
    write_text_atomic(out, header + "\n" + rows, what="poses")
    write_text_atomic(frames_csv, f"frame,t,r,s,z,{count_column},reprojection_px,tilt_deg,"
                      "status\n" + detail, what="per-frame tracking")
    return {"poses": str(out), "frames_csv": str(frames_csv)}


def refuse_existing(out: str | os.PathLike, overwrite: bool,
                    inputs: tuple = ()) -> Path:
    """``out`` as a path, refused when it exists and ``overwrite`` is not set, or when it or
    the per-frame file beside it is, lies in or holds one of ``inputs`` (the video)."""
    out = Path(out)
    for path in (out, frames_path(out)) if out.name else (out,):
        check_output(path, inputs)
    if out.exists() and not overwrite:
        raise LtmError(f"output {str(out)!r} already exists; pass --overwrite to replace it")
    return out


def save_tracks(out: Path, results: list[FramePose], statuses: tuple[str, ...], *,
                count_column: str = "corners") -> dict:
    """Write the poses files (:func:`write_tracks`) and summarise the tracking.

    Returns
    -------
    dict
        ``frames``, ``rows`` (written to ``out``), ``status`` counts, ``height`` (median LED
        height), ``reprojection_px`` (median and 95th percentile), the median point count
        (``count_column``), ``longest_gap_s`` between written rows, and the paths.
    """
    paths = write_tracks(out, results, count_column=count_column)
    kept = [r for r in results if r.status in WRITTEN]
    t = np.array([r.t for r in kept])
    rms = np.array([r.reprojection_px for r in kept])
    return {"frames": len(results), "rows": len(kept),
            "status": {s: sum(r.status == s for r in results) for s in statuses},
            "height": float(np.median([r.led[2] for r in kept])),
            "reprojection_px": {"median": float(np.median(rms)),
                                "p95": float(np.percentile(rms, 95))},
            count_column: float(np.median([r.corners for r in kept])),
            "longest_gap_s": float(np.diff(t).max()) if len(t) > 1 else 0.0, **paths}


def track(video: str | os.PathLike, spec: BoardSpec, intr: Intrinsics, out: str | os.PathLike,
          *, config: TrackConfig, overwrite: bool = False, progress: bool = True) -> dict:
    """Track phone A's video and write the poses (see the module docstring).

    Parameters
    ----------
    video : path
        Phone A's video.
    spec : BoardSpec
        The board in the object plane.
    intr : Intrinsics
        Phone A's camera calibration (for the video's resolution).
    out : path
        ``poses.csv`` to write.
    config : TrackConfig
        LED offset and the pose checks.
    overwrite : bool
        Replace an existing ``out``.
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        As :func:`save_tracks` (``corners``: the median corner count).
    """
    out = refuse_existing(out, overwrite, inputs=(video,))
    results = track_video(video, spec, intr, config, progress=progress)
    return save_tracks(out, results, STATUSES)
