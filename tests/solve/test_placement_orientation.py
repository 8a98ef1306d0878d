"""The frame's map to the plane in any orientation (issue 63, item 8): turned by multiples of
90 degrees, mirrored, turned by a small angle, or sheared, estimated from the pixels' radial
profiles; the map's two written forms place pixels alike; ``acquisition.json`` declares it."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.core.dims import Lattice, Plane, object_pixels
from ltmstore.core.errors import LtmError
from ltmstore.solve.placement import (
    estimate_placement,
    frame_corners,
    pixel_map,
    profile,
    turn_degrees,
)

SHAPE = (24, 30)  # off centre, not square: a swapped side or a wrong turn shows
EXTENT = {"x": [0.02, 0.17], "y": [-0.05, 0.07]}  # pixels 5 mm wide, 5 mm high
CENTRE = np.array([0.095, 0.01])


def _profiles(corners: np.ndarray, *, jitter: float = 0.003, seed: int = 0):
    """Radial profiles of a frame :data:`SHAPE` with ``corners`` on the plane, each pixel
    displaced by ``jitter`` (as a tilted normal displaces its peak), under a random 40 % of a
    16 x 16 lattice, with noise."""
    rng = np.random.default_rng(seed)
    rows, cols = (a.ravel() for a in np.indices(SHAPE))
    origin, a = pixel_map(corners, SHAPE)
    where = origin + np.column_stack([cols + 0.5, rows + 0.5]) @ a.T
    where += rng.normal(0, jitter, where.shape)
    lat = Lattice.from_plane(Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3), (16, 16))
    rr, ss = np.meshgrid(lat.centres(0), lat.centres(1), indexing="ij")
    lights = np.column_stack([rr.ravel(), ss.ravel()])[rng.random(256) < 0.4]
    albedo = rng.uniform(0.2, 1.0, (len(rows), 1))
    values = 0.01 + albedo * profile(lights, where, 0.3, 2.0)
    values += rng.normal(0, 0.005 * values.max(), values.shape)
    return values, rows, cols, SHAPE, lights


def _turned(degrees: float, mirrored: bool = False) -> np.ndarray:
    """:data:`EXTENT`'s corners mirrored left to right, then turned about its centre."""
    corners = frame_corners(EXTENT) - CENTRE
    if mirrored:
        corners = corners * [-1, 1]
    t = np.radians(degrees)
    return corners @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]]) + CENTRE


@pytest.mark.parametrize("mirrored", [False, True])
def test_every_turn_by_90_degrees_is_found(mirrored):
    for turn in (0, 90, 180, -90):
        corners = _turned(turn, mirrored)
        found = estimate_placement(*_profiles(corners), 0.3)
        err = np.abs(found.corners - corners).max()
        # measured: 0.25-0.53 mm (0.1 px); a wrong turn or mirror is 60-150 mm off
        assert err < 0.0015, (turn, mirrored, found.extent)
        assert found.model == "square" and found.mirrored == mirrored
        assert found.turn == pytest.approx(turn if turn != -180 else 180, abs=1e-9)
        assert (found.extent.keys() == {"x", "y"}) == (turn == 0 and not mirrored)
        assert found.pitch == pytest.approx((0.005, 0.005), rel=0.02)
        assert 0 < found.sigma_max < 0.002 and found.support == pytest.approx(1.0)


@pytest.mark.parametrize("degrees", [3.0, 30.0])
def test_a_turn_by_any_angle_is_found(degrees):
    corners = _turned(degrees)
    found = estimate_placement(*_profiles(corners), 0.3)
    assert found.model == "similarity" and not found.mirrored
    # measured: turns 3.03 and 29.99 degrees, sigma 0.19-0.20; corners within 0.57-0.65 mm
    assert abs(found.turn - degrees) < 3 * found.turn_sigma + 0.05, found.turn
    assert np.abs(found.corners - corners).max() < 0.0015
    assert "top_left" in found.extent


def test_an_unturned_frame_keeps_the_axis_aligned_map():
    found = estimate_placement(*_profiles(frame_corners(EXTENT)), 0.3)
    assert found.model == "square" and found.turn == 0.0  # a turn of 0.2 sigma is no turn
    assert found.turn_sigma == pytest.approx(0.2, abs=0.15)  # measured 0.19 degrees


def test_a_sheared_map_is_kept_where_the_data_insist():
    corners = frame_corners(EXTENT)
    corners[2] += [0.03, 0.0]  # the bottom edge moved right: columns lean by 0.25
    found = estimate_placement(*_profiles(corners, jitter=0.001), 0.3)
    assert found.model == "affine"
    assert np.abs(found.corners - corners).max() < 0.001  # measured 0.37 mm


def test_both_forms_place_pixels_alike():
    image = (3, 4)
    everywhere = (slice(None), slice(None))
    along = object_pixels(EXTENT, image, *everywhere)
    corners = dict(zip(("top_left", "top_right", "bottom_left"),
                       frame_corners(EXTENT).tolist(), strict=True))
    assert np.allclose(object_pixels(corners, image, *everywhere), along, atol=1e-15)
    turned = _turned(90)
    origin, a = pixel_map(turned, image)
    rows, cols = np.indices(image)
    want = origin + np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5]) @ a.T
    declared = dict(zip(("top_left", "top_right", "bottom_left"), turned.tolist(), strict=True))
    assert np.allclose(object_pixels(declared, image, slice(1, 3), slice(0, 2)),
                       want.reshape(*image, 2)[1:3, 0:2].reshape(-1, 2))
    assert turn_degrees(turned) == (pytest.approx(90.0), False)


def test_acquisition_declares_any_orientation(tmp_path):
    import json

    from ltmstore.capture.acquisition import load_acquisition

    (tmp_path / "video.mkv").write_bytes(b"")
    (tmp_path / "poses.csv").write_text("t,r,s,z\n0,0,0,0.3\n0.1,0,0,0.3\n")

    def load(obj):
        meta = {"format": "ltm-acquisition/1", "video": "video.mkv", "poses": "poses.csv",
                "plane": {"r": [-0.2, 0.2], "s": [-0.2, 0.2], "height": 0.3},
                "transfer": "srgb", "object": obj}
        (tmp_path / "acquisition.json").write_text(json.dumps(meta))
        return load_acquisition(tmp_path)

    turned = {"top_left": [0.1, -0.1], "top_right": [0.1, 0.1], "bottom_left": [-0.1, -0.1]}
    assert load(turned).object_extent == turned
    for bad in ({"top_left": [0, 0], "top_right": [1, 1], "bottom_left": [2, 2]},  # a line
                {"top_left": [0, 0], "top_right": [1, 0]},
                {"top_left": [0, 0], "top_right": [1, 0], "bottom_left": [0, "1"]},
                {"top_left": [0, 0], "top_right": [0, 0], "bottom_left": [0, 1]}):
        with pytest.raises(LtmError, match=r"object .* must look like .*'top_left': \[r, s\]"):
            load(bad)
