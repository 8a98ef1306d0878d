"""Phone A's frames of a painting, rendered for the boardless tracking tests (issue 29):
``tests/capture/test_painting_track.py`` and ``tests/capture/test_painting_track_cli.py``.

The canvas scene's albedo, a 20 cm painting on a plain wall, warped from known poses (640 x 360,
focal 500 px: phone A's 65 degree field of view at a quarter of the pixels), with the LED's
fall-off, a moving saturating highlight, lens blur and noise.
"""

from __future__ import annotations

import cv2
import numpy as np

from ltmstore.capture.calibrate import Intrinsics
from ltmstore.capture.painting_track import PaintingMap
from ltmstore.core.dims import LUMA
from ltmstore.synthetic.raw import DOWN, rotation

SIZE, FOCAL = (640, 360), 500.0
K = np.array([[FOCAL, 0, SIZE[0] / 2 - 0.5], [0, FOCAL, SIZE[1] / 2 - 0.5], [0, 0, 1]])
OFFSET = (0.012, -0.004, 0.002)
WIDTH = 0.2  # m
WALL = 0.45
INTR = Intrinsics(SIZE, K, np.zeros(5))


def _plane_to_texture(n: int) -> np.ndarray:
    k = n / WIDTH
    return np.array([[k, 0, k * WIDTH / 2 - 0.5], [0, -k, k * WIDTH / 2 - 0.5], [0, 0, 1]])


def _extrinsics(led, r_wc):
    centre = np.asarray(led) - r_wc @ np.asarray(OFFSET)
    r_co = r_wc.T
    return centre, r_co, -r_co @ centre


def render(texture, led, r_wc, rng, highlight=160.0):
    """Phone A's grey frame: painting on a wall, LED fall-off and highlight, blur, noise."""
    centre, r_co, t = _extrinsics(led, r_wc)
    h = K @ np.column_stack([r_co[:, 0], r_co[:, 1], t]) @ np.linalg.inv(
        _plane_to_texture(texture.shape[1]))
    img = cv2.warpPerspective(texture, h, SIZE, flags=cv2.INTER_LINEAR, borderValue=WALL)
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    u, v = np.meshgrid(np.arange(SIZE[0]) - K[0, 2], np.arange(SIZE[1]) - K[1, 2])
    dn = (20 + 200 * img) * (1 + (u * u + v * v) / FOCAL**2) ** -2
    led = np.asarray(led)
    mirror = (centre[:2] * led[2] + led[:2] * centre[2]) / (led[2] + centre[2])
    q = K @ (r_co @ np.array([*mirror, 0.0]) + t)
    x, y = q[:2] / q[2] - K[:2, 2]
    dn += highlight * np.exp(-((u - x) ** 2 + (v - y) ** 2) / (2 * 25.0**2))
    dn += rng.normal(0, 2.0, dn.shape)
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


def visible_fraction(led, r_wc) -> float:
    """Fraction of the painting inside the frame."""
    _, r_co, t = _extrinsics(led, r_wc)
    g = np.linspace(-WIDTH / 2, WIDTH / 2, 21)
    rs = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    p = (K @ (r_co @ np.column_stack([rs, np.zeros(len(rs))]).T + t[:, None])).T
    x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    return float(np.mean((x > 0) & (x < SIZE[0]) & (y > 0) & (y < SIZE[1])))


def wave(n, *, reach=0.08, fps=30.0, t=None):
    """A hand's wave: LED positions (n, 3) and camera axes, 30 cm over the painting, at ``n``
    frames (or at the times ``t``)."""
    t = np.arange(n) / fps if t is None else np.asarray(t, np.float64)
    r = reach * np.sin(2 * np.pi * 0.5 * t)
    s = 0.75 * reach * np.sin(2 * np.pi * 0.17 * t + 0.5)
    z = 0.3 + 0.01 * np.sin(2 * np.pi * 0.4 * t)
    yaw = 0.3 * np.sin(0.3 * t)
    tx, ty = np.radians(2) * np.sin(2 * t + 1), np.radians(2) * np.sin(1.4 * t)
    r_wc = [rotation(2, a) @ rotation(0, b) @ rotation(1, c) @ DOWN
            for a, b, c in zip(yaw, tx, ty, strict=True)]
    return t, np.column_stack([r, s, z]), r_wc



def make_painting() -> tuple[np.ndarray, PaintingMap]:
    """The painting's texture (640 x 640, grey 0-1) and its map (400 x 400 pixels)."""
    from ltmstore.synthetic.scenes import make_scene

    albedo = np.clip(make_scene("canvas", size=160).albedo @ LUMA, 0, 1).astype(np.float32)
    texture = cv2.resize(albedo, (640, 640), interpolation=cv2.INTER_LINEAR)
    picture = np.clip(np.rint(255 * cv2.resize(albedo, (400, 400))), 0, 255).astype(np.uint8)
    return texture, PaintingMap(picture, WIDTH)


def led_error_mm(got: np.ndarray, true: np.ndarray) -> np.ndarray:
    return 1e3 * np.linalg.norm(got - true, axis=-1)

