"""A browser's recording made readable by ``ltm sync`` / ``ltm ingest``: constant frame rate.

A phone's ``MediaRecorder`` writes variable-frame-rate video (WebM, 1 ms time base, frames
whenever the camera delivered one, no duration in its header). ``ltm sync`` and ``ltm ingest``
read a video as frames at one rate and refuse one whose time stamps skip frames. A joined
recording is therefore kept as it is when it already is constant-rate with a stated length, and
otherwise rewritten (:func:`rewrite_constant_rate`) at a common rate near its median: each
output frame is the latest recorded frame at or before its time (H.264 ``.mp4``, CRF
:data:`CRF`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ltmstore.core.errors import LtmError

RATES = (10, 12, 15, 24, 25, 30, 48, 50, 60, 90, 120, 240)  # the rates phones record at
CRF = 12  # H.264 quality of a rewrite (0 lossless .. 51): close to the upload's own quality
REGULAR_TOLERANCE_S = 1e-3  # a frame this close to its slot counts as on it (1 ms time bases)


@dataclass(frozen=True)
class VideoFacts:
    """What a recording's packets say: frame times (s, from the first), size, stated length."""

    times: np.ndarray
    size: tuple[int, int]
    declares_length: bool

    @property
    def rate(self) -> int:
        """The common rate nearest (in ratio) to the median frame rate."""
        steps = np.diff(self.times)
        steps = steps[steps > 0]
        median = 1.0 / float(np.median(steps)) if len(steps) else 30.0
        return min(RATES, key=lambda r: abs(np.log(r / median)))

    @property
    def regular(self) -> bool:
        """Every frame on its slot of :attr:`rate` and none missing."""
        slots = np.arange(len(self.times)) / self.rate
        return bool(np.all(np.abs(self.times - slots) <= REGULAR_TOLERANCE_S))


def probe(path: str | os.PathLike, what: str) -> VideoFacts:
    """Frame times, size and stated length of ``path``'s first video stream (packets only).

    Raises
    ------
    LtmError
        If FFmpeg cannot read it or it holds no frame.
    """
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            pts = [p.pts for p in container.demux(stream) if p.size and p.pts is not None]
            size = (stream.codec_context.width, stream.codec_context.height)
            declared = bool(stream.frames or stream.duration or container.duration)
            base = stream.time_base
    except (av.error.FFmpegError, IndexError, OSError) as exc:
        raise LtmError(f"{what} is not a readable video ({exc}); expected one MediaRecorder "
                       "recording sent in order") from exc
    if not pts:
        raise LtmError(f"{what} holds no video frame; expected a recording of a few seconds")
    times = np.sort(np.array(pts, dtype=np.float64)) * float(base)
    return VideoFacts(times=times - times[0], size=size, declares_length=declared)


def first_rate(path: str | os.PathLike) -> int | None:
    """The common rate of the frames in the start of a recording (its first chunk, which may
    end mid-frame), or None when it holds fewer than 3 readable frame times."""
    pts = list(_packet_times(path))
    if len(pts) < 3:
        return None
    times = np.sort(np.array(pts))
    return VideoFacts(times=times - times[0], size=(0, 0), declares_length=False).rate


def _packet_times(path: str | os.PathLike) -> Iterator[float]:
    """Time stamps (seconds) of the video packets up to the first that cannot be read (a first
    chunk ends mid-frame)."""
    import av

    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            base = float(stream.time_base)
            for packet in container.demux(stream):
                if packet.size and packet.pts is not None:
                    yield packet.pts * base
    except (av.error.FFmpegError, IndexError, OSError):
        return


def rewrite_constant_rate(src: str | os.PathLike, dst: str | os.PathLike, rate: int, *,
                          what: str) -> int:
    """Write ``src`` to ``dst`` (H.264 ``.mp4``) at ``rate`` frames per second: output frame
    ``k`` (time ``k / rate`` from the first frame) is the latest input frame at or before that
    time. ``dst`` is written beside and moved into place; nothing is left on failure.

    Returns
    -------
    int
        Frames written.
    """
    import av

    dst = Path(dst)
    tmp = dst.with_name(dst.name + ".tmp.mp4")
    try:
        with av.open(str(src)) as inp, av.open(str(tmp), "w", format="mp4") as out:
            written = _encode(inp, out, rate)
        os.replace(tmp, dst)
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        tmp.unlink(missing_ok=True)
        raise LtmError(f"{what} cannot be rewritten at {rate} frames per second ({exc}); "
                       "expected one recording sent in order") from exc
    return written


def _encode(inp, out, rate: int) -> int:
    source = inp.streams.video[0]
    stream = out.add_stream("libx264", rate=rate)
    width, height = source.codec_context.width // 2 * 2, source.codec_context.height // 2 * 2
    stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
    stream.codec_context.time_base = Fraction(1, rate)
    stream.options = {"crf": str(CRF), "preset": "veryfast"}
    k, first, previous = 0, None, None

    def emit(frame) -> None:
        nonlocal k
        copy = frame.reformat(width=width, height=height, format="yuv420p")
        copy.pts, copy.time_base = k, Fraction(1, rate)
        out.mux(stream.encode(copy))
        k += 1

    for frame in inp.decode(source):
        if frame.time is None:
            continue
        first = frame.time if first is None else first
        t = frame.time - first
        while previous is not None and k / rate + REGULAR_TOLERANCE_S < t:
            emit(previous)  # slots before this frame's time show the latest earlier frame
        previous = frame
    if previous is None:
        raise ValueError("no frame decoded")
    while k / rate <= previous.time - first + REGULAR_TOLERANCE_S:
        emit(previous)
    out.mux(stream.encode())
    return k
