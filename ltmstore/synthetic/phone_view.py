"""Phone A's camera as a phone has it: ray-cast views of a textured plane.

Every pixel's ray (through the lens, with its radial distortion) is intersected with the object
plane ``z = 0`` from the camera's pose at the time the pixel's row was read (rolling shutter),
averaged over the instants the shutter is open (motion blur). The plane holds a
:class:`PlaneTexture`: the ChArUco board with the painting pasted at its centre, evenly lit (the
board simulation, as before), or the painting on a plain, faintly textured wall lit by the
phone's own LED (:class:`LedLighting`): Lambertian shading with the near light's inverse-square
fall-off, the LED's angular profile about the phone's optical axis, a varnish highlight that
moves with the phone, and the room's ambient light. The painting's relief is not rendered in
phone A's view (it is flat paint and varnish there); camera B's view has it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ltmstore.core.transfer import linear_to_srgb
from ltmstore.synthetic.phone_effects import normalised_rays

OPTICS_BLUR_PX = 0.8  # Gaussian sigma of the lens blur, pixels at 1280 wide
NOISE_DN = 2.0  # read noise, 8-bit code values
SHOT_DN = 0.02  # shot noise variance per code value
WALL_ALBEDO = 0.75  # a white-painted wall ...
WALL_GRAIN = 0.02  # ... with 2 % albedo grain (paint texture), correlated over 0.6 mm
WALL_GRAIN_M = 0.6e-3
CANVAS_GRAIN = 0.04  # canvas weave and brushwork finer than camera B sees: 4 %, over 0.3 mm
CANVAS_GRAIN_M = 0.3e-3
VARNISH_ALPHA = 0.2  # GGX roughness of the painting's varnish (the canvas scene: 0.12-0.4)
VARNISH_F0 = 0.04
WALL_ALPHA = 0.6  # matt wall paint
PIXEL_AREA_SIGMA = 0.4  # texture low-pass, in pixel footprints (a box of 1 has sigma 0.29)
SHADE_STRIDE = 4  # pixels between shading samples (the LED's light varies over centimetres)
LIT_WHITE = 0.55  # linear value of a white (albedo 1) surface 30 cm straight below the LED


@dataclass(frozen=True, eq=False)
class PlaneTexture:
    """Albedo (linear grey, ``(H, W)`` float32) over a plane rectangle, and the half sizes of
    the varnished painting at its centre (``None``: no varnish).

    Texel ``(i, j)`` covers plane ``r = r0 + (j + 0.5) / ppm``, ``s = s0 - (i + 0.5) / ppm``
    (``(r0, s0)``: the texture's top-left corner in plane coordinates).
    """

    albedo: np.ndarray
    varnish: tuple[float, float] | None
    r0: float
    s0: float
    ppm: float
    border: float

    def sample(self, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Bilinear albedo at plane points."""
        col = ((r - self.r0) * self.ppm - 0.5).astype(np.float32)
        row = ((self.s0 - s) * self.ppm - 0.5).astype(np.float32)
        return cv2.remap(self.albedo, col, row, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=self.border)

    def painting(self) -> np.ndarray:
        """The albedo texels of the painting (the varnished rectangle at the centre)."""
        half_w, half_h = self.varnish
        cols = np.round((np.array([-half_w, half_w]) - self.r0) * self.ppm).astype(int)
        rows = np.round((self.s0 - np.array([half_h, -half_h])) * self.ppm).astype(int)
        return self.albedo[rows[0]:rows[1], cols[0]:cols[1]]

    def varnished(self, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Where the plane points lie on the varnished painting."""
        if self.varnish is None:
            return np.zeros(r.shape, bool)
        return (np.abs(r) < self.varnish[0]) & (np.abs(s) < self.varnish[1])


def wall_with_painting(albedo: np.ndarray, width: float, *, ppm: float, extent: float,
                       seed: int) -> PlaneTexture:
    """The painting (grey albedo ``(h, w)`` in linear units, ``width`` metres wide, centred)
    on a plain wall ``2 * extent`` metres square with a faint paint grain; the painting gets a
    fine canvas grain (:data:`CANVAS_GRAIN`) below camera B's resolution."""
    side = int(round(2 * extent * ppm))
    rng = np.random.default_rng([seed, 111])
    wall = WALL_ALBEDO * (1 + WALL_GRAIN * _grain(rng, side, side, WALL_GRAIN_M * ppm))
    pw = int(round(width * ppm))
    ph = int(round(width * albedo.shape[0] / albedo.shape[1] * ppm))
    patch = cv2.resize(np.asarray(albedo, np.float32), (pw, ph), interpolation=cv2.INTER_CUBIC)
    patch *= 1 + CANVAS_GRAIN * _grain(rng, ph, pw, CANVAS_GRAIN_M * ppm)
    y0, x0 = (side - ph) // 2, (side - pw) // 2
    wall[y0:y0 + ph, x0:x0 + pw] = np.clip(patch, 0, 1)
    return PlaneTexture(wall.astype(np.float32), (width / 2, width * ph / pw / 2), -extent,
                        extent, ppm, WALL_ALBEDO)


def _grain(rng: np.random.Generator, h: int, w: int, sigma_px: float) -> np.ndarray:
    """Unit-variance Gaussian noise correlated over ``sigma_px``."""
    g = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0),
                         max(sigma_px, 0.3))
    return g / max(float(g.std()), 1e-9)


@dataclass(frozen=True)
class LedLighting:
    """Phone A's LED lighting its own view (``None`` fields: effect off)."""

    exponent: float = 0.0  # LED angular fall-off about the optical axis
    ambient: float = 0.0  # room irradiance / the LED's at ``height`` straight below
    height: float = 0.3


PoseFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


class PhoneView:
    """Render phone A's frames of a :class:`PlaneTexture`.

    Parameters
    ----------
    matrix, dist, size
        Camera matrix, radial distortion ``(k1, k2)`` and ``(w, h)``.
    texture : PlaneTexture
    lighting : LedLighting or None
        ``None``: the board simulation's even lighting (``30 + 190 * albedo`` code values and
        the lens's cos^4 vignetting).
    readout_s : float
        Rolling-shutter readout time (0: global shutter).
    shutter_s, samples : float, int
        Open-shutter time and the instants averaged over it (motion blur).
    distance : float
        Typical distance to the plane, metres: the texture is low-passed to a pixel's footprint
        there (a pixel integrates its area; point samples of a finer texture alias).
    """

    def __init__(self, matrix: np.ndarray, dist: tuple[float, float], size: tuple[int, int],
                 texture: PlaneTexture, lighting: LedLighting | None, *, readout_s: float = 0.0,
                 shutter_s: float = 0.0, samples: int = 1, distance: float = 0.3) -> None:
        footprint = texture.ppm * distance / float(matrix[0, 0])  # texels per pixel
        sigma = PIXEL_AREA_SIGMA * footprint
        if sigma > 0.3:
            texture = replace(texture, albedo=cv2.GaussianBlur(texture.albedo, (0, 0), sigma))
        self.size, self.texture, self.lighting = size, texture, lighting
        self.rays = normalised_rays(matrix, dist, size).astype(np.float32)
        self.readout_s = readout_s
        self.offsets = shutter_s * (np.arange(samples) / max(samples - 1, 1) - 0.5) \
            if samples > 1 else np.zeros(1)
        cos2 = 1 / np.sum(self.rays**2, axis=-1)
        self.vignette = (cos2 * cos2).astype(np.float32)
        self.blur = OPTICS_BLUR_PX * size[0] / 1280
        u, v = np.meshgrid(np.arange(size[0], dtype=np.float32),
                           np.arange(size[1], dtype=np.float32))
        self.shade_maps = (u / SHADE_STRIDE, v / SHADE_STRIDE)

    def row_times(self, t: float) -> np.ndarray:
        """Read-out time of every row around the frame time ``t`` (the middle row at ``t``)."""
        h = self.size[1]
        return t + self.readout_s * (np.arange(h) / max(h - 1, 1) - 0.5)

    def radiance(self, centre: np.ndarray, r_wc: np.ndarray, led: np.ndarray,
                 led_on: np.ndarray) -> np.ndarray:
        """One instant: per-row camera centres ``(h, 3)``, axes ``(h, 3, 3)`` and LED positions
        ``(h, 3)`` (rows may differ: rolling shutter); linear image ``(h, w)`` float32."""
        f32 = np.float32
        d = np.matmul(self.rays, r_wc.transpose(0, 2, 1).astype(f32))  # (h, w, 3), plane axes
        c = centre.astype(f32)[:, :, None]  # (h, 3, 1): broadcast along each row
        t = -c[:, 2] / d[..., 2]
        r, s = c[:, 0] + t * d[..., 0], c[:, 1] + t * d[..., 1]
        albedo = self.texture.sample(r, s)
        if self.lighting is None:
            return albedo
        k = SHADE_STRIDE  # the shading is smooth: computed on every k-th pixel, interpolated
        diffuse, spec = self._shade(r[::k, ::k], s[::k, ::k], c[::k],
                                    r_wc[::k, :, 2].astype(f32), led[::k].astype(f32),
                                    led_on[::k].astype(f32))
        up = [cv2.remap(x, *self.shade_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
              for x in (diffuse, spec)]
        return np.float32(LIT_WHITE) * (albedo * up[0] + up[1])

    def _shade(self, r, s, c, axis, led, led_on) -> tuple[np.ndarray, np.ndarray]:
        """LED (Lambert + GGX varnish highlight, near-light fall-off, angular profile) and
        ambient light on the flat plane points ``(r, s, 0)``; ``c``: camera centres per row.
        Returns the factor of the albedo and the specular term (white = 1 straight below)."""
        light = self.lighting
        lx, ly, lz = led[:, :1] - r, led[:, 1:2] - s, led[:, 2:3]
        inv = 1 / np.sqrt(lx * lx + ly * ly + lz * lz)
        cos_l = np.clip(lz * inv, 0, None)
        emitted = np.float32(light.height**2) * led_on[:, None] * inv * inv
        if light.exponent:
            cos_a = -(axis[:, :1] * lx + axis[:, 1:2] * ly + axis[:, 2:3] * lz) * inv
            emitted *= np.clip(cos_a, 0, None) ** np.float32(light.exponent)
        vx, vy, vz = c[:, 0] - r, c[:, 1] - s, c[:, 2]
        vinv = 1 / np.sqrt(vx * vx + vy * vy + vz * vz)
        hx, hy, hz = lx * inv + vx * vinv, ly * inv + vy * vinv, lz * inv + vz * vinv
        cos_h2 = hz * hz / (hx * hx + hy * hy + hz * hz)
        a2 = np.where(self.texture.varnished(r, s), np.float32(VARNISH_ALPHA**2),
                      np.float32(WALL_ALPHA**2))
        ggx = a2 / (np.float32(np.pi) * (cos_h2 * (a2 - 1) + 1) ** 2)
        spec = np.float32(VARNISH_F0 / 4) * ggx / np.clip(vz * vinv, 0.05, None)
        led_term = cos_l * emitted
        return led_term + np.float32(light.ambient), np.float32(np.pi) * spec * led_term

    def frame(self, t: float, poses: PoseFn, rng: np.random.Generator,
              led_on: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """The uint8 grey frame at time ``t``; ``poses(times)`` gives camera centres, axes and
        LED positions at ``times``; ``led_on(times)`` 0/1 (default: always on)."""
        acc = np.zeros(self.size[::-1], np.float32)
        for dt in self.offsets:
            times = self.row_times(t + dt)
            centre, r_wc, led = poses(times)
            on = np.ones(len(times)) if led_on is None else led_on(times)
            acc += self.radiance(centre, r_wc, led, on)
        img = cv2.GaussianBlur(acc / len(self.offsets), (0, 0), self.blur)
        if self.lighting is None:
            dn = (30 + 190 * img) * self.vignette
        else:
            dn = 255 * linear_to_srgb(img * self.vignette)
        dn += rng.standard_normal(dn.shape).astype(np.float32) * np.sqrt(
            NOISE_DN**2 + SHOT_DN * np.clip(dn, 0, None))
        return np.clip(np.rint(dn), 0, 255).astype(np.uint8)

    def still(self, centre: np.ndarray, r_wc: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A frame from a still pose (calibration views)."""
        h = self.size[1]

        def fixed(times):
            return np.repeat(centre[None], h, 0), np.repeat(r_wc[None], h, 0), \
                np.repeat(centre[None], h, 0)

        return self.frame(0.0, fixed, rng)
