"""Write an acquisition folder (ARCHITECTURE.md section 3.1) from frames and poses."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import FORMAT
from ltmstore.core.dims import Plane
from ltmstore.core.errors import LtmError

FPS = 30.0


def prepare_folder(folder: Path, outputs: Iterable[str], *, overwrite: bool) -> Path:
    """Create ``folder`` or check that it may be written; with ``overwrite`` remove ``outputs``
    (the names an earlier simulation wrote there)."""
    if folder.exists() and not folder.is_dir():
        raise LtmError(f"output {str(folder)!r} exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()):
        if not overwrite:
            raise LtmError(f"output folder {str(folder)!r} is not empty; pass --overwrite to "
                           "replace an earlier simulation there")
        for name in outputs:
            target = folder / name
            if target.is_dir():
                shutil.rmtree(target)
            elif target.exists():
                target.unlink()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LtmError(f"cannot create output folder {str(folder)!r}: {exc.strerror or exc}") \
            from exc
    if not os.access(folder, os.W_OK):
        raise LtmError(f"output folder {str(folder)!r} is not writable")
    return folder


def video_name(lossy: bool) -> str:
    """``video.mkv`` (FFV1, lossless) or ``video.mp4`` (mp4v, lossy)."""
    return "video.mp4" if lossy else "video.mkv"


def write_video(path: Path, frames_rgb8: Iterable[np.ndarray], *, fps: float = FPS) -> int:
    """Write 8-bit RGB frames ``(H, W, 3)`` to ``path``; FFV1 for ``.mkv``, mp4v for ``.mp4``.

    Returns the number of frames written.
    """
    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if path.suffix == ".mp4" else "FFV1"))
    writer = None
    n = 0
    try:
        for frame in frames_rgb8:
            frame = np.asarray(frame)
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                raise ValueError(f"frames must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
            if writer is None:
                h, w = frame.shape[:2]
                writer = cv2.VideoWriter(str(path), fourcc, fps, (w, h), True)
                if not writer.isOpened():
                    raise LtmError(f"OpenCV cannot open a video writer for {str(path)!r}")
            writer.write(np.ascontiguousarray(frame[..., ::-1]))
            n += 1
    finally:
        if writer is not None:
            writer.release()
    return n


def write_poses(path: Path, t: np.ndarray, r: np.ndarray, s: np.ndarray, z: np.ndarray,
                p: np.ndarray | None = None, q: np.ndarray | None = None) -> None:
    """Write ``poses.csv`` with header ``t,r,s,z[,p,q]``."""
    cols = [t, r, s, z] + ([p, q] if p is not None and q is not None else [])
    header = "t,r,s,z" + (",p,q" if len(cols) == 6 else "")
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="",
               fmt="%.9g")


def write_acquisition_json(folder: Path, *, video: str, plane: Plane, transfer: str = "srgb",
                           extra: dict | None = None) -> None:
    """Write ``acquisition.json`` for a folder holding ``video`` and ``poses.csv``."""
    meta = {"format": FORMAT, "video": video, "poses": "poses.csv", "plane": plane.to_json(),
            "transfer": transfer}
    meta.update(extra or {})
    (folder / "acquisition.json").write_text(json.dumps(meta, indent=2) + "\n")


def write_h264(path: Path, frames_rgb8: Iterable[np.ndarray], *, fps: float = FPS,
               bitrate: int, preset: str = "medium") -> int:
    """Write 8-bit RGB frames as H.264 (libx264 via PyAV, yuv420p, High profile, a key frame
    every second) at ``bitrate`` bit/s, as a phone records; returns the frames written.
    ``preset`` is x264's speed for quality trade (``veryfast`` encodes a 4K frame about 3x
    sooner than ``medium``)."""
    from fractions import Fraction

    import av

    n = 0
    with av.open(str(path), "w") as container:
        stream = None
        for frame in frames_rgb8:
            frame = np.ascontiguousarray(frame)
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                raise ValueError(f"frames must be (H, W, 3) uint8, got {frame.shape} {frame.dtype}")
            if stream is None:
                stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
                stream.width, stream.height = frame.shape[1], frame.shape[0]
                stream.pix_fmt = "yuv420p"
                stream.bit_rate = int(bitrate)
                stream.options = {"profile": "high", "g": str(int(round(fps))),
                                  "preset": preset, "maxrate": str(int(bitrate * 1.5)),
                                  "bufsize": str(int(bitrate))}
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
            n += 1
        if stream is not None:
            for packet in stream.encode():
                container.mux(packet)
    return n
