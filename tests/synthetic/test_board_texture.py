"""Issue 63 item 3: the simulator draws camera B's calibration board where its JSON puts it.

Camera B's A4 board has 46.1 mm squares; at the texture's 5000 px/m that is 230.5 texels per
square, and OpenCV draws squares on whole texels, so each corner was off by up to half a texel
(0.1 mm). Filmed by camera B (720 px, f = 1620 px) through its true intrinsics, the detected
corners then missed their projections by 0.158 px RMS (20 views), which ``ltm calibrate`` fitted
as lens error. :func:`~ltmstore.synthetic.raw.board_px_per_m` draws a whole number of texels per
square (230, 4989.2 px/m): 0.031 px RMS, the corner detector's own noise.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ltmstore.capture.board import BoardDetector, board_spec
from ltmstore.synthetic.phone_effects import DISTORTION_B, camera_b_matrix
from ltmstore.synthetic.phone_view import PhoneView
from ltmstore.synthetic.raw import (
    BOARD_B_SQUARES,
    BOARD_SQUARE_MM,
    CAMERA_B_CALIBRATION_M,
    TEXTURE_PX_PER_M,
    board_px_per_m,
    board_texture,
    calibration_frames,
)

SIZE = (720, 720)


def reprojection_rms(spec, views: int = 12, seed: int = 1) -> tuple[float, int]:
    """Camera B's calibration views of ``spec`` as ``simulate_raw`` renders them (seed 1: the
    video of ``simulate_raw(seed=0)``); each view's detected corners posed by
    :func:`cv2.solvePnP` with the true intrinsics and reprojected through them.

    Returns
    -------
    float, int
        RMS distance (px) between detected and reprojected corners; the number of corners.
    """
    matrix = camera_b_matrix(SIZE)
    dist = np.array([*DISTORTION_B, 0, 0, 0])
    view = PhoneView(matrix, DISTORTION_B, SIZE, board_texture(spec), None,
                     distance=sum(CAMERA_B_CALIBRATION_M) / 2)
    detector = BoardDetector(spec)
    residuals = []
    for gray in calibration_frames(view, seed, views, height=CAMERA_B_CALIBRATION_M,
                                   spread=0.35, aim=0.03):
        obj, img, _ = detector.detect(gray)
        assert len(obj) >= 6
        ok, rvec, tvec = cv2.solvePnP(obj, img, matrix, dist)
        assert ok
        proj, _ = cv2.projectPoints(obj, rvec, tvec, matrix, dist)
        residuals.append(proj.reshape(-1, 2) - img)
    res = np.concatenate(residuals)
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1)))), len(res)


@pytest.mark.parametrize(("spec", "texels"), [
    (board_spec("A4", squares=BOARD_B_SQUARES), 230),  # camera B's: 46.1 mm, 230.5 at 5000
    (board_spec("A4", square_mm=BOARD_SQUARE_MM), 150),  # phone A's page: unchanged
    (board_spec("A0", square_mm=BOARD_SQUARE_MM), 150),  # phone A's tracking board: unchanged
])
def test_whole_texels_per_square_at_the_true_size(spec, texels):
    ppm = board_px_per_m(spec)
    assert spec.square_length * ppm == pytest.approx(texels, abs=1e-9)
    if texels == 150:
        assert ppm == TEXTURE_PX_PER_M
    tex = board_texture(spec)
    assert tex.ppm == ppm
    nx, ny = spec.squares
    assert tex.albedo.shape == (ny * texels, nx * texels)  # the board's true physical size
    w, h = spec.size
    assert (tex.r0, tex.s0) == (-w / 2, h / 2)


def test_camera_b_board_corners_reproject_under_true_intrinsics():
    rms, corners = reprojection_rms(board_spec("A4", squares=BOARD_B_SQUARES))
    assert corners > 150  # measured 177 corners in 12 views
    assert rms < 0.045, rms  # measured 0.029 px (0.031 in 20 views); at 230.5 texels 0.147
