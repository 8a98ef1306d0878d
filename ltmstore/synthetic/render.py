"""Render a :class:`~ltmstore.synthetic.scenes.Scene` lit by a point light.

Physics, per pixel (surface point ``P``, unit normal ``n``, light ``L``, unit view ``v``)::

    radiance = (albedo / pi * (1 - metallic) + f_GGX(n, l, v)) * I0 * max(n.l, 0) / |L - P|^2 * V

with ``f_GGX = D F G / (4 (n.l) (n.v))`` (GGX distribution, Schlick Fresnel on ``spec_color``,
separable Smith masking) and ``V`` the hard cast-shadow visibility found by ray-marching the
height field from ``P`` towards ``L`` in steps of half a pixel (bilinear heights), only while the
ray is still below the highest point of the scene. Attached shadows come from ``n.l <= 0``.

Geometry follows :mod:`ltmstore.core.dims`: object plane ``z = 0``, pixel centres
``X = (x + 0.5 - W/2) pitch``, ``Y = (H/2 - y - 0.5) pitch``, a light ``(r, s, z)`` sits at
``(X, Y, Z) = (r, s, z)``. The camera is orthographic looking straight down unless a
:class:`PinholeCamera` is given; the image always stays on the object-plane pixel grid (the
rectified view), only the view direction changes.

:class:`Shading` changes the physics for benchmarks that must not share the fitted model's
assumptions (:data:`MISMATCHED`): a Beckmann or Blinn-Phong lobe instead of GGX, an LED whose
emission falls off as ``cos^m`` about its downward axis, an ambient floor, and a second, broader
clear-coat gloss layer. The default, :data:`GGX`, is the physics above.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from tqdm.auto import tqdm

from ltmstore.core.dims import LIGHT_DIMS, LUMA, VIEW_DIMS, Lattice
from ltmstore.core.errors import LtmError, brief
from ltmstore.synthetic.scenes import Scene

LOBES = ("ggx", "beckmann", "phong")
MARCH_STEP_PX = 0.5  # shadow ray step, pixels (horizontal)
SHADOW_EPS = 1e-7  # metres: a height must exceed the ray by this to occlude it


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera centred at ``(p, q, distance)`` above the object plane.

    Parameters
    ----------
    p, q : float
        Camera centre on the view plane, plane units (same axes as ``r, s``).
    distance : float
        Height of the camera centre above the object plane.
    focal_px : float
        Focal length in pixels. The renderer produces the object-plane-rectified view, so only
        the camera centre enters the shading; ``focal_px`` is recorded for re-projection.
    """

    p: float
    q: float
    distance: float
    focal_px: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise LtmError(f"camera distance {self.distance!r} must be a positive number")
        if not (np.isfinite(self.focal_px) and self.focal_px > 0):
            raise LtmError(f"camera focal_px {self.focal_px!r} must be a positive number")


@dataclass(frozen=True)
class Shading:
    """Options of the physics, for renders that do not share a fitted model's assumptions.

    Parameters
    ----------
    lobe : {"ggx", "beckmann", "phong"}
        Microfacet distribution of the specular lobe (Blinn-Phong with exponent
        ``2 / alpha^2 - 2`` for ``phong``); the masking term stays Smith GGX.
    led_exponent : float
        The light emits ``I0 cos^m`` about its downward axis (``m = 0``: isotropic).
    ambient : float
        A floor added to every pixel: ``ambient * albedo * I0 / z^2`` (``z``: the light's
        height), light from the room that does not move with the LED.
    clearcoat : float
        Strength of a second specular layer (Fresnel ``F0 = 0.04``, GGX) with roughness
        ``clearcoat_roughness``, over the whole scene.
    clearcoat_roughness : float
    """

    lobe: str = "ggx"
    led_exponent: float = 0.0
    ambient: float = 0.0
    clearcoat: float = 0.0
    clearcoat_roughness: float = 0.4

    def __post_init__(self) -> None:
        if self.lobe not in LOBES:
            raise LtmError(f"shading lobe {self.lobe!r} is not one of {', '.join(LOBES)}")
        for name in ("led_exponent", "ambient", "clearcoat"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise LtmError(f"shading {name} {value!r} must be a number >= 0")
        if not 0 < self.clearcoat_roughness <= 1:
            raise LtmError(f"shading clearcoat_roughness {self.clearcoat_roughness!r} must be "
                           "in (0, 1]")


GGX = Shading()
# Not the family of ltmstore.solve.physical: Beckmann lobe, cos^2 LED, 2 % floor, clear coat.
MISMATCHED = Shading(lobe="beckmann", led_exponent=2.0, ambient=0.02, clearcoat=0.25)


class _Renderer:
    """Per-scene precomputation (positions, normals, view vectors) shared by all lights."""

    def __init__(self, scene: Scene, camera: PinholeCamera | None = None,
                 shading: Shading = GGX) -> None:
        self.scene = scene
        self.shading = shading
        x, y = scene.pixel_centres()
        self.height = np.asarray(scene.height, dtype=np.float64)
        self.pos = np.stack([x, y, self.height])
        self.n = scene.normals()
        self.alpha2 = np.asarray(scene.roughness, dtype=np.float64) ** 2
        metallic = np.asarray(scene.metallic, dtype=np.float64)
        self.kd = np.asarray(scene.albedo) / np.pi * (1 - metallic)[..., None]
        self.f0 = np.asarray(scene.spec_color, dtype=np.float64)
        self.h_max = float(self.height.max())
        self.rows, self.cols = np.indices(self.height.shape, dtype=np.float64)
        self.set_camera(camera)

    def set_camera(self, camera: PinholeCamera | None) -> None:
        """Recompute the view-dependent terms (and, for a pinhole, the parallax of the
        rectified view) for ``camera``."""
        self.camera = camera
        if camera is None:
            self.v = np.array([0.0, 0.0, 1.0])[:, None, None] * np.ones_like(self.n)
        else:
            to_cam = np.array([camera.p, camera.q, camera.distance])[:, None, None] - self.pos
            self.v = to_cam / np.linalg.norm(to_cam, axis=0)
        self.ndotv = np.sum(self.n * self.v, axis=0)
        self.g1v = _smith_g1(self.ndotv, self.alpha2)
        self.g1v_coat = _smith_g1(self.ndotv, self.shading.clearcoat_roughness**4)
        self.sight = None if camera is None else _sight_lines(self.scene, self.height, camera)

    def rectified(self, light: np.ndarray, intensity: float = 1.0) -> np.ndarray:
        """The camera's view resampled onto the object-plane grid (``(H, W, 3)``): grid pixel
        ``(y, x)`` shows the surface point on the sight line through the plane point ``(X, Y,
        0)``, so raised features shift with the camera (parallax)."""
        shaded = self(light, intensity)
        if self.sight is None:
            return shaded
        return np.stack([ndimage.map_coordinates(shaded[..., c], self.sight, order=1,
                                                 mode="nearest", prefilter=False)
                         for c in range(shaded.shape[-1])], axis=-1)

    def __call__(self, light: np.ndarray, intensity: float = 1.0) -> np.ndarray:
        light = np.asarray(light, dtype=np.float64)
        lvec = light[:, None, None] - self.pos
        d2 = np.sum(lvec * lvec, axis=0)
        l_dir = lvec / np.sqrt(d2)
        ndotl = np.sum(self.n * l_dir, axis=0)
        lit = (ndotl > 0) & (self.ndotv > 0)
        # Specular times n.l: D F G / (4 n.v), which avoids dividing by a small n.l.
        spec_cos = self._specular(l_dir, ndotl) / (4 * np.where(lit, self.ndotv, 1.0))[..., None]
        cos = np.where(lit, ndotl, 0.0)
        shaded = self.kd * cos[..., None] + np.where(lit[..., None], spec_cos, 0.0)
        visible = ~self._occluded(light, lit)
        emitted = intensity * visible / d2
        if self.shading.led_exponent:  # cos of the angle off the LED's downward axis
            emitted = emitted * l_dir[2].clip(min=0) ** self.shading.led_exponent
        out = shaded * emitted[..., None]
        if self.shading.ambient:
            out += self.kd * np.pi * (self.shading.ambient * intensity / light[2] ** 2)
        return out.astype(np.float32)

    def _specular(self, l_dir: np.ndarray, ndotl: np.ndarray) -> np.ndarray:
        half = l_dir + self.v
        half /= np.linalg.norm(half, axis=0)
        ndoth = np.clip(np.sum(self.n * half, axis=0), 0.0, 1.0)
        vdoth = np.clip(np.sum(self.v * half, axis=0), 0.0, 1.0)
        schlick = ((1 - vdoth) ** 5)[..., None]
        cos_l = np.clip(ndotl, 0.0, 1.0)
        a2 = self.alpha2
        dist = _distribution(self.shading.lobe, ndoth, a2)
        lobe = (self.f0 + (1 - self.f0) * schlick) * (dist * _smith_g1(cos_l, a2)
                                                      * self.g1v)[..., None]
        if self.shading.clearcoat:
            c2 = self.shading.clearcoat_roughness**4
            coat = _distribution("ggx", ndoth, c2) * _smith_g1(cos_l, c2) * self.g1v_coat
            lobe = lobe + self.shading.clearcoat * (0.04 + 0.96 * schlick) * coat[..., None]
        return lobe

    def _occluded(self, light: np.ndarray, lit: np.ndarray) -> np.ndarray:
        """Hard cast shadows: march every lit pixel towards the light (vectorised over pixels)."""
        rays = _Rays.towards(self, light, lit)
        occluded = np.zeros(self.height.shape, dtype=bool)
        active = np.flatnonzero(rays.steps > 0)
        k = 1
        while active.size:
            t = k * rays.dt[active]
            ray_h = rays.h0[active] + t * rays.dh[active]
            ground = _height_at(self.height, rays.y0[active] + t * rays.dy[active],
                                rays.x0[active] + t * rays.dx[active])
            hit = ground > ray_h + SHADOW_EPS
            occluded.flat[active[hit]] = True
            k += 1
            active = active[~hit & (rays.steps[active] >= k)]
        return occluded


@dataclass(frozen=True)
class _Rays:
    """Shadow rays of the pixels to march, flattened: start, direction (pixels), step, count."""

    y0: np.ndarray
    x0: np.ndarray
    h0: np.ndarray
    dy: np.ndarray
    dx: np.ndarray
    dh: np.ndarray
    dt: np.ndarray
    steps: np.ndarray

    @classmethod
    def towards(cls, rnd: _Renderer, light: np.ndarray, lit: np.ndarray) -> _Rays:
        row, col = _light_pixel(rnd.scene, light)
        y0, x0, h0 = rnd.rows.ravel(), rnd.cols.ravel(), rnd.height.ravel()
        dy, dx, dh = row - y0, col - x0, light[2] - h0
        dt, steps = _march_plan(dy, dx, h0, dh, rnd.h_max)
        steps = np.where(lit.ravel(), steps, 0)
        return cls(y0, x0, h0, dy, dx, dh, dt, steps)


def _sight_lines(scene: Scene, height: np.ndarray, camera: PinholeCamera,
                 iterations: int = 3) -> np.ndarray:
    """Fractional ``(row, col)`` of the surface point seen through each grid pixel, ``(2, H, W)``.

    The sight line from the camera centre ``C = (p, q, d)`` through the plane point ``X'`` meets
    the surface at height ``h`` at ``X = X' - (h / d) (X' - C_xy)``; ``h`` is found by a few
    fixed-point steps on the bilinear height field (heights are millimetres, ``d`` decimetres).
    Occlusion of the surface by itself along the sight line is neglected.
    """
    rows, cols = np.indices(height.shape, dtype=np.float64)
    x, y = scene.pixel_centres()
    dx = (x - camera.p) / scene.pixel_size  # grid pixels per unit h/d, along +col
    dy = -(y - camera.q) / scene.pixel_size  # along +row (rows grow downwards)
    h = height
    for _ in range(iterations):
        ratio = h / camera.distance
        r, c = rows - ratio * dy, cols - ratio * dx
        h = _height_at(height, r.ravel(), c.ravel()).reshape(height.shape)
    ratio = h / camera.distance
    return np.stack([rows - ratio * dy, cols - ratio * dx])


def _distribution(lobe: str, ndoth: np.ndarray, a2: np.ndarray | float) -> np.ndarray:
    """Normal distribution ``D(n.h)`` of the microfacet ``lobe`` with ``alpha^2 = a2``."""
    c2 = np.maximum(ndoth, 1e-6) ** 2
    if lobe == "beckmann":
        return np.exp((c2 - 1) / (c2 * a2)) / (np.pi * a2 * c2 * c2)
    if lobe == "phong":
        power = 2 / a2 - 2
        return (power + 2) / (2 * np.pi) * np.maximum(ndoth, 0.0) ** power
    return a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)


def _smith_g1(cos: np.ndarray, a2: np.ndarray) -> np.ndarray:
    """Smith GGX masking for one direction."""
    return 2 * cos / (cos + np.sqrt(a2 + (1 - a2) * cos * cos) + 1e-300)


def _light_pixel(scene: Scene, light: np.ndarray) -> tuple[float, float]:
    """Fractional (row, column) of the light's foot point on the pixel grid."""
    h, w = scene.shape
    col = light[0] / scene.pixel_size + w / 2 - 0.5
    row = h / 2 - 0.5 - light[1] / scene.pixel_size
    return row, col


def _march_plan(dy: np.ndarray, dx: np.ndarray, h0: np.ndarray, dh: np.ndarray,
                h_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Parameter step ``dt`` (half a pixel horizontally) and number of steps below ``h_max``.

    The ray is ``P + t (L - P)``; it can only be occluded while its height is below ``h_max``,
    i.e. for ``t < (h_max - h0) / dh`` (or up to the light when the light is that low).
    """
    horiz = np.sqrt(dy * dy + dx * dx)
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = MARCH_STEP_PX / horiz
        t_max = np.where(dh > h_max - h0, (h_max - h0) / dh, 1.0)
        steps = np.where(horiz > 0, np.floor(t_max / dt), 0)
    return dt, np.nan_to_num(steps).astype(np.int64)


def _height_at(height: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear height lookup at fractional pixel positions (edge values extend outwards)."""
    return ndimage.map_coordinates(height, np.stack([np.atleast_1d(rows), np.atleast_1d(cols)]),
                                   order=1, mode="nearest", prefilter=False)


def _as_light(light) -> np.ndarray:
    light = np.asarray(light, dtype=np.float64)
    if light.shape != (3,) or not np.all(np.isfinite(light)):
        raise LtmError(f"light {brief(light)} must be three finite numbers (r, s, z)")
    return light


def render_frame(scene: Scene, light, *, camera: PinholeCamera | None = None,
                 intensity: float = 1.0, shading: Shading = GGX) -> np.ndarray:
    """Render the scene lit by a point light at ``light = (r, s, z)``.

    Parameters
    ----------
    scene : Scene
    light : array_like, shape (3,)
        Light position in plane units; ``z`` is the height above the object plane.
    camera : PinholeCamera, optional
        Default: orthographic, looking straight down.
    intensity : float
        Radiant intensity ``I0`` of the light.
    shading : Shading
        Options of the physics (default: the GGX model of the module docstring).

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        Linear RGB radiance.
    """
    return _Renderer(scene, camera, shading)(_as_light(light), intensity)


def iter_frames(scene: Scene, lights: Iterable, *, camera: PinholeCamera | None = None,
                intensity: float = 1.0, shading: Shading = GGX) -> Iterator[np.ndarray]:
    """Yield :func:`render_frame` for each light of ``lights`` (streaming; shares set-up)."""
    renderer = _Renderer(scene, camera, shading)
    for light in lights:
        yield renderer(_as_light(light), intensity)


def render_frames(scene: Scene, lights, *, camera: PinholeCamera | None = None,
                  intensity: float = 1.0) -> np.ndarray:
    """Render ``lights (N, 3)`` into ``(N, H, W, 3)`` float32 linear RGB."""
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 3)
    frames = np.empty((len(lights), *scene.shape, 3), dtype=np.float32)
    for i, frame in enumerate(iter_frames(scene, lights, camera=camera, intensity=intensity)):
        frames[i] = frame
    return frames


def render_ltm(scene: Scene, lattice: Lattice, height: float, *,
               camera: PinholeCamera | None = None, intensity: float = 1.0,
               progress: bool = False, shading: Shading = GGX) -> np.ndarray:
    """The ground-truth light transport matrix at the lattice cell centres.

    Parameters
    ----------
    scene : Scene
    lattice : Lattice
        A 2-D ``(r, s)`` lattice; lights sit at ``lattice.centres(0) x lattice.centres(1)``.
    height : float
        Height of the illumination plane above the object.
    camera : PinholeCamera, optional
    intensity : float
    progress : bool
        Show a progress bar over the lights.
    shading : Shading

    Returns
    -------
    ndarray, shape (H, W, R, S, 3), float32
        ``ltm[y, x, i, j]`` is pixel ``(y, x)`` lit from ``(r_i, s_j, height)``.
    """
    if tuple(lattice.dims) != LIGHT_DIMS:
        raise LtmError(f"render_ltm needs an (r, s) lattice, got dims {lattice.dims}")
    r, s = lattice.centres(0), lattice.centres(1)
    out = np.empty((*scene.shape, len(r), len(s), 3), dtype=np.float32)
    renderer = _Renderer(scene, camera, shading)
    for i, j in tqdm(np.ndindex(len(r), len(s)), total=len(r) * len(s), disable=not progress,
                     desc="truth LTM", unit="light"):
        out[:, :, i, j] = renderer(np.array([r[i], s[j], height]), intensity)
    return out


def is_occluded(scene: Scene, pixel_yx: tuple[int, int], light) -> bool:
    """Reference (slow, scalar) hard-shadow test for one pixel and one light.

    Marches from the surface point of pixel ``(y, x)`` towards ``light = (r, s, z)`` in steps of
    half a pixel, while the ray is below the scene's highest point, and reports whether the
    bilinear height field rises above the ray anywhere.
    """
    light = _as_light(light)
    y, x = (float(c) for c in pixel_yx)
    height = np.asarray(scene.height, dtype=np.float64)
    h0 = float(height[int(y), int(x)])
    row, col = _light_pixel(scene, light)
    dy, dx, dh = row - y, col - x, light[2] - h0
    dt, steps = _march_plan(np.float64(dy), np.float64(dx), h0, dh, float(height.max()))
    for k in range(1, int(steps) + 1):
        t = k * dt
        if _height_at(height, y + t * dy, x + t * dx)[0] > h0 + t * dh + SHADOW_EPS:
            return True
    return False


def render_ltm_6d(scene: Scene, lattice: Lattice, height: float, *, distance: float,
                  intensity: float = 1.0, progress: bool = False) -> np.ndarray:
    """The 6D ground truth: luminance at every light ``(r, s)`` and camera ``(p, q)`` cell centre.

    Parameters
    ----------
    scene : Scene
    lattice : Lattice
        A 4-D ``(r, s, p, q)`` lattice: lights at ``(r_i, s_j, height)``, camera centres at
        ``(p_k, q_l, distance)``.
    height : float
        Height of the illumination plane.
    distance : float
        Height of the view plane (camera centres).
    intensity : float
    progress : bool

    Returns
    -------
    ndarray, shape (H, W, R, S, P, Q), float32
        Linear luminance (BT.601) of the rectified view (:meth:`_Renderer.rectified`).
    """
    if tuple(lattice.dims) != (*LIGHT_DIMS, *VIEW_DIMS):
        raise LtmError(f"render_ltm_6d needs an (r, s, p, q) lattice, got dims {lattice.dims}")
    r, s, p, q = (lattice.centres(i) for i in range(4))
    out = np.empty((*scene.shape, *lattice.shape), dtype=np.float32)
    luma = LUMA.astype(np.float32)
    renderer = _Renderer(scene)
    bar = tqdm(total=lattice.size, disable=not progress, desc="truth 6D LTM", unit="image")
    for k, m in np.ndindex(len(p), len(q)):
        renderer.set_camera(PinholeCamera(p[k], q[m], distance, focal_px=1.0))
        for i, j in np.ndindex(len(r), len(s)):
            out[:, :, i, j, k, m] = renderer.rectified(np.array([r[i], s[j], height]),
                                                       intensity) @ luma
            bar.update()
    bar.close()
    return out
