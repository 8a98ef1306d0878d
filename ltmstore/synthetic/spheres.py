"""Render a classic RTI capture with calibration spheres: a chrome and a black glossy sphere
beside a flat textured object, under known lights (the ground truth of ``ltm lights``).

The camera is orthographic, looking straight down (view ``v = (0, 0, 1)``). Image coordinates
follow OpenCV: pixel ``(col, row)`` has its centre at integer ``(col, row)``; the scene point
under it is ``X = col + 0.5 - W/2``, ``Y = H/2 - row - 0.5`` in pixel units on the object plane
``z = 0`` (x right, y up, z towards the camera, as the ``.lp`` file). A sphere of radius ``r``
rests on that plane: its centre is at height ``r``.

Each pixel is the mean of ``supersample**2`` samples, so the spheres' outlines and highlights are
anti-aliased as a camera's are, then blurred by the lens (:data:`BLUR_PX`) before the sRGB
codes clip. Per sample (unit normal ``n`` of the sphere, mirror direction
``R = 2 (n.v) n - v``, direction ``l`` from the surface point towards the light):

* chrome: ``env(R) + E * disc(angle(R, l))``: a dim room plus the light, a disc of
  :data:`LIGHT_RADIUS_DEG` angular radius, bright enough to clip: the highlight is at the
  normal ``n = normalize(l + v)``;
* black glossy: ``0.02 E max(n.l, 0) + 0.2 env(R) + K exp(-(angle(n, h) / sigma)^2)`` with
  ``h = normalize(l + v)``: a dark dielectric with a glossy lobe that peaks below white;
* the table and the object: Lambertian, ``albedo E max(n.l, 0) + ambient`` with ``n = (0, 0,
  1)``; the object a textured rectangle.

A light is a direction (far, the same ``l`` everywhere) or a position (near, ``l`` from each
point), in pixel units with the origin at the image centre on the object plane.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import linear_to_srgb

LIGHT_RADIUS_DEG = 1.5  # angular radius of the light seen from the chrome sphere
BLUR_PX = 0.7  # the lens's blur (Gaussian sigma, pixels), applied to linear light before clipping
GLOSS_SIGMA_DEG = 2.0  # width of the black sphere's lobe, in normal angle
GLOSS_PEAK = 0.8  # the black sphere's lobe at its peak (linear; below white)
LIGHT_RADIANCE = 8.0  # the light's radiance in the chrome sphere: clipped
AMBIENT = 0.03


@dataclass(frozen=True)
class SphereSpec:
    """A sphere in the image: centre ``(x, y)`` in pixels (OpenCV convention), radius ``r`` in
    pixels, ``kind`` ``"chrome"`` or ``"black"``."""

    x: float
    y: float
    r: float
    kind: str = "chrome"


DEFAULT_SPHERES = (SphereSpec(70.3, 75.6, 45.2, "chrome"), SphereSpec(72.7, 222.4, 40.6, "black"))
OBJECT_BOX = (170, 40, 380, 260)  # the flat object's columns and rows: x0, y0, x1, y1


def dome_directions(n: int, seed: int = 0, elevation_deg: tuple[float, float] = (15, 80)
                    ) -> np.ndarray:
    """``n`` unit directions towards lights above the object: azimuths spread by the golden
    angle (with a random phase), elevations uniform in ``elevation_deg``."""
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(0, 2 * np.pi) + np.arange(n) * np.pi * (3 - np.sqrt(5))
    elevation = np.radians(rng.uniform(*elevation_deg, n))
    return np.column_stack([np.cos(elevation) * np.cos(azimuth),
                            np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])


def _towards(light: np.ndarray, points: np.ndarray, near: bool) -> np.ndarray:
    """Unit directions from ``points (..., 3)`` towards the light."""
    if not near:
        return np.broadcast_to(light / np.linalg.norm(light), points.shape)
    d = light - points
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


def _environment(direction: np.ndarray) -> np.ndarray:
    """A dim room: brighter overhead, a faint horizon band."""
    return 0.04 + 0.06 * np.clip(direction[..., 2], 0, 1) + 0.03 * direction[..., 0] ** 2


def _texture(col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Albedo of the flat object: stripes and blobs in three colours, ``(..., 3)``."""
    a = 0.45 + 0.2 * np.sin(col / 7.0) * np.cos(row / 11.0)
    b = 0.35 + 0.25 * (np.sin((col + row) / 13.0) > 0)
    return np.stack([a, 0.5 * (a + b), b], axis=-1)


def _sphere_radiance(sphere: SphereSpec, points: np.ndarray, normal: np.ndarray,
                     light: np.ndarray, near: bool) -> np.ndarray:
    """Grey linear radiance of the sphere's samples ``(m,)``."""
    view = np.array([0.0, 0.0, 1.0])
    mirror = 2 * normal[:, 2:3] * normal - view
    towards = _towards(light, points, near)
    if sphere.kind == "chrome":
        edge = np.radians(LIGHT_RADIUS_DEG)
        disc = np.clip((edge - _angle(mirror, towards)) / (0.3 * edge) + 0.5, 0, 1)
        return 0.9 * _environment(mirror) + LIGHT_RADIANCE * disc
    half = towards + view
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    lobe = GLOSS_PEAK * np.exp(-(_angle(normal, half) / np.radians(GLOSS_SIGMA_DEG)) ** 2)
    return 0.02 * np.clip(np.sum(normal * towards, -1), 0, None) + 0.2 * _environment(
        mirror) + lobe


def render(light: np.ndarray, *, near: bool = False, size: tuple[int, int] = (300, 400),
           spheres: tuple[SphereSpec, ...] = DEFAULT_SPHERES, supersample: int = 3
           ) -> np.ndarray:
    """One photograph: linear RGB ``(H, W, 3)`` float64 (not clipped).

    Parameters
    ----------
    light : array_like, shape (3,)
        A direction towards the light (``near=False``) or its position in pixel units from the
        image centre on the object plane (``near=True``).
    size : (int, int)
        Height and width, pixels.
    spheres : tuple of SphereSpec
        The spheres (resting on the object plane).
    supersample : int
        Samples per pixel along each axis.
    """
    light = np.asarray(light, dtype=np.float64)
    h, w = size
    row, col = np.mgrid[0:h, 0:w].astype(np.float64)
    image = _flat(light, row, col, size, near)
    for sphere in spheres:
        y0, y1 = max(int(sphere.y - sphere.r) - 1, 0), min(int(sphere.y + sphere.r) + 2, h)
        x0, x1 = max(int(sphere.x - sphere.r) - 1, 0), min(int(sphere.x + sphere.r) + 2, w)
        image[y0:y1, x0:x1] = _sphere_box(sphere, light, (y0, y1, x0, x1), size, near,
                                          int(supersample))
    return ndimage.gaussian_filter(image, (BLUR_PX, BLUR_PX, 0), mode="nearest")


def _points(row: np.ndarray, col: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    h, w = size
    return np.stack([col + 0.5 - w / 2, h / 2 - row - 0.5, np.zeros_like(col)], axis=-1)


def _flat(light: np.ndarray, row: np.ndarray, col: np.ndarray, size: tuple[int, int],
          near: bool) -> np.ndarray:
    """The table and the object (Lambertian, facing the camera) at the samples ``(row, col)``."""
    towards = _towards(light, _points(row, col, size), near)
    albedo = np.full(row.shape + (3,), 0.3)
    x0, y0, x1, y1 = OBJECT_BOX
    inside = (col >= x0 - 0.5) & (col < x1 - 0.5) & (row >= y0 - 0.5) & (row < y1 - 0.5)
    albedo[inside] = _texture(col[inside], row[inside])
    return albedo * np.clip(towards[..., 2], 0, None)[..., None] + AMBIENT


def _sphere_box(sphere: SphereSpec, light: np.ndarray, box: tuple[int, int, int, int],
                size: tuple[int, int], near: bool, s: int) -> np.ndarray:
    """The pixels of ``box`` (rows y0:y1, columns x0:x1) around ``sphere``, each the mean of
    ``s * s`` samples."""
    y0, y1, x0, x1 = box
    offsets = (np.arange(s) + 0.5) / s - 0.5
    rows = (np.arange(y0, y1)[:, None] + offsets[None, :]).ravel()
    cols = (np.arange(x0, x1)[:, None] + offsets[None, :]).ravel()
    row, col = np.meshgrid(rows, cols, indexing="ij")
    image = _flat(light, row, col, size, near)
    dx, dy = (col - sphere.x) / sphere.r, -(row - sphere.y) / sphere.r
    on = dx**2 + dy**2 < 1
    normal = np.stack([dx[on], dy[on], np.sqrt(1 - dx[on] ** 2 - dy[on] ** 2)], axis=-1)
    where = _points(row[on], col[on], size) + sphere.r * (1 + normal[:, 2:3]) * [0, 0, 1]
    image[on] = _sphere_radiance(sphere, where, normal, light, near)[:, None]
    return image.reshape(y1 - y0, s, x1 - x0, s, 3).mean(axis=(1, 3))


def write_capture(folder: str | Path, lights: np.ndarray, *, near: bool = False,
                  size: tuple[int, int] = (300, 400),
                  spheres: tuple[SphereSpec, ...] = DEFAULT_SPHERES, supersample: int = 3
                  ) -> Path:
    """Render one 8-bit sRGB PNG per light into a new ``folder`` (``im000.png``, ...) and the
    true ``dirs.lp`` (for near lights, the directions from the image centre on the object
    plane). Returns the ``.lp`` path."""
    import cv2

    folder = Path(folder)
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 3)
    if not (lights[:, 2] > 0).all():
        raise LtmError("every light must lie above the object plane (z > 0)")
    folder.mkdir(parents=True, exist_ok=False)
    lines = [str(len(lights))]
    for i, light in enumerate(lights):
        linear = render(light, near=near, size=size, spheres=spheres, supersample=supersample)
        code = np.round(linear_to_srgb(linear) * 255).astype(np.uint8)
        name = f"im{i:03d}.png"
        if not cv2.imwrite(str(folder / name), np.ascontiguousarray(code[..., ::-1])):
            raise LtmError(f"cannot write {str(folder / name)!r}")
        d = light / np.linalg.norm(light)
        lines.append(f"{name} {d[0]:.8f} {d[1]:.8f} {d[2]:.8f}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"
