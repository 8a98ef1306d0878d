"""Boardless tracking: phone A's pose from the painting itself (``ltm track --painting``).

Phone A films the painting it lights. A *map* of the painting (a front-on picture cropped to the
painting's edges, or camera B's rectified video, whose per-pixel median is taken) and the
painting's width in metres fix the plane coordinates: origin at the painting's centre, ``r`` to
the right, ``s`` up the picture, ``z`` above the plane (metres).

Per frame (:meth:`PaintingTracker.track_frame`):

1. undistort with the intrinsics, shrink to a working width (640 px) and normalise the local
   contrast (local mean and standard deviation), which removes the LED's fall-off; saturated
   pixels (the LED's highlight) are masked;
2. predict the pose from the last two poses (constant velocity); render the map as the
   predicted pose would see it (smeared over the open shutter by the phone's motion, when the
   shutter time is known or estimated: :func:`estimate_shutter`), normalise it over the same
   working pixels as the frame, and track corners of that rendering into the frame (pyramidal
   Lucas-Kanade, forward-backward checked), twice, each from the last estimate;
3. without a prediction, or where it fails, match SIFT features of the frame against the
   map's (computed once at a few scales; ratio test; RANSAC homography: OpenCV 5.0's
   ``USAC_MAGSAC`` returns no homography at all here) and refine as in 2;
4. fit the pose to the inlying plane points (IPPE, Levenberg-Marquardt: the same pose code and
   checks as the board tracker, :mod:`ltmstore.capture.track`), place the LED at its offset.

Frames where the painting cannot be placed get the status ``no_painting``; ``poor_pose`` when
the fit is off or leaves the LED uncertain by more than 2 mm (:func:`led_sigma`: a sliver of
the painting at the frame's edge); ``tilted`` as the board tracker. They are left out of
``poses.csv`` and counted in ``poses.frames.csv``, never guessed.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.board import video_frames
from ltmstore.capture.calibrate import Intrinsics
from ltmstore.capture.track import (
    MIN_TRACKED_FRACTION,
    FramePose,
    TrackConfig,
    camera_led,
    check_frame_size,
    checked_pose,
    enough_posed,
    estimate_pose,
    flag_out_of_plane,
    refuse_existing,
    save_tracks,
)
from ltmstore.capture.undistort import Undistorter
from ltmstore.core.errors import LtmError

STATUSES = ("ok", "no_painting", "poor_pose", "tilted", "out_of_plane")
WIDTH_RANGE_M = (0.02, 20.0)  # a painting's plausible width
HEIGHT_RANGE_M = (0.03, 3.0)  # plausible LED heights over the painting
MAP_FRAMES = 30  # frames of camera B's video whose median is the map
MIN_MAP_FEATURES = 30
WORK_WIDTH = 640  # frames are matched at this width (pixels)
NORMALISE_SIGMA = 6.0  # local contrast window, working pixels
NOISE_FLOOR = 3.0  # grey levels: local contrast below this is not amplified
SATURATED = 250
MIN_POINTS = 20  # fewest inlying points for a pose
MAX_LED_SIGMA_M = 0.002  # the fit's own LED uncertainty above this: poor_pose
MAX_GAP_S = 0.3  # longer without a pose: search the whole map again
RATIO = 0.8  # Lowe's ratio test
LK_WINDOW = 21
LK_LEVELS = 3
FB_MAX_PX = 0.5  # forward-backward disagreement of a tracked point, working pixels
HEIGHTS_M = (0.18, 0.3, 0.5)  # camera heights the map's features are computed for
SHUTTERS_S = (0.0, 1 / 480, 1 / 240, 1 / 120, 1 / 60)  # open-shutter times tried (auto)
SHUTTER_FRAMES = 24  # the fastest-moving placed frames that choose among them
BLUR_SAMPLES = 7  # instants of the open shutter averaged into a smeared rendering of the map
RS_PASSES = 2  # later passes over a video whose rolling shutter is corrected (velocities from
# the previous pass's poses on both sides of each frame)


def check_width(width: float) -> float:
    """The painting width in metres, or a one-line error when it cannot be one."""
    try:
        width = float(width)
    except (TypeError, ValueError):
        raise LtmError(f"painting width {width!r} is not a number; expected metres") from None
    if not (math.isfinite(width) and width > 0):
        raise LtmError(f"painting width {width!r} must be a positive number of metres")
    lo, hi = WIDTH_RANGE_M
    if not lo <= width <= hi:
        raise LtmError(f"painting width {width:g} m is implausible; expected the width in "
                       f"metres, {lo:g}-{hi:g} (e.g. 0.4 for 40 cm)")
    return width


@dataclass(frozen=True, eq=False)
class PaintingMap:
    """The painting seen front-on, cropped to its edges, and its width.

    Attributes
    ----------
    image : ndarray (h, w) uint8
        Grey picture of the painting, image up = ``s`` up.
    width : float
        Width of the painting (of ``image``), metres.
    """

    image: np.ndarray
    width: float

    def __post_init__(self) -> None:
        check_width(self.width)
        img = np.asarray(self.image)
        if img.ndim != 2 or img.dtype != np.uint8 or min(img.shape) < 32:
            raise LtmError(f"painting map of shape {img.shape} ({img.dtype}) must be a grey "
                           "uint8 image of at least 32 x 32 pixels")

    @property
    def height(self) -> float:
        """Height of the painting, metres (from the map's aspect ratio)."""
        return self.width * self.image.shape[0] / self.image.shape[1]

    @property
    def px_per_m(self) -> float:
        return self.image.shape[1] / self.width

    def plane_to_map(self, scale: float = 1.0) -> np.ndarray:
        """3 x 3 homography from plane ``(r, s, 1)`` to map pixels (at ``scale`` x the map)."""
        k = self.px_per_m * scale
        return np.array([[k, 0, k * self.width / 2 - 0.5], [0, -k, k * self.height / 2 - 0.5],
                         [0, 0, 1]])

    @classmethod
    def from_image(cls, path: str | os.PathLike, width: float) -> PaintingMap:
        """Read a picture (PNG, JPEG, ...) of the painting, front-on and cropped to it."""
        path = Path(path)
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
        if image is None:
            raise LtmError(f"painting map {str(path)!r} is not an image OpenCV can read; "
                           "expected a PNG or JPEG of the painting, front-on and cropped")
        return cls(image, check_width(width))

    @classmethod
    def from_video(cls, path: str | os.PathLike, width: float, intrinsics: Intrinsics | None = None,
                   frames: int = MAP_FRAMES) -> PaintingMap:
        """The per-pixel median of ``frames`` evenly spaced frames of camera B's video.

        Parameters
        ----------
        path : path
            Camera B's video (its frame shows exactly the painting).
        width : float
            The painting's width, metres.
        intrinsics : Intrinsics, optional
            Camera B's calibration (``ltm calibrate``): each frame's lens distortion is undone
            (onto the same camera matrix) before the median.
        frames : int
            How many frames the median takes.

        Raises
        ------
        LtmError
            If the video's frame size is not the intrinsics' image size.
        """
        check_width(width)
        count = _frame_count(path)
        keep = set(np.linspace(0, count - 1, min(frames, count)).round().astype(int).tolist())
        undo = _map_undistorter(intrinsics, path)
        picked = [undo(g) for i, _t, g in video_frames(path, what="painting map video")
                  if i in keep]
        median = np.median(np.stack(picked), axis=0)  # bicubic: may overshoot 0..255
        return cls(median.round().clip(0, 255).astype(np.uint8), width)

    @classmethod
    def load(cls, path: str | os.PathLike, width: float,
             intrinsics: Intrinsics | None = None) -> PaintingMap:
        """An image (PNG/JPEG) or a video, whichever ``path`` is (``intrinsics``: camera B's
        calibration, for a video only, :meth:`from_video`)."""
        path = Path(path)
        if not path.is_file():
            raise LtmError(f"painting map {str(path)!r} does not exist")
        check_width(width)
        if cv2.haveImageReader(str(path)):
            if intrinsics is not None:
                raise LtmError(f"painting map {str(path)!r} is an image: camera B's intrinsics "
                               "go with a map made from camera B's video, not with a picture "
                               "already front-on and cropped")
            return cls.from_image(path, width)
        if not cv2.VideoCapture(str(path)).isOpened():
            raise LtmError(f"painting map {str(path)!r} is neither an image nor a video "
                           "OpenCV can read; expected a PNG/JPEG of the painting front-on "
                           "and cropped to it, or camera B's video")
        return cls.from_video(path, width, intrinsics)


def _map_undistorter(intr: Intrinsics | None, path: str | os.PathLike):
    """A function undoing camera B's lens distortion on a grey frame of ``path`` (identity
    without ``intr``); it refuses a frame of another size than the calibration's."""
    if intr is None:
        return lambda gray: gray
    undistorter = Undistorter(intr, "--painting-intrinsics")

    def undo(gray: np.ndarray) -> np.ndarray:
        undistorter.check_size(gray, Path(path), what="painting map video")
        return undistorter.apply(gray)

    return undo


def _frame_count(path: str | os.PathLike) -> int:
    cap = cv2.VideoCapture(str(path))
    count = int(max(cap.get(cv2.CAP_PROP_FRAME_COUNT), 0)) if cap.isOpened() else 0
    cap.release()
    return count or sum(1 for _ in video_frames(path, what="painting map video"))


def normalise(gray: np.ndarray, sigma: float | None = None) -> np.ndarray:
    """Local contrast normalisation to uint8: (I - local mean) / local deviation over a
    Gaussian window (``sigma`` pixels, default :data:`NORMALISE_SIGMA`), so that the LED's
    smooth fall-off and exposure changes vanish; flat noise stays near grey."""
    sigma = NORMALISE_SIGMA if sigma is None else sigma
    g = np.asarray(gray, np.float32)
    d = g - cv2.GaussianBlur(g, (0, 0), sigma)
    sd = np.sqrt(cv2.GaussianBlur(d * d, (0, 0), sigma))
    return np.clip(128 + 40 * d / (sd + NOISE_FLOOR), 0, 255).astype(np.uint8)


class PaintingTracker:
    """Phone A's pose, frame by frame, against a :class:`PaintingMap`.

    The tracker keeps the last poses between calls (its motion model), so call
    :meth:`track_frame` with the frames in time order; :meth:`reset` forgets them.

    Parameters
    ----------
    painting : PaintingMap
        The painting and its width.
    intr : Intrinsics
        Phone A's calibration (its ``dist_coeffs`` are undone).
    config : TrackConfig
        LED offset and the pose checks (as the board tracker).
    readout_s : float
        Rolling-shutter readout time of phone A's video, top row to bottom row, seconds
        (phones: 0.02-0.03 s; 0: a global shutter, no correction).
    shutter_s : float
        Open-shutter time, seconds (0: sharp frames). Where the camera moves, the map is
        rendered smeared over it, as the frame is (motion blur).
    """

    def __init__(self, painting: PaintingMap, intr: Intrinsics,
                 config: TrackConfig | None = None, *, readout_s: float = 0.0,
                 shutter_s: float = 0.0) -> None:
        self.map, self.intr, self.config = painting, intr, config or TrackConfig()
        self.readout_s, self.shutter_s, self._t = float(readout_s), float(shutter_s), 0.0
        w, h = intr.image_size
        self.k = min(1.0, WORK_WIDTH / w)
        self.work_size = (round(w * self.k), round(h * self.k))
        c = 0.5 * self.k - 0.5  # pixel centres: x' + 0.5 = k (x + 0.5)
        self.to_work = np.array([[self.k, 0, c], [0, self.k, c], [0, 0, 1]])
        self.matrix_work = self.to_work @ intr.matrix
        self._undistort = None
        if np.any(np.asarray(intr.distortion) != 0):
            self._undistort = cv2.initUndistortRectifyMap(intr.matrix, intr.distortion, None,
                                                          intr.matrix, (w, h), cv2.CV_16SC2)
        self._levels = self._pyramid()
        self._sift = cv2.SIFT_create(nfeatures=1500)
        self._map_xy, self._map_desc = self._map_features()
        self._matcher = cv2.BFMatcher(cv2.NORM_L2)
        self._history: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._motion: tuple[np.ndarray, np.ndarray] | None = None
        self.camera: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the motion model (the next frame is searched over the whole map)."""
        self._history = []

    # -- the map -----------------------------------------------------------------------------

    def _pyramid(self) -> list[tuple[float, np.ndarray]]:
        """(scale, image) of the map, halving down to the coarsest useful size."""
        img = self.map.image
        levels = [(1.0, img)]
        need = self.matrix_work[0, 0] / max(HEIGHTS_M) / 2  # px/m at the highest camera, / 2
        scale = 1.0
        while self.map.px_per_m * scale / 2 >= need and min(img.shape) >= 64:
            img = cv2.pyrDown(img)
            scale = img.shape[1] / self.map.image.shape[1]
            levels.append((scale, img))
        return levels

    def _map_features(self) -> tuple[np.ndarray, np.ndarray]:
        """SIFT keypoints (plane r, s) and descriptors of the map at the scales a camera at
        :data:`HEIGHTS_M` sees it."""
        xy, desc = [], []
        scales = {round(min(1.0, self.matrix_work[0, 0] / h / self.map.px_per_m), 2)
                  for h in HEIGHTS_M}  # once each: a repeated feature would fail the ratio test
        for scale in sorted(scales):
            img = self.map.image if scale == 1.0 else cv2.resize(
                self.map.image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            kp, d = self._sift.detectAndCompute(normalise(img), None)
            if d is None:
                continue
            px = np.array([k.pt for k in kp], np.float64).reshape(-1, 2)
            xy.append(_apply(np.linalg.inv(self.map.plane_to_map(scale)), px))
            desc.append(d)
        n = sum(len(d) for d in desc)
        if n < MIN_MAP_FEATURES:
            raise LtmError(f"painting map has {n} features to match (expected at least "
                           f"{MIN_MAP_FEATURES}): too little texture to track; use --board for "
                           "a textureless object")
        return np.concatenate(xy), np.concatenate(desc)

    # -- one frame ---------------------------------------------------------------------------

    def track_frame(self, gray: np.ndarray, t: float,
                    motion: tuple[np.ndarray, np.ndarray] | None = None) -> FramePose:
        """Place the LED for one grey frame at time ``t`` (seconds), in time order.

        ``motion``: the camera's velocity (m/s) and angular velocity (rad/s, world axes) at
        ``t`` for the rolling-shutter correction, when known better than from the last pose
        (:func:`track_painting_video`'s later passes). After the call, :attr:`camera` holds the
        frame's camera pose (rotation world to camera, translation), None when not placed.

        Returns
        -------
        FramePose
            ``corners`` holds the number of inlying painting points; ``status`` is ``ok``,
            ``no_painting``, ``poor_pose`` or ``tilted`` (``out_of_plane`` is decided over the
            whole video, :func:`ltmstore.capture.track.flag_out_of_plane`).

        Raises
        ------
        LtmError
            If the frame's size is not the intrinsics' image size.
        """
        check_frame_size(gray, self.intr, "phone A's frame")
        self._t, self._motion, self.camera = t, motion, None
        frame, valid = self._prepare(gray)
        guess = self._predict(t)
        found = self._refine(frame, valid, *guess) if guess is not None else None
        if found is None:
            guess = self._search(frame, valid)
            found = self._refine(frame, valid, *guess) if guess is not None else None
        if found is None:
            return FramePose(t, np.full(3, np.nan), 0, np.nan, np.nan, "no_painting")
        r_co, tvec, rms, sigma, n = found
        led, tilt = camera_led(r_co, tvec, self.config.led_offset, normal_sign=-1.0)
        pose = checked_pose(t, led, n, rms, tilt, self.intr, self.config, r_co[2])
        if pose.status == "ok" and sigma > MAX_LED_SIGMA_M:
            pose = replace(pose, status="poor_pose")
        if pose.status in ("ok", "tilted"):
            self._history = [*self._history[-1:], (t, r_co, tvec)]
            self.camera = (r_co, tvec)
        return pose

    def refit_error(self, gray: np.ndarray, t: float, motion: tuple[np.ndarray, np.ndarray],
                    pose: tuple[np.ndarray, np.ndarray]) -> float:
        """RMS reprojection error (pixels) of a frame refined from a known camera pose and
        motion (:meth:`track_frame`'s refinement without its prediction or search; the motion
        model is left as it was); infinite where it cannot be placed."""
        self._t, self._motion = t, motion
        try:
            found = self._refine(*self._prepare(gray), *pose)
        finally:
            self._motion = None
        return math.inf if found is None else float(found[2])

    def _prepare(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted, working-size, normalised frame and its mask of usable pixels."""
        if self._undistort is not None:
            gray = cv2.remap(gray, *self._undistort, cv2.INTER_LINEAR)
        if self.k != 1.0:
            gray = cv2.resize(gray, self.work_size, interpolation=cv2.INTER_AREA)
        valid = (gray < SATURATED).astype(np.uint8)
        valid = cv2.erode(valid, np.ones((7, 7), np.uint8))
        return normalise(gray), valid

    def _predict(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The pose at ``t`` from the last two (constant velocity), or None."""
        if not self._history or t - self._history[-1][0] > MAX_GAP_S:
            return None
        t1, r1, tv1 = self._history[-1]
        if len(self._history) == 1 or t <= t1:
            return r1, tv1
        t0, r0, tv0 = self._history[0]
        a = (t - t1) / max(t1 - t0, 1e-6)
        rot = cv2.Rodrigues(cv2.Rodrigues(r1 @ r0.T)[0] * a)[0] @ r1
        c0, c1 = -r0.T @ tv0, -r1.T @ tv1
        return rot, -rot @ (c1 + a * (c1 - c0))

    def _search(self, frame: np.ndarray,
                valid: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """A pose from SIFT matches of the whole map (ratio test, MAGSAC homography), or None."""
        kp, desc = self._sift.detectAndCompute(frame, valid)
        if desc is None or len(kp) < MIN_POINTS:
            return None
        pairs = self._matcher.knnMatch(desc, self._map_desc, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < RATIO * p[1].distance]
        if len(good) < MIN_POINTS:
            return None
        img = np.array([kp[m.queryIdx].pt for m in good], np.float64)
        obj = self._map_xy[[m.trainIdx for m in good]]
        h, inl = cv2.findHomography(obj, img, cv2.RANSAC, 2.0, maxIters=2000)
        if h is None or int(inl.sum()) < MIN_POINTS:
            return None
        keep = inl.ravel().astype(bool)
        pose = self._fit(obj[keep], img[keep])
        return None if pose is None else pose[:2]

    def _fit(self, obj: np.ndarray, img_work: np.ndarray):
        """Pose (rotation, translation, RMS px) from plane points and working-pixel image points
        (undistorted), with the LED's standard deviation (:func:`led_sigma`), or None."""
        full = (img_work + 0.5) / self.k - 0.5
        obj3 = np.column_stack([obj, np.zeros(len(obj))])
        pose = estimate_pose(obj3, full, Intrinsics(self.intr.image_size, self.intr.matrix,
                                                    np.zeros(5)))
        if pose is None:
            return None
        return *pose, led_sigma(obj3, *pose, self.intr.matrix, self.config.led_offset)

    def _refine(self, frame: np.ndarray, valid: np.ndarray, r_co: np.ndarray,
                tvec: np.ndarray):
        """Render the map at the guessed pose, track its corners into the frame, refit; twice.
        Returns (rotation, translation, RMS px, LED sigma m, inliers) or None."""
        for _ in range(2):
            step = self._track_points(frame, valid, r_co, tvec)
            if step is None or step[0] is None:
                return None
            (r_co, tvec, rms, sigma), n = step
            if tvec[2] <= 0:
                return None
        return r_co, tvec, rms, sigma, n

    def _track_points(self, frame: np.ndarray, valid: np.ndarray, r_co: np.ndarray,
                      tvec: np.ndarray):
        plane_to_work = self.matrix_work @ np.column_stack([r_co[:, 0], r_co[:, 1], tvec])
        scale, level = self._level(tvec[2])
        h = plane_to_work @ np.linalg.inv(self.map.plane_to_map(scale))
        view = self._render(level, scale, h, r_co, tvec)
        inside = cv2.warpPerspective(np.ones(level.shape, np.uint8), h, self.work_size,
                                     flags=cv2.INTER_NEAREST, borderValue=0)
        mask = cv2.erode(inside, np.ones((9, 9), np.uint8)) & valid
        pts = cv2.goodFeaturesToTrack(view, 400, 0.01, 7, mask=mask, blockSize=7)
        if pts is None or len(pts) < MIN_POINTS:
            return None
        lk = {"winSize": (LK_WINDOW, LK_WINDOW), "maxLevel": LK_LEVELS}
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(view, frame, pts, None, **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(frame, view, nxt, None, **lk)
        ok = (st.ravel() == 1) & (st2.ravel() == 1) & (
            np.linalg.norm((back - pts).reshape(-1, 2), axis=1) < FB_MAX_PX)
        if ok.sum() < MIN_POINTS:
            return None
        src = pts.reshape(-1, 2)[ok].astype(np.float64)
        dst = nxt.reshape(-1, 2)[ok].astype(np.float64)
        obj = _apply(np.linalg.inv(plane_to_work), src)
        dst = self._unroll(obj, dst, r_co, tvec)
        hom, inl = cv2.findHomography(obj, dst, cv2.RANSAC, 1.0, maxIters=500)
        if hom is None or int(inl.sum()) < MIN_POINTS:
            return None
        keep = inl.ravel().astype(bool)
        return self._fit(obj[keep], dst[keep]), int(keep.sum())

    def _unroll(self, obj: np.ndarray, img_work: np.ndarray, r_co: np.ndarray,
                tvec: np.ndarray) -> np.ndarray:
        """Rolling shutter: move each image point to where the camera at the frame's time
        (the middle row's) would have seen it, from the phone's velocity since the last pose.

        Sensor row ``y`` (of the raw, distorted frame: the sensor reads its rows, top first) is
        read ``readout_s * (y / (h - 1) - 0.5)`` after the frame's time, the convention of the
        simulator (:meth:`ltmstore.synthetic.phone_view.PhoneView.row_times`). A phone that
        stamps its frames at the first row's read instead shifts every pose's time by
        ``readout_s / 2``, a constant that ``ltm sync`` absorbs into the clock offset."""
        motion = self._velocity(r_co, tvec) if self.readout_s > 0 else None
        if motion is None:
            return img_work
        (v, w), c = motion, -r_co.T @ tvec
        full = (img_work + 0.5) / self.k - 0.5
        delta = self.readout_s * (self._sensor_row(full) / (self.intr.image_size[1] - 1) - 0.5)
        rel = np.column_stack([obj, np.zeros(len(obj))]) - c
        moved = rel - delta[:, None] * (v + np.cross(w, rel))
        shift = _project(self.intr.matrix, r_co, moved) - _project(self.intr.matrix, r_co, rel)
        return img_work - self.k * shift

    def _velocity(self, r_co: np.ndarray, tvec: np.ndarray):
        """The camera's velocity and angular velocity at this frame (from the later passes'
        centred estimate, else since the last pose), or None."""
        if self._motion is not None:
            return self._motion
        if self._history and 0 < self._t - self._history[-1][0] <= MAX_GAP_S:
            t1, r1, tv1 = self._history[-1]
            return camera_motion(t1, (r1, tv1), self._t, (r_co, tvec))
        return None

    def _render(self, level: np.ndarray, scale: float, h: np.ndarray, r_co: np.ndarray,
                tvec: np.ndarray) -> np.ndarray:
        """The map level as the camera at this pose sees it (``h``: map to working pixels),
        smeared as the open shutter smears it where the camera moves (motion blur), then
        normalised as the frame is, over the same working pixels."""
        motion = self._velocity(r_co, tvec) if self.shutter_s > 0 else None
        if motion is None:
            return normalise(cv2.warpPerspective(level, h, self.work_size, flags=cv2.INTER_LINEAR,
                                                 borderMode=cv2.BORDER_REPLICATE))
        (v, w), c = motion, -r_co.T @ tvec
        hh, ww = level.shape
        corners = np.array([[0, 0], [ww, 0], [ww, hh], [0, hh]], np.float64) - 0.5
        rel = np.column_stack([_apply(np.linalg.inv(self.map.plane_to_map(scale)), corners),
                               np.zeros(4)]) - c
        acc = np.zeros(self.work_size[::-1], np.float32)
        offsets = self.shutter_s * (np.arange(BLUR_SAMPLES) / (BLUR_SAMPLES - 1) - 0.5)
        for dt in offsets:
            moved = _project(self.matrix_work, r_co, rel - dt * (v + np.cross(w, rel)))
            hd = cv2.getPerspectiveTransform(corners.astype(np.float32),
                                             moved.astype(np.float32))
            acc += cv2.warpPerspective(level, hd, self.work_size, flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
        return normalise(acc / len(offsets))

    def _sensor_row(self, full: np.ndarray) -> np.ndarray:
        """Row on the sensor (lens distortion applied) of undistorted full-size pixels."""
        if self._undistort is None:
            return full[:, 1]
        ray = cv2.undistortPoints(full.reshape(-1, 1, 2), self.intr.matrix, None)
        ray = np.concatenate([ray.reshape(-1, 2), np.ones((len(full), 1))], axis=1)
        px, _ = cv2.projectPoints(ray, np.zeros(3), np.zeros(3), self.intr.matrix,
                                  self.intr.distortion)
        return px.reshape(-1, 2)[:, 1]

    def _level(self, distance: float) -> tuple[float, np.ndarray]:
        """The coarsest map level still as fine as the frame at ``distance`` metres."""
        need = self.matrix_work[0, 0] / max(distance, 1e-3)
        best = self._levels[0]
        for scale, img in self._levels:
            if self.map.px_per_m * scale >= need:
                best = (scale, img)
        return best


def camera_motion(t0: float, pose0: tuple[np.ndarray, np.ndarray], t1: float,
                  pose1: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean velocity (m/s) and angular velocity (rad/s, world axes) of the camera between two
    poses (rotation world to camera, translation) at times ``t0 < t1``."""
    (r0, tv0), (r1, tv1), dt = pose0, pose1, t1 - t0
    return (r0.T @ tv0 - r1.T @ tv1) / dt, cv2.Rodrigues(r1.T @ r0)[0].ravel() / dt


def led_sigma(obj: np.ndarray, r_co: np.ndarray, tvec: np.ndarray, rms: float,
              matrix: np.ndarray, led_offset) -> float:
    """Standard deviation (metres, 3D) of the LED position that the pose's own fit implies:
    pixel noise ``rms`` propagated through the pose's Jacobian (a few points bunched in one
    corner of the frame leave the pose, and so the LED, poorly determined)."""
    rvec = cv2.Rodrigues(r_co)[0]
    _, jac = cv2.projectPoints(obj, rvec, tvec.reshape(3, 1), matrix, None)
    j = jac[:, :6]
    try:
        cov = max(rms, 0.05) ** 2 * np.linalg.inv(j.T @ j)
    except np.linalg.LinAlgError:
        return math.inf
    offset = np.asarray(led_offset, np.float64)

    def led(x: np.ndarray) -> np.ndarray:
        r = cv2.Rodrigues(x[:3])[0]
        return r.T @ (offset - x[3:])

    x0 = np.concatenate([rvec.ravel(), tvec.ravel()])
    g = np.column_stack([(led(x0 + d) - led(x0 - d)) / 2e-6 for d in np.eye(6) * 1e-6])
    return float(np.sqrt(max(np.trace(g @ cov @ g.T), 0.0)))


def _project(matrix: np.ndarray, r_co: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """Pixels of points given relative to the camera centre (world axes)."""
    p = (matrix @ r_co @ rel.T).T
    return p[:, :2] / p[:, 2:]


def _apply(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Apply a 3 x 3 homography to points (n, 2)."""
    p = np.column_stack([xy, np.ones(len(xy))]) @ h.T
    return p[:, :2] / p[:, 2:]


def track_painting_video(video: str | os.PathLike, painting: PaintingMap, intr: Intrinsics,
                         config: TrackConfig, *, readout_s: float = 0.0,
                         shutter_s: float | None = 0.0,
                         progress: bool = True) -> list[FramePose]:
    """Track every frame of phone A's video against the painting (``readout_s``: the
    rolling-shutter readout time, ``shutter_s``: the open-shutter time, None to estimate it,
    :class:`PaintingTracker`, :func:`estimate_shutter`).

    Raises
    ------
    LtmError
        If the video's frame size differs from the intrinsics', the painting is posed in fewer
        than :data:`~ltmstore.capture.track.MIN_TRACKED_FRACTION` of the frames, or the LED's
        median height is implausible (a painting width not in metres).
    """
    return _track_video(video, painting, intr, config, readout_s, shutter_s, progress)[0]


def _track_video(video, painting: PaintingMap, intr: Intrinsics, config: TrackConfig,
                 readout_s: float, shutter_s: float | None,
                 progress: bool) -> tuple[list[FramePose], float]:
    """:func:`track_painting_video`, and the shutter time it used."""
    tracker = PaintingTracker(painting, intr, config, readout_s=readout_s,
                              shutter_s=shutter_s or 0.0)
    results, times, cameras = _track_pass(video, tracker, None, progress, "track")
    if shutter_s is None:
        tracker.shutter_s = estimate_shutter(video, tracker, times, cameras)
    for k in range(RS_PASSES if readout_s > 0 or tracker.shutter_s > 0 else 0):
        motion = _centred_motion(times, cameras)
        tracker.reset()
        results, times, cameras = _track_pass(video, tracker, motion, progress,
                                              f"motion {k + 1}/{RS_PASSES}")
    _check_height(results, painting.width)
    if not enough_posed(results):
        good = sum(r.status == "ok" for r in results)
        found = sum(r.status != "no_painting" for r in results)
        raise LtmError(f"painting found in {found} and posed in {good} of {len(results)} "
                       f"frames of video A {str(video)!r}; expected it in view in at least "
                       f"{MIN_TRACKED_FRACTION:.0%} of the frames (wrong --painting map, or "
                       "the painting not in view?)")
    return flag_out_of_plane(results, config), tracker.shutter_s


def estimate_shutter(video: str | os.PathLike, tracker: PaintingTracker, times: list[float],
                     cameras: list) -> float:
    """Phone A's open-shutter time, from the data: the :data:`SHUTTERS_S` candidate whose
    smeared rendering of the map the fastest-moving placed frames (``times``, ``cameras``: a
    first pass's) fit best, by the median of :meth:`PaintingTracker.refit_error` (a frame a
    candidate cannot place counts as the worst). On simulated phones: 1/120 s found for a
    1/120 s shutter, 0-4 ms for a sharp video."""
    motion = _centred_motion(times, cameras)
    speed = np.array([np.linalg.norm(m[0]) if m is not None and c is not None else -1.0
                      for m, c in zip(motion, cameras, strict=True)])
    fastest = np.argsort(-speed)[:SHUTTER_FRAMES]
    picked = set(fastest[speed[fastest] > 0].tolist())
    if not picked:
        return 0.0
    frames = [(i, t, g) for i, t, g in video_frames(video, what="video A") if i in picked]
    errors = np.empty((len(SHUTTERS_S), len(frames)))
    for k, shutter in enumerate(SHUTTERS_S):
        tracker.shutter_s = shutter
        errors[k] = [tracker.refit_error(g, t, motion[i], cameras[i]) for i, t, g in frames]
    return float(SHUTTERS_S[int(np.argmin(np.median(errors, axis=1)))])


def _track_pass(video, tracker: PaintingTracker, motion: list | None, progress: bool,
                desc: str) -> tuple[list[FramePose], list[float], list]:
    """One pass over the video: the frames' poses, times and camera poses (None: not placed)."""
    results, times, cameras = [], [], []
    for i, t, gray in video_frames(video, what="video A", progress=progress, desc=desc):
        if i == 0:
            check_frame_size(gray, tracker.intr, f"video A {str(video)!r}")
        results.append(tracker.track_frame(gray, t, None if motion is None else motion[i]))
        times.append(t)
        cameras.append(tracker.camera)
    return results, times, cameras


def _centred_motion(times: list[float], cameras: list) -> list:
    """Each frame's camera velocity from the placed frames before and after it (centred;
    one-sided where one is missing; None where both are), for the rolling-shutter correction."""
    out = []
    for i in range(len(times)):
        ends = [j for j in (i - 1, i + 1) if 0 <= j < len(times) and cameras[j] is not None
                and abs(times[j] - times[i]) <= MAX_GAP_S]
        if len(ends) == 1 and cameras[i] is not None:
            ends = sorted([*ends, i])
        out.append(camera_motion(times[ends[0]], cameras[ends[0]], times[ends[-1]],
                                 cameras[ends[-1]]) if len(ends) == 2 else None)
    return out


def _check_height(results: list[FramePose], width: float) -> None:
    """Refuse a painting width that puts the LED at an implausible height (metres confused
    with centimetres, a map of another object)."""
    z = [r.led[2] for r in results if np.isfinite(r.led[2])]
    height = float(np.median(z)) if z else math.nan
    if z and not HEIGHT_RANGE_M[0] <= height <= HEIGHT_RANGE_M[1]:
        raise LtmError(f"with --painting-width {width:g} m the LED is tracked at a median "
                       f"height of {height:.3g} m; expected {HEIGHT_RANGE_M[0]:g}-"
                       f"{HEIGHT_RANGE_M[1]:g} m: is the width the painting's, in metres?")


def track_painting(video: str | os.PathLike, painting: PaintingMap, intr: Intrinsics,
                   out: str | os.PathLike, *, config: TrackConfig, readout_s: float = 0.0,
                   shutter_s: float | None = 0.0, overwrite: bool = False,
                   progress: bool = True) -> dict:
    """Track phone A's video against the painting and write the poses (as ``ltm track``).

    Parameters
    ----------
    video : path
        Phone A's video.
    painting : PaintingMap
        The painting's map and width.
    intr : Intrinsics
        Phone A's camera calibration (for the video's resolution).
    out : path
        ``poses.csv`` to write (``poses.frames.csv`` beside it).
    config : TrackConfig
        LED offset and the pose checks.
    readout_s : float
        Phone A's rolling-shutter readout time, seconds (0: no correction).
    shutter_s : float or None
        Phone A's open-shutter time, seconds (0: sharp frames; None: estimated,
        :func:`estimate_shutter`).
    overwrite : bool
        Replace an existing ``out``.
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        As :func:`ltmstore.capture.track.save_tracks` (``matches``: the median number of
        inlying painting points), and ``shutter_ms``, the shutter time used.
    """
    out = refuse_existing(out, overwrite, inputs=(video,))
    results, shutter_s = _track_video(video, painting, intr, config, readout_s, shutter_s,
                                      progress)
    return {**save_tracks(out, results, STATUSES, count_column="matches"),
            "shutter_ms": 1000 * shutter_s}
