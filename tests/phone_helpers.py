"""Phone effects put on a clean simulated acquisition, for the ingest tests.

A clean ``ltm simulate`` folder is decoded to linear RGB, changed by a known effect (camera B's
gain drift per channel, a room light with an LED-off lead, lens distortion) and written back as
a new acquisition folder with the project's writer; its poses stay (shifted by the lead), so the
truth of the clean folder is the truth of the variant.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.calibrate import Intrinsics
from ltmstore.capture.video import VideoReader
from ltmstore.core.transfer import encode, transfer_lut
from ltmstore.synthetic.writer import write_video


def read_linear(folder: Path) -> tuple[np.ndarray, float]:
    """``(n, H, W, 3)`` linear RGB frames of an acquisition's video and its frame rate."""
    meta = json.loads((folder / "acquisition.json").read_text())
    lut = transfer_lut(meta["transfer"])
    with VideoReader(folder / meta["video"]) as video:
        frames = np.stack([lut[rgb] for _, rgb in video.frames()])
        return frames, video.fps


def write_variant(src: Path, dst: Path, frames: np.ndarray, fps: float, *,
                  time_offset: float = 0.0, extra: dict | None = None) -> Path:
    """A copy of acquisition ``src`` at ``dst`` with video frames ``frames`` (linear RGB)."""
    dst.mkdir(parents=True, exist_ok=True)
    meta = json.loads((src / "acquisition.json").read_text())
    shutil.copy(src / meta["poses"], dst / meta["poses"])
    meta["video"] = "video.mkv"
    write_video(dst / "video.mkv", (encode(np.clip(f, 0, 1), meta["transfer"]) for f in frames),
                fps=fps)
    meta.update(extra or {})
    if time_offset:
        meta["time_offset"] = time_offset
    (dst / "acquisition.json").write_text(json.dumps(meta, indent=2))
    return dst


def drift_gains(n: int, fps: float, *, exposure: float, white_balance: float) -> np.ndarray:
    """``(n, 3)`` smooth gains per frame and channel: an exposure wave of relative amplitude
    ``exposure`` (period 7 s) and opposite red/blue wanders of ``white_balance`` (9 s, 11 s)."""
    t = np.arange(n) / fps
    log_g = exposure * np.sin(2 * np.pi * t / 7.0)[:, None] * np.ones(3)
    log_g[:, 0] += white_balance * np.sin(2 * np.pi * t / 9.0)
    log_g[:, 2] -= white_balance * np.sin(2 * np.pi * t / 11.0 + 1.0)
    return np.exp(log_g)


def room_light(frames: np.ndarray, strength: float) -> np.ndarray:
    """An ambient image: the painting under its average light, at ``strength`` times the mean
    lit level, with a gentle left-to-right gradient (a window)."""
    mean = frames.mean(axis=0)
    ramp = np.linspace(0.6, 1.4, mean.shape[1])[None, :, None]
    return (strength * mean * ramp).astype(np.float32)


def with_lead(frames: np.ndarray, ambient: np.ndarray, lead: int, rng: np.random.Generator,
              noise: float = 0.002) -> np.ndarray:
    """``lead`` LED-off frames (room light and sensor noise) then the lit frames plus the room
    light."""
    dark = ambient[None] + rng.normal(0, noise, (lead, *ambient.shape)).astype(np.float32)
    return np.concatenate([dark, frames + ambient[None]])


def camera(width: int, height: int, k1: float, k2: float = 0.0) -> Intrinsics:
    """A pinhole camera of the frame size (60 degrees across) with radial distortion."""
    f = width / (2 * np.tan(np.radians(30)))
    matrix = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return Intrinsics((width, height), matrix, np.array([k1, k2, 0.0, 0.0, 0.0]), 0.1)


def distort(frames: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Frames as the distorting lens records them: each recorded pixel shows the ideal image
    where the lens bends its ray from."""
    w, h = intr.image_size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.stack([xx.ravel(), yy.ravel()], axis=1)[:, None, :]
    ideal = cv2.undistortPoints(pts, intr.matrix, intr.distortion, P=intr.matrix)
    map_x = ideal[:, 0, 0].reshape(h, w).astype(np.float32)
    map_y = ideal[:, 0, 1].reshape(h, w).astype(np.float32)
    return np.stack([cv2.remap(f, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
                     for f in frames])
