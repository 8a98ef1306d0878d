"""Light kinds: near lights (a position on a plane at height h) and far lights (a direction).

A handheld LED is a **near light**: a point ``(r, s)`` on the illumination plane ``z = h``
(plane units, metres). A dome or a flash far away is a **far light**: a unit direction
``(lx, ly, lz)`` from the object towards the light (``x`` image right, ``y`` image up, ``z``
towards the camera), the same for every pixel.

A far-light store keeps the dims ``(y, x, r, s)`` with ``r = lx`` and ``s = ly``: the light's
direction projected orthographically onto the object plane, so the whole hemisphere fills the
unit disk (the zenith at the centre, raking lights near the rim) and every light above the
horizon has a place; a plane cannot hold raking lights (they map to infinity). The store
attribute :data:`KIND_ATTR` names the kind; :func:`coordinate_attrs` gives the units of ``r, s``.

Conversions (for a pixel at the plane's origin, below the plane's centre):

* :func:`plane_to_direction`: ``(r, s, h) / |(r, s, h)|``;
* :func:`direction_to_plane`: ``r = h lx / lz``, ``s = h ly / lz``;
* :func:`disk_to_direction`: ``lz = sqrt(1 - lx^2 - ly^2)``.
"""

from __future__ import annotations

import numpy as np

from ltmstore.core.dims import Plane
from ltmstore.core.errors import LtmError, brief

NEAR, FAR = "near", "far"
KIND_ATTR = "light_kind"  # acquisition attribute: "near" (default, handheld) or "far"
# The "plane" of a far-light store: the square of direction cosines (lx, ly) that holds the disk.
DISK = Plane(r=(-1.0, 1.0), s=(-1.0, 1.0), height=1.0, unit="1")
# The largest light value a user may give: a position in plane units (a near light a thousand
# kilometres away is a far light), or a direction's component.
MAX_LIGHT_VALUE = 1e6


def light_kind(acquisition: dict) -> str:
    """The light kind an acquisition record declares (``near`` when it says nothing)."""
    kind = acquisition.get(KIND_ATTR, NEAR)
    if kind not in (NEAR, FAR):
        raise LtmError(f"store light kind {kind!r} must be {NEAR!r} or {FAR!r}")
    return kind


def coordinate_attrs(kind: str, unit: str = "m") -> dict[str, dict[str, str]]:
    """Attributes of the ``r`` and ``s`` coordinates for a store of light ``kind``."""
    if kind == FAR:
        return {"r": {"units": "1", "long_name": "light direction lx (x component, image right)"},
                "s": {"units": "1", "long_name": "light direction ly (y component, image up)"}}
    return {"r": {"units": unit, "long_name": "light position on the plane, image right"},
            "s": {"units": unit, "long_name": "light position on the plane, image up"}}


def normalise(directions) -> np.ndarray:
    """Unit vectors ``(n, 3)`` from any non-zero finite vectors ``(n, 3)`` or ``(3,)``."""
    d = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    if d.shape[-1] != 3 or not np.isfinite(d).all():
        raise LtmError(f"direction {brief(directions)} must be finite "
                       "LX,LY,LZ triples")
    scale = np.abs(d).max(axis=-1, keepdims=True)  # first: 1e300 or 1e-320 stay in range
    if (scale == 0).any():
        raise LtmError("a light direction must not be the zero vector")
    d = d / scale
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def check_light(values, what: str, names: tuple[str, ...]) -> np.ndarray:
    """Lights as a user gives them, refused unless finite and of a sane magnitude.

    Parameters
    ----------
    values : array_like
        One light or ``(n, len(names))`` of them.
    what : str
        ``"light"`` or ``"direction"``, for the message.
    names : tuple of str
        The components (``("r", "s")``, ``("lx", "ly", "lz")``).

    Returns
    -------
    ndarray
        ``(n, len(names))`` float64.

    Raises
    ------
    LtmError
        Naming the light and the component that is not finite or beyond
        :data:`MAX_LIGHT_VALUE` in magnitude, or the values when they are not such numbers.
    """
    try:
        v = np.atleast_2d(np.asarray(values, dtype=np.float64))
    except (TypeError, ValueError):
        v = np.empty((0, 0))
    if v.ndim != 2 or v.shape[-1] != len(names) or not v.size:
        raise LtmError(f"{what} {brief(values)} must be {','.join(names).upper()} numbers")
    for light in v:
        text = ", ".join(f"{x:g}" for x in light)
        for name, x in zip(names, light, strict=True):
            if not np.isfinite(x):
                raise LtmError(f"{what} ({text}): {name} = {x:g} must be finite")
            if abs(x) > MAX_LIGHT_VALUE:
                raise LtmError(f"{what} ({text}): {name} = {x:g} must be at most "
                               f"{MAX_LIGHT_VALUE:g} in magnitude; expected "
                               + ("a position near the plane (plane units)" if what == "light"
                                  else "components of a sane size (a direction's length does "
                                  "not matter)"))
    return v


def above_horizon(directions: np.ndarray) -> np.ndarray:
    """True where a unit direction points above the object plane (``lz > 0``)."""
    return np.asarray(directions)[..., 2] > 0


def plane_to_direction(r, s, height: float) -> np.ndarray:
    """Unit directions ``(n, 3)`` towards plane positions ``(r, s)`` at ``height``, seen from
    the point of the object below the plane's origin."""
    r, s = np.broadcast_arrays(np.atleast_1d(np.asarray(r, float)),
                               np.atleast_1d(np.asarray(s, float)))
    return normalise(np.column_stack([r, s, np.full(r.shape, float(height))]))


def direction_to_plane(directions, height: float) -> np.ndarray:
    """Plane positions ``(n, 2)`` where directions hit the plane at ``height``; ``inf`` for a
    direction at or below the horizon (it never reaches the plane)."""
    d = normalise(directions)
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = height * d[:, :2] / d[:, 2:3]
    return np.where(above_horizon(d)[:, None], rs, np.inf)


def disk_to_direction(lx, ly) -> np.ndarray:
    """Unit directions ``(n, 3)`` of disk coordinates; points outside the unit disk go to the
    horizon along their azimuth."""
    lx, ly = np.broadcast_arrays(np.atleast_1d(np.asarray(lx, float)),
                                 np.atleast_1d(np.asarray(ly, float)))
    rho = np.hypot(lx, ly)
    scale = np.where(rho > 1, 1 / np.maximum(rho, 1e-300), 1.0)
    lx, ly = lx * scale, ly * scale
    lz = np.sqrt(np.clip(1 - lx * lx - ly * ly, 0, None))
    return np.column_stack([lx, ly, lz])


def elevation_azimuth(elevation_deg, azimuth_deg) -> np.ndarray:
    """Unit directions ``(n, 3)`` from elevations above the horizon and azimuths (degrees,
    counter-clockwise from image right)."""
    el, az = np.broadcast_arrays(np.radians(np.atleast_1d(elevation_deg)),
                                 np.radians(np.atleast_1d(azimuth_deg)))
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
