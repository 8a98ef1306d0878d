"""Tiny synthetic acquisitions with known content, for the acquisition and ingest tests.

The scene is a fixed colour map (two colour halves, brighter towards the bottom rows) whose
brightness changes with a per-frame gain ``GAINS[i]`` (a permutation, so the frame order shows);
linear light is encoded with the sRGB curve (or kept linear) and quantised to 8 bits.

Poses cover ``[POSE_T0, POSE_T1]`` (frames 15..45 at 30 fps) with irregular times; ``r, s`` are
linear in time (so interpolation is exact); ``z`` leaves the plane (by 20 % of the height) for
frames 30..36; ``r`` leaves the plane rectangle for frames 41..45.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np

from ltmstore.core.dims import Plane, rgb_to_ycbcr
from ltmstore.synthetic.writer import FPS, write_acquisition_json, write_poses, write_video

H, W, N = 16, 20, 60
PLANE = Plane(r=(-0.5, 0.5), s=(-0.5, 0.5), height=0.5)
GAINS = 0.15 + 0.8 * ((np.arange(N) * 7) % N) / (N - 1)
COLOURS = np.array([[0.8, 0.4, 0.2], [0.2, 0.5, 0.9]])  # linear RGB of the left, right halves
POSE_T0, POSE_T1 = 0.49, 1.51
Z_OUT = (0.995, 1.205)  # light 20 % above the plane between these times
EXPECTED = {"n_frames": N, "n_valid": 19,
            "rejected": {"beyond_poses": 29, "out_of_plane": 7, "outside_bounds": 5,
                         "occluded": 0}}


def colour_map() -> np.ndarray:
    """(H, W, 3) linear RGB of the scene at gain 1."""
    rows = 0.6 + 0.4 * np.arange(H) / (H - 1)
    halves = COLOURS[(np.arange(W) >= W // 2).astype(int)]
    return rows[:, None, None] * halves[None, :, :]


def encode(linear: np.ndarray, transfer: str) -> np.ndarray:
    """Linear RGB in [0, 1] to 8-bit code values."""
    if transfer == "srgb":
        linear = np.where(linear <= 0.0031308, 12.92 * linear,
                          1.055 * linear ** (1 / 2.4) - 0.055)
    return np.round(np.clip(linear, 0, 1) * 255).astype(np.uint8)


def frames_rgb8(transfer: str = "srgb", n: int = N) -> list[np.ndarray]:
    base = colour_map()
    return [encode(g * base, transfer) for g in GAINS[:n]]


def expected_luminance(n: int = N) -> np.ndarray:
    """(n, H, W) true linear luminance."""
    return GAINS[:n, None, None] * rgb_to_ycbcr(colour_map())[..., 0]


def expected_chroma() -> np.ndarray:
    """(H, W, 2) true chroma ratios Cb/Y, Cr/Y."""
    ycc = rgb_to_ycbcr(colour_map())
    return ycc[..., 1:] / ycc[..., :1]


def r_of(t: np.ndarray) -> np.ndarray:
    return -0.31 + 0.6 * t  # leaves the plane (r > 0.5) after t = 1.35


def s_of(t: np.ndarray) -> np.ndarray:
    return 0.2 - 0.1 * t


def pose_times(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    inner = rng.uniform(POSE_T0, POSE_T1, 80)
    edges = [POSE_T0, POSE_T1, Z_OUT[0] - 0.01, Z_OUT[0], Z_OUT[1], Z_OUT[1] + 0.01]
    return np.unique(np.concatenate([inner, edges]))


def write_pose_file(path: Path, *, view: bool = False) -> None:
    t = pose_times()
    z = np.where((t >= Z_OUT[0]) & (t <= Z_OUT[1]), 1.2, 1.0) * PLANE.height
    pq = (0.1 * t, -0.1 * t) if view else (None, None)
    write_poses(path, t, r_of(t), s_of(t), z, *pq)


def make_acquisition(folder: Path, *, video: str = "video.mkv", transfer: str = "srgb",
                     n: int = N, extra: dict | None = None, view: bool = False) -> Path:
    """Write a synthetic acquisition folder and return it."""
    folder.mkdir(parents=True, exist_ok=True)
    assert write_video(folder / video, frames_rgb8(transfer, n)) == n
    write_pose_file(folder / "poses.csv", view=view)
    write_acquisition_json(folder, video=video, plane=PLANE, transfer=transfer, extra=extra)
    return folder


def frame_times(n: int = N) -> np.ndarray:
    return np.arange(n) / FPS


def tree_hashes(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# Light directions of the tiny capture: (lx, ly, lz) before normalisation.
DIRS = np.array([[0, 0, 1], [0.5, 0, 1], [0, -0.5, 1], [1, 1, 1], [-1, 0.2, 1], [0.2, 0.1, 2],
                 [0.1, 0.1, 1], [-0.3, -0.3, 1], [0.4, 0.2, 1], [3, 0, 1], [0, 0.3, 1]])
COLOUR = np.array([0.7, 0.5, 0.3])  # linear RGB of the tiny scene


def gains(n):
    return 0.2 + 0.6 * np.arange(n) / n


def write_capture(folder: Path, dirs=DIRS, *, trailing: str = "   ") -> Path:
    """Tiny PNG capture: image i is the constant colour COLOUR * gains[i] (sRGB encoded)."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"{len(dirs)}{trailing}"]
    for i, (d, g) in enumerate(zip(dirs, gains(len(dirs)), strict=True)):
        rgb = encode(np.broadcast_to(g * COLOUR, (6, 5, 3)), "srgb")
        assert cv2.imwrite(str(folder / f"im{i:02d}.png"), rgb[..., ::-1])
        lines.append(f"im{i:02d}.png {d[0]} {d[1]} {d[2]}{trailing}")
    path = folder / "dirs.lp"
    path.write_text("\n".join(lines) + "\n\n")
    return path
