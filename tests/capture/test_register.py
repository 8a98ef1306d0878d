"""Registration of camera B's frames onto the object grid (plane-induced homographies)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ltmstore.capture.register import (
    Intrinsics,
    ObjectGrid,
    ViewRig,
    footprint,
    rectify,
    render_camera_frame,
)
from ltmstore.core.errors import LtmError

GRID = ObjectGrid((48, 64), 0.2 / 64)
RIG = ViewRig(intrinsics=Intrinsics(fx=170.0, fy=172.0, cx=49.5, cy=41.0, width=100, height=84),
              distance=0.45, grid=GRID, look_at=(0.01, -0.005))
VIEWS = [(0.0, 0.0), (0.1, 0.1), (-0.1, 0.07), (0.08, -0.1), (-0.03, -0.09)]


def project_independently(rig: ViewRig, p: float, q: float, point: np.ndarray) -> np.ndarray:
    """Image position of a 3D point by cv2.projectPoints (camera pose, not the homography)."""
    rot = rig.rotation(p, q)
    rvec, _ = cv2.Rodrigues(rot)
    tvec = -rot @ np.array([p, q, rig.distance])
    uv, _ = cv2.projectPoints(point.reshape(1, 1, 3), rvec, tvec, rig.intrinsics.matrix, None)
    return uv.reshape(2)


def blob_frame(rig: ViewRig, uv: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """A camera frame showing a Gaussian spot centred at image position ``uv``."""
    v, u = np.mgrid[0:rig.intrinsics.height, 0:rig.intrinsics.width].astype(np.float64)
    return np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma**2)).astype(np.float32)


def centroid(image: np.ndarray) -> np.ndarray:
    """``(x, y)`` intensity centroid of the finite, above-background part of an image."""
    weights = np.where(np.isfinite(image), image, 0.0)
    weights = np.where(weights > 0.05 * weights.max(), weights, 0.0)
    y, x = np.indices(image.shape)
    return np.array([(weights * x).sum(), (weights * y).sum()]) / weights.sum()


@pytest.mark.parametrize("point_xy", [(0.0, 0.0), (0.031, -0.017), (-0.06, 0.04)])
def test_plane_point_lands_on_the_same_pixel_in_every_view(point_xy):
    h, w = GRID.shape
    expected = np.array([point_xy[0] / GRID.pixel_size + w / 2 - 0.5,
                         h / 2 - 0.5 - point_xy[1] / GRID.pixel_size])
    for p, q in VIEWS:
        uv = project_independently(RIG, p, q, np.array([*point_xy, 0.0]))
        found = centroid(rectify(blob_frame(RIG, uv), RIG, p, q))
        assert np.abs(found - expected).max() < 0.5, (p, q, found, expected)


def test_a_raised_point_moves_with_the_view():
    """Parallax: a point 1 cm above the plane does not register to one pixel."""
    spots = []
    for p, q in VIEWS[:3]:
        uv = project_independently(RIG, p, q, np.array([0.0, 0.0, 0.01]))
        spots.append(centroid(rectify(blob_frame(RIG, uv), RIG, p, q)))
    assert np.ptp(np.array(spots), axis=0).max() > 1.0


def test_grid_outside_the_frame_is_unobserved():
    zoomed = ViewRig(intrinsics=Intrinsics(fx=300.0, fy=300.0, cx=49.5, cy=41.5, width=100,
                                           height=84), distance=0.45, grid=GRID, look_at=(0, 0))
    image = np.ones((84, 100, 3), np.float32)
    out = rectify(image, zoomed, 0.1, 0.1)
    inside = footprint(zoomed, 0.1, 0.1)
    assert out.shape == (*GRID.shape, 3)
    assert 0.2 < inside.mean() < 0.95
    assert np.isnan(out[~inside]).all() and np.allclose(out[inside], 1.0)
    assert np.isnan(rectify(image, zoomed, np.nan, 0.0)).all()


def test_camera_frame_and_rectify_are_inverse_inside_the_footprint():
    rng = np.random.default_rng(0)
    smooth = cv2.GaussianBlur(rng.random(GRID.shape).astype(np.float32), (0, 0), 3)
    frame = render_camera_frame(smooth, RIG, -0.05, 0.02)
    back = rectify(frame, RIG, -0.05, 0.02)
    ok = np.isfinite(back)
    ok[:2], ok[-2:], ok[:, :2], ok[:, -2:] = False, False, False, False
    assert np.abs(back[ok] - smooth[ok]).max() < 0.02 * np.ptp(smooth)


def test_rig_json_round_trip_and_errors():
    assert ViewRig.from_json(RIG.to_json()) == RIG
    bad = {**RIG.to_json(), "distance": -1}
    with pytest.raises(LtmError, match=r"distance must be positive finite numbers"):
        ViewRig.from_json(bad)
    with pytest.raises(LtmError, match=r"must hold the camera as \{'distance'"):
        ViewRig.from_json({"p": [0, 1], "q": [0, 1]})


def test_ingest_rejects_a_partial_camera_and_a_wrong_frame_size(tmp_path):
    from ingest_helpers import H, W, make_acquisition

    from ltmstore.stages.ingest import ingest

    partial = {"p": [0.0, 0.1], "q": [-1.0, 1.0], "distance": 0.45}
    folder = make_acquisition(tmp_path / "a", view=True, extra={"view_plane": partial})
    with pytest.raises(LtmError, match=r"view_plane .* must hold the camera as"):
        ingest(folder, tmp_path / "a.zarr", progress=False)
    wrong = {"p": [0.0, 0.1], "q": [-1.0, 1.0], **RIG.to_json()}  # a 100 x 84 camera
    folder = make_acquisition(tmp_path / "b", view=True, extra={"view_plane": wrong})
    with pytest.raises(LtmError, match=rf"frames are {W}x{H} pixels; view_plane intrinsics "
                                       r"declare 100x84"):
        ingest(folder, tmp_path / "b.zarr", progress=False)
