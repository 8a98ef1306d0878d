"""Synthetic dome captures of a known far-light surface (GGX or Beckmann lobes), written as
8-bit photographs and a ``.lp`` file, and the far-light store reconstructed from one."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ltmstore.core.store import open_store
from ltmstore.core.transfer import linear_to_srgb
from ltmstore.solve import physical
from ltmstore.stages.relight import relight

RINGS = {10: 18, 30: 12, 50: 10, 70: 8, 90: 1}  # SynthRTI's dome: elevation -> lights
FLICKER = 0.08  # relative spread of the flash's energy between photographs


def dome() -> np.ndarray:
    """Unit directions on the rings of :data:`RINGS`."""
    out = []
    for elevation, count in RINGS.items():
        azimuth = np.linspace(0, 2 * np.pi, count, endpoint=False) + elevation / 100
        e = np.radians(elevation)
        out += [[np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)] for a in azimuth]
    return np.array(out)


def surface(n: int, seed: int = 0) -> np.ndarray:
    """Per-channel GGX parameters ``(n, 3, 6)`` of ``n`` pixels: tilted, coloured, glossy."""
    rng = np.random.default_rng(seed)
    theta = np.empty((n, 3, 6))
    theta[..., 0:2] = rng.uniform(-0.4, 0.4, (n, 1, 2))
    theta[..., 2] = rng.uniform(0.2, 0.7, (n, 3))
    theta[..., 3] = rng.uniform(0.05, 0.3, (n, 1))
    theta[..., 4] = np.log(rng.uniform(0.15, 0.4, (n, 1)))
    theta[..., 5] = 0.01
    return theta


def flash(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 1 + FLICKER * rng.standard_normal(n)


def rendered(theta: np.ndarray, directions: np.ndarray, lobe: str = "ggx") -> np.ndarray:
    """Linear RGB ``(lights, pixels, 3)``."""
    lights = physical.far_lights(directions, len(theta), lobe)
    return np.moveaxis(physical.render_colour(theta.astype(np.float32), lights), 1, 0)


def write_capture(folder: Path, gains: np.ndarray, shape=(12, 14), lobe: str = "ggx") -> Path:
    """A dome capture of a surface (GGX lobes, or those of ``lobe``), 8-bit sRGB, photograph i
    scaled by ``gains[i]``."""
    directions = dome()
    rgb = rendered(surface(int(np.prod(shape))), directions, lobe) * gains[:, None, None]
    folder.mkdir()
    lines = [str(len(directions))]
    for i, (d, image) in enumerate(zip(directions, rgb, strict=True)):
        code = np.round(linear_to_srgb(image.clip(0, 1)) * 255).astype(np.uint8)
        assert cv2.imwrite(str(folder / f"im{i:02d}.png"), code.reshape(*shape, 3)[..., ::-1])
        lines.append(f"im{i:02d}.png {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"


def relit_error(store: Path, gains: np.ndarray) -> float:
    """RMS error (sRGB-encoded) of the store relit at its lights against the capture without
    flicker, at the flash's mean energy."""
    steady = rendered(surface(12 * 14), dome()).reshape(-1, 12, 14, 3) * gains.mean()
    relit = relight(open_store(store), directions=dome()).values
    return float(np.sqrt(np.mean((linear_to_srgb(relit) - linear_to_srgb(steady.clip(0, 1)))**2)))
