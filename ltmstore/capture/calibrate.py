"""Camera intrinsics from a video of the ChArUco board: ``ltm calibrate``.

The intrinsics file (``ltm-intrinsics/1``) holds the image size, the 3 x 3 camera matrix and
OpenCV's distortion coefficients, with the RMS reprojection error of the calibration and, under
``calibration``, the lens model chosen and its held-out error.

The lens model is chosen, not fixed: a narrow field (camera B: 25 degrees) cannot tell the
principal point, ``k2`` and the tangential terms from one another or from the board's own
printing errors, and fitting them all moved the principal point 29 px on a simulated camera B.
Nested models (:data:`LENS_MODELS`, from ``k1`` with the principal point at the image centre to
OpenCV's full ``k1, k2, p1, p2`` with a free principal point and aspect) are each scored by
their reprojection error on views left out of the fit (:data:`CV_FOLDS`-fold cross-validation
over the views); the simplest model within :data:`TOLERANCE_PX` and within a factor
``1 +`` :data:`RELATIVE_TOLERANCE` of the best held-out error is kept. A wide lens, whose views
determine ``k2``, gains far more than that from it and keeps it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import write_text_atomic
from ltmstore.capture.board import BoardDetector, BoardSpec, read_spec_json, video_frames
from ltmstore.core.errors import LtmError

FORMAT = "ltm-intrinsics/1"
MIN_VIEWS = 4  # fewest board views for a calibration
CALIB_CORNERS = 12  # fewest corners in a view used for calibration
CV_FOLDS = 5  # folds of the cross-validation over views
# The simplest lens model whose held-out RMS is within min(TOLERANCE_PX, RELATIVE_TOLERANCE x
# best) of the best is kept: a richer model must gain more than 0.1 px or halve the error. A
# smaller gain is within what the board's own corner errors explain (the simulator's texture
# places corners to +-0.1 mm, a 300 dpi print to +-0.04 mm: 0.1-0.25 px at camera B).
TOLERANCE_PX = 0.1
RELATIVE_TOLERANCE = 1.0

_FIXED_CENTRE = cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
_RADIAL = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
# name -> (OpenCV flags, free parameters); in order of the number of parameters
LENS_MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "k1": (_FIXED_CENTRE | _RADIAL | cv2.CALIB_FIX_K2, ("f", "k1")),
    "k1k2": (_FIXED_CENTRE | _RADIAL, ("f", "k1", "k2")),
    "k1+centre": (cv2.CALIB_FIX_ASPECT_RATIO | _RADIAL | cv2.CALIB_FIX_K2,
                  ("f", "cx", "cy", "k1")),
    "k1k2+centre": (cv2.CALIB_FIX_ASPECT_RATIO | _RADIAL, ("f", "cx", "cy", "k1", "k2")),
    "k1k2+centre+tangential": (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_K3,
                               ("f", "cx", "cy", "k1", "k2", "p1", "p2")),
    "full": (cv2.CALIB_FIX_K3, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
}
Views = list[tuple[np.ndarray, np.ndarray]]  # (object points (n, 3), image points (n, 2))


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera with distortion.

    Attributes
    ----------
    image_size : (int, int)
        Width, height in pixels.
    matrix : ndarray (3, 3)
        Camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    distortion : ndarray
        OpenCV distortion coefficients (``k1, k2, p1, p2[, k3 ...]``).
    rms_px : float or None
        RMS reprojection error of the calibration, pixels.
    """

    image_size: tuple[int, int]
    matrix: np.ndarray
    distortion: np.ndarray
    rms_px: float | None = None

    def to_json(self) -> dict:
        return {"format": FORMAT, "image_size": list(self.image_size),
                "camera_matrix": np.asarray(self.matrix).tolist(),
                "dist_coeffs": np.asarray(self.distortion).ravel().tolist(),
                "reprojection_rms_px": self.rms_px}

    def write(self, path: str | os.PathLike, extra: dict | None = None) -> None:
        """Write the JSON file (atomically)."""
        write_text_atomic(path, json.dumps({**self.to_json(), **(extra or {})}, indent=2) + "\n",
                          what="intrinsics")


def load_intrinsics(path: str | os.PathLike) -> Intrinsics:
    """Read an intrinsics file written by ``ltm calibrate``; one-line errors otherwise."""
    path = Path(path)
    d = read_spec_json(path, what="intrinsics file", written_by="ltm calibrate")
    try:
        if d.get("format") != FORMAT:
            raise LtmError(f"intrinsics file {str(path)!r} has format {d.get('format')!r}; "
                           f"expected {FORMAT!r}")
        matrix = np.asarray(d["camera_matrix"], dtype=np.float64)
        dist = np.asarray(d["dist_coeffs"], dtype=np.float64).ravel()
        size = tuple(int(v) for v in d["image_size"])
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise LtmError(f"intrinsics file {str(path)!r} is malformed ({exc}); expected the JSON "
                       "written by `ltm calibrate`") from None
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)) or matrix[0, 0] <= 0 \
            or len(size) != 2 or dist.size not in (4, 5, 8, 12, 14):
        raise LtmError(f"intrinsics file {str(path)!r}: camera_matrix must be 3x3 with fx > 0, "
                       "image_size [w, h], dist_coeffs 4, 5, 8, 12 or 14 numbers")
    return Intrinsics(size, matrix, dist, d.get("reprojection_rms_px"))


def calibrate_video(video: str | os.PathLike, spec: BoardSpec, *, max_views: int = 40,
                    progress: bool = True) -> tuple[Intrinsics, dict]:
    """Calibrate a camera from a video of the board seen from varied angles.

    Parameters
    ----------
    video : path
        The calibration video (phone A's, or camera B's).
    spec : BoardSpec
        The board filmed.
    max_views : int
        Views used at most, spread evenly over the frames where the board is well seen.
    progress : bool
        Show a progress bar over the frames.

    Returns
    -------
    (Intrinsics, dict)
        The calibration and a report: ``frames``, ``views_found``, ``views_used``,
        ``reprojection_rms_px`` and the lens model chosen (:func:`calibrate_views`).

    Raises
    ------
    LtmError
        If the board is seen in fewer than :data:`MIN_VIEWS` frames.
    """
    detector = BoardDetector(spec)
    views, n, size = [], 0, (0, 0)
    for _i, _t, gray in video_frames(video, progress=progress, desc="calibrate"):
        n += 1
        obj, img, _ = detector.detect(gray)
        if len(obj) >= CALIB_CORNERS:
            views.append((obj, img))
        size = gray.shape[::-1]
    if len(views) < MIN_VIEWS:
        raise LtmError(f"board {spec.squares[0]}x{spec.squares[1]} ({spec.dictionary}) found in "
                       f"{len(views)} of {n} frames of {str(video)!r}; expected at least "
                       f"{MIN_VIEWS} views of the board described by --board")
    pick = np.unique(np.linspace(0, len(views) - 1, min(max_views, len(views))).round()
                     .astype(int))
    size = (int(size[0]), int(size[1]))
    intr, choice = calibrate_views([views[i] for i in pick], size)
    report = {"frames": n, "views_found": len(views), "views_used": len(pick),
              "reprojection_rms_px": intr.rms_px, "image_size": list(intr.image_size),
              "focal_px": [float(intr.matrix[0, 0]), float(intr.matrix[1, 1])], **choice}
    return intr, report


def calibrate_views(views: Views, size: tuple[int, int], *,
                    models: tuple[str, ...] | None = None,
                    tolerance_px: float = TOLERANCE_PX) -> tuple[Intrinsics, dict]:
    """Calibrate from board views, choosing the lens model by held-out reprojection error.

    Parameters
    ----------
    views : list of (object_points (n, 3), image_points (n, 2))
        Board corners of each view (metres, pixels).
    size : (int, int)
        Image width, height.
    models : tuple of str, optional
        Names of :data:`LENS_MODELS` to choose from, simplest first (default: all). One name
        fits that model without cross-validation.
    tolerance_px : float
        The simplest model whose held-out RMS is within this (and within
        :data:`RELATIVE_TOLERANCE` times the best) of the best is chosen.

    Returns
    -------
    (Intrinsics, dict)
        The calibration with the chosen model and a report: ``lens_model``, its
        ``heldout_rms_px``, ``free_parameters``, ``std_intrinsics`` (OpenCV's standard deviations
        of fx, fy, cx, cy, k1, k2, p1, p2; 0 where fixed, the focal's under fy where the
        pixels are square) and ``lens_models`` (each candidate's
        ``rms_px`` on all views and ``heldout_rms_px``).

    Raises
    ------
    LtmError
        For an unknown model name, or where OpenCV cannot fit the chosen model to the views.
    """
    models = tuple(LENS_MODELS) if models is None else models
    unknown = [m for m in models if m not in LENS_MODELS]
    if unknown or not models:
        raise LtmError(f"lens models {unknown or list(models)!r}: expected some of "
                       f"{', '.join(LENS_MODELS)}")
    try:
        guess = initial_matrix(views, size)
        scores = {m: heldout_rms(views, size, m, guess) if len(models) > 1 else None
                  for m in models}
        chosen = choose_model(scores, tolerance_px)
        rms, matrix, dist, std = _fit(views, size, chosen, guess, extended=True)
        candidates = {m: {"rms_px": _round(_fit(views, size, m, guess)[0]),
                          "heldout_rms_px": _round(scores[m])} for m in models}
    except cv2.error as exc:
        raise LtmError(f"OpenCV could not calibrate from {len(views)} board views "
                       f"({getattr(exc, 'err', exc)}); expected views of the board from varied "
                       "angles") from None
    report = {"lens_model": chosen, "heldout_rms_px": _round(scores[chosen]),
              "free_parameters": list(LENS_MODELS[chosen][1]),
              "std_intrinsics": np.round(std[:8], 6).tolist(), "lens_models": candidates,
              "cv_folds": min(CV_FOLDS, len(views)), "tolerance_px": tolerance_px,
              "relative_tolerance": RELATIVE_TOLERANCE}
    return Intrinsics(size, matrix, dist[:5], rms), report


def choose_model(scores: dict[str, float | None], tolerance_px: float = TOLERANCE_PX,
                 relative: float = RELATIVE_TOLERANCE) -> str:
    """The first (simplest) model whose held-out RMS is within ``min(tolerance_px, relative *
    best)`` of the best (``None``: its fit failed); the first model when no score is known."""
    known = [v for v in scores.values() if v is not None]
    if not known:
        return next(iter(scores))
    best = min(known)
    limit = best + min(tolerance_px, relative * best)
    return next(m for m, v in scores.items() if v is not None and v <= limit)


def _round(v: float | None) -> float | None:
    return None if v is None else round(float(v), 5)


def initial_matrix(views: Views, size: tuple[int, int]) -> np.ndarray:
    """Camera matrix to start from: OpenCV's focal estimate, principal point at the image centre
    (``((w - 1) / 2, (h - 1) / 2)``, pixel centres at integers), square pixels."""
    k = cv2.initCameraMatrix2D([v[0] for v in views], [v[1] for v in views], size)
    f = float(np.sqrt(k[0, 0] * k[1, 1]))
    return np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]])


def _fit(views: Views, size: tuple[int, int], model: str, guess: np.ndarray,
         extended: bool = False):
    flags = LENS_MODELS[model][0] | cv2.CALIB_USE_INTRINSIC_GUESS
    obj, img = [v[0] for v in views], [v[1] for v in views]
    if extended:
        rms, matrix, dist, _, _, std, _, _ = cv2.calibrateCameraExtended(
            obj, img, size, guess.copy(), np.zeros(5), flags=flags)
        return float(rms), matrix, dist.ravel(), std.ravel()
    rms, matrix, dist, _, _ = cv2.calibrateCamera(obj, img, size, guess.copy(), np.zeros(5),
                                                  flags=flags)
    return float(rms), matrix, dist.ravel()


def heldout_rms(views: Views, size: tuple[int, int], model: str,
                guess: np.ndarray | None = None, folds: int = CV_FOLDS) -> float | None:
    """RMS reprojection error (pixels) of views left out of the fit, over ``folds`` folds (view
    ``i`` in fold ``i % folds``): each left-out view's pose is fitted to its corners with the
    other views' intrinsics. ``None`` where a fold's fit fails."""
    guess = initial_matrix(views, size) if guess is None else guess
    folds = min(folds, len(views))
    err, count = 0.0, 0
    for f in range(folds):
        train = [v for i, v in enumerate(views) if i % folds != f]
        try:
            _, matrix, dist = _fit(train, size, model, guess)
        except cv2.error:
            return None
        for obj, img in views[f::folds]:
            _ok, rvec, tvec = cv2.solvePnP(obj, img, matrix, dist)
            proj, _ = cv2.projectPoints(obj, rvec, tvec, matrix, dist)
            err += float(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2))
            count += len(img)
    return float(np.sqrt(err / count))
