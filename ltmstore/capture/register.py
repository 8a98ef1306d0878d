"""Registration of a moving camera's frames onto one object-plane pixel grid (6D acquisitions).

Camera B is a pinhole camera whose centre moves on a view plane parallel to the object, at
``(p, q, distance)`` in the frame of :mod:`ltmstore.core.dims` (object plane ``z = 0``). It either
looks straight down (optical axis along ``-Z``) or turns to keep a point ``look_at = (X, Y)`` of
the object plane on its optical axis (image up towards ``+Y`` as far as possible). The object
plane ``z = 0`` maps to the image by the plane-induced homography ``K [r1 r2 t]``; composed with
the object grid (pixel ``(x, y)`` to plane ``(X, Y)``) it takes grid pixels to image pixels.
:func:`rectify` inverts it for every frame with :func:`cv2.warpPerspective`, so that every frame
lands on the same ``(y, x)`` grid; grid pixels whose image position falls outside the frame are
NaN (unobserved in that frame).

Declared in ``acquisition.json`` under ``view_plane`` (beside ``p`` and ``q``)::

    "distance": d,                            camera centre height above the object
    "intrinsics": {"fx": .., "fy": .., "cx": .., "cy": .., "width": .., "height": ..},
    "grid": {"shape": [H, W], "pixel_size": pitch},   the object-plane output grid
    "look_at": [X, Y]                         optional; default: looking straight down

Pixel coordinates follow OpenCV: integer ``(u, v)`` are pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ltmstore.core.errors import LtmError


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of camera B (pixels) and its frame size."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def matrix(self) -> np.ndarray:
        """The ``3 x 3`` calibration matrix ``K``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ObjectGrid:
    """The rectified output grid: ``shape = (H, W)`` pixels of ``pixel_size`` plane units,
    centred on the object-plane origin (the convention of :mod:`ltmstore.core.dims`)."""

    shape: tuple[int, int]
    pixel_size: float

    @property
    def matrix(self) -> np.ndarray:
        """Homogeneous map from grid pixel ``(x, y, 1)`` to plane point ``(X, Y, 1)``."""
        h, w = self.shape
        d = self.pixel_size
        return np.array([[d, 0.0, (0.5 - w / 2) * d], [0.0, -d, (h / 2 - 0.5) * d],
                         [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ViewRig:
    """Camera B on its view plane: intrinsics, distance, orientation rule and output grid.

    Parameters
    ----------
    intrinsics : Intrinsics
    distance : float
        Height of the camera centre above the object plane (plane units).
    grid : ObjectGrid
        The object-plane grid every frame is rectified onto.
    look_at : (float, float) or None
        Plane point kept on the optical axis; ``None``: the optical axis is the plane normal.
    """

    intrinsics: Intrinsics
    distance: float
    grid: ObjectGrid
    look_at: tuple[float, float] | None = None

    def rotation(self, p: float, q: float) -> np.ndarray:
        """World-to-camera rotation ``R`` (rows: camera x right, y down, z forward)."""
        centre = np.array([p, q, self.distance])
        target = (np.array([p, q, 0.0]) if self.look_at is None
                  else np.array([*self.look_at, 0.0]))
        forward = target - centre
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        return np.stack([right, down, forward])

    def plane_homography(self, p: float, q: float) -> np.ndarray:
        """Homography from object-plane points ``(X, Y, 1)`` to image pixels ``(u, v, 1)``."""
        rot = self.rotation(p, q)
        t = -rot @ np.array([p, q, self.distance])
        return self.intrinsics.matrix @ np.column_stack([rot[:, 0], rot[:, 1], t])

    def homography(self, p: float, q: float) -> np.ndarray:
        """Homography from grid pixels ``(x, y, 1)`` to image pixels ``(u, v, 1)``."""
        hom = self.plane_homography(p, q) @ self.grid.matrix
        return hom / hom[2, 2]

    def project(self, p: float, q: float, points: np.ndarray) -> np.ndarray:
        """Image pixels ``(n, 2)`` of object-plane points ``(n, 2)`` (plane units)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 2)
        return cv2.perspectiveTransform(pts, self.plane_homography(p, q)).reshape(-1, 2)

    def to_json(self) -> dict:
        k = self.intrinsics
        out = {"distance": self.distance,
               "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
                              "width": k.width, "height": k.height},
               "grid": {"shape": list(self.grid.shape), "pixel_size": self.grid.pixel_size}}
        if self.look_at is not None:
            out["look_at"] = list(self.look_at)
        return out

    @classmethod
    def from_json(cls, value: object, where: str = "view_plane") -> ViewRig:
        """Parse the camera part of ``view_plane`` (see the module docstring).

        Raises
        ------
        LtmError
            One line naming the bad value and the expected form.
        """
        expect = ("{'distance': d, 'intrinsics': {'fx','fy','cx','cy','width','height'}, "
                  "'grid': {'shape': [H, W], 'pixel_size': m}[, 'look_at': [X, Y]]}")
        try:
            k = value["intrinsics"]
            intr = Intrinsics(float(k["fx"]), float(k["fy"]), float(k["cx"]), float(k["cy"]),
                              int(k["width"]), int(k["height"]))
            g = value["grid"]
            grid = ObjectGrid((int(g["shape"][0]), int(g["shape"][1])), float(g["pixel_size"]))
            distance = float(value["distance"])
            look = value.get("look_at")
            look_at = None if look is None else (float(look[0]), float(look[1]))
        except (KeyError, TypeError, IndexError, ValueError, AttributeError):
            raise LtmError(f"{where} {value!r} must hold the camera as {expect}") from None
        numbers = [intr.fx, intr.fy, intr.cx, intr.cy, grid.pixel_size, distance,
                   *(look_at or ())]
        if not all(np.isfinite(numbers)) or min(intr.fx, intr.fy, grid.pixel_size,
                                                 distance) <= 0:
            raise LtmError(f"{where} camera {value!r}: fx, fy, pixel_size and distance must be "
                           "positive finite numbers")
        if min(intr.width, intr.height, *grid.shape) < 1:
            raise LtmError(f"{where} camera {value!r}: frame and grid sizes must be positive")
        return cls(intrinsics=intr, distance=distance, grid=grid, look_at=look_at)


def rectify(image: np.ndarray, rig: ViewRig, p: float, q: float) -> np.ndarray:
    """Warp one camera frame onto the object grid; NaN where the grid falls outside the frame.

    Parameters
    ----------
    image : ndarray, shape (h, w) or (h, w, c), float32
        The frame (linear values), of the rig's frame size.
    rig : ViewRig
    p, q : float
        Camera position for this frame; NaN gives an all-NaN result.

    Returns
    -------
    ndarray of float32, shape ``grid.shape`` (+ ``(c,)``)
    """
    h, w = rig.grid.shape
    out_shape = (h, w, *np.shape(image)[2:])
    if not (np.isfinite(p) and np.isfinite(q)):
        return np.full(out_shape, np.nan, dtype=np.float32)
    hom = rig.homography(p, q)
    out = cv2.warpPerspective(np.asarray(image, dtype=np.float32), hom, (w, h),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE).reshape(out_shape)
    inside = footprint(rig, p, q)
    out[~inside] = np.nan
    return out


def footprint(rig: ViewRig, p: float, q: float) -> np.ndarray:
    """Grid pixels ``(H, W)`` whose image position lies inside the frame (with bilinear
    support: between the first and last pixel centres)."""
    h, w = rig.grid.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.stack([xs.ravel(), ys.ravel()], axis=-1).reshape(-1, 1, 2)
    uv = cv2.perspectiveTransform(pts, rig.homography(p, q)).reshape(h, w, 2)
    k = rig.intrinsics
    return ((uv[..., 0] >= 0) & (uv[..., 0] <= k.width - 1) & (uv[..., 1] >= 0)
            & (uv[..., 1] <= k.height - 1))


def render_camera_frame(rectified: np.ndarray, rig: ViewRig, p: float, q: float,
                        background: float = 0.0) -> np.ndarray:
    """What camera B at ``(p, q)`` sees of a rectified object-grid image (the inverse of
    :func:`rectify`, for simulations); outside the object the frame shows ``background``."""
    k = rig.intrinsics
    return cv2.warpPerspective(np.asarray(rectified, dtype=np.float32), rig.homography(p, q),
                               (k.width, k.height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT,
                               borderValue=(background,) * 4)
