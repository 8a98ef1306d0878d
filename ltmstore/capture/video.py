"""Decoding camera B's video: frames as 8-bit RGB, code values to linear light."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import decode

# A video whose decoded frame count falls short of its header's by more than this is truncated.
TRUNCATION_SLACK = (2, 0.02)  # frames, fraction of the declared count


def transfer_lut(transfer: str, bits: int = 8) -> np.ndarray:
    """Linear light of each code value of ``bits`` (8 or 16), as a ``(2**bits,)`` float32 table
    (see :func:`ltmstore.core.transfer.decode`)."""
    codes = np.arange(2**bits)
    return decode(codes if bits == 8 else codes * (255 / (2**bits - 1)), transfer)


class VideoReader:
    """Decode a video frame by frame with OpenCV, as a context manager yielding RGB frames.

    Parameters
    ----------
    path : Path
        The video file.

    Attributes
    ----------
    fps : float
        Frames per second from the container.
    frame_count : int or None
        The container's frame count, when it declares one (it may be approximate).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._cap = cv2.VideoCapture(str(path))
        if not self._cap.isOpened():
            self._fail("OpenCV cannot open it (not a video file, or an unsupported container "
                       "or codec; expected e.g. FFV1 .mkv or mp4v .mp4)")
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS))
        if not (np.isfinite(self.fps) and self.fps > 0):
            self._fail(f"its frame rate {self.fps!r} is not a positive number")
        count = self._cap.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if np.isfinite(count) and count > 0 else None

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self._cap.release()

    def __iter__(self):
        n = 0
        while True:
            ok, bgr = self._cap.read()
            if not ok or bgr is None:
                break
            n += 1
            yield bgr[..., ::-1]
        self._check_complete(n)

    def _check_complete(self, n: int) -> None:
        if n == 0:
            self._fail("it yields no frames")
        slack = max(TRUNCATION_SLACK[0], TRUNCATION_SLACK[1] * (self.frame_count or 0))
        if self.frame_count is not None and n < self.frame_count - slack:
            self._fail(f"it ends after {n} of the {self.frame_count} frames its header declares "
                       "(truncated or corrupt file?)")

    def _fail(self, why: str) -> None:
        self._cap.release()
        raise LtmError(f"video {str(self.path)!r} cannot be decoded: {why}")
