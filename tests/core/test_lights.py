"""Light kinds: direction <-> plane conversions against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.core.errors import LtmError
from ltmstore.core.lights import (
    FAR,
    NEAR,
    coordinate_attrs,
    direction_to_plane,
    disk_to_direction,
    elevation_azimuth,
    light_kind,
    normalise,
    plane_to_direction,
)


def test_plane_to_direction_by_hand():
    # (r, s, h) = (3, 0, 4): a 3-4-5 triangle
    np.testing.assert_allclose(plane_to_direction(3.0, 0.0, 4.0), [[0.6, 0.0, 0.8]])
    # (1, 1, 1) / sqrt(3)
    np.testing.assert_allclose(plane_to_direction(0.5, 0.5, 0.5), [[3**-0.5] * 3])


def test_direction_to_plane_by_hand():
    # r = h lx / lz: 45 degrees of elevation lands at r = h
    np.testing.assert_allclose(direction_to_plane([1, 0, 1], 2.0), [[2.0, 0.0]])
    np.testing.assert_allclose(direction_to_plane([0.6, -0.0, 0.8], 4.0), [[3.0, 0.0]])
    np.testing.assert_allclose(direction_to_plane([0, 0.5, 0.25], 1.0), [[0.0, 2.0]])
    # at or below the horizon it never meets the plane
    assert np.isinf(direction_to_plane([[1, 0, 0], [1, 0, -0.1]], 1.0)).all()


def test_round_trip():
    dirs = elevation_azimuth(np.arange(5, 91, 5), np.arange(0, 360, 20))
    back = plane_to_direction(*direction_to_plane(dirs, 0.7).T, 0.7)
    np.testing.assert_allclose(back, dirs, atol=1e-12)


def test_disk_to_direction():
    np.testing.assert_allclose(disk_to_direction(0.6, 0.0), [[0.6, 0.0, 0.8]])
    np.testing.assert_allclose(disk_to_direction(0.0, 0.0), [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(disk_to_direction(2.0, 0.0), [[1.0, 0.0, 0.0]])  # to the rim


def test_elevation_azimuth():
    np.testing.assert_allclose(elevation_azimuth(30, 90), [[0.0, np.cos(np.pi / 6), 0.5]],
                               atol=1e-12)


def test_kinds_and_units():
    assert light_kind({}) == NEAR and light_kind({"light_kind": "far"}) == FAR
    assert coordinate_attrs(FAR)["r"]["units"] == "1"
    assert coordinate_attrs(NEAR)["s"]["units"] == "m"
    with pytest.raises(LtmError, match="light kind 'dome' must be 'near' or 'far'"):
        light_kind({"light_kind": "dome"})


def test_bad_directions():
    with pytest.raises(LtmError, match="must not be the zero vector"):
        normalise([0, 0, 0])
    with pytest.raises(LtmError, match="must be finite LX,LY,LZ triples"):
        normalise([1, np.nan, 0])
