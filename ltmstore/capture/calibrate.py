"""Camera intrinsics of phone A from a video of the ChArUco board: ``ltm calibrate``.

The intrinsics file (``ltm-intrinsics/1``) holds the image size, the 3 x 3 camera matrix and
OpenCV's distortion coefficients, with the RMS reprojection error of the calibration.
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
        Phone A's calibration video.
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
        ``reprojection_rms_px``.

    Raises
    ------
    LtmError
        If the board is seen in fewer than :data:`MIN_VIEWS` frames.
    """
    detector = BoardDetector(spec)
    views, n = [], 0
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
    obj = [views[i][0] for i in pick]
    img = [views[i][1] for i in pick]
    flags = cv2.CALIB_FIX_K3
    rms, matrix, dist, _, _ = cv2.calibrateCamera(obj, img, tuple(size), None, None, flags=flags)
    intr = Intrinsics(tuple(int(v) for v in size), matrix, dist.ravel(), float(rms))
    report = {"frames": n, "views_found": len(views), "views_used": len(pick),
              "reprojection_rms_px": float(rms), "image_size": list(intr.image_size),
              "focal_px": [float(matrix[0, 0]), float(matrix[1, 1])]}
    return intr, report
