"""Decoding camera B's video: frames as 8-bit RGB, code values to linear light.

Frames are decoded with PyAV (FFmpeg), which reports what OpenCV hides: a damaged packet (an FFV1
slice whose CRC does not match, an MPEG-4 macroblock that cannot be parsed) is logged by the
decoder, and a frame decoded from it, or from the frames after it up to the next key frame that
predict from it, holds wrong values. Such frames, frames missing from the time stamps and a
stream that ends before the frame count its container declares are errors; with
``allow_dropped`` they are left out, counted (:attr:`VideoReader.dropped`) and reported.
A phone's 4:2:0 frames are converted to RGB by :func:`~ltmstore.capture.yuv.frame_to_rgb`
(smooth chroma, the frame's own matrix and range), not by FFmpeg's blocky 8-bit conversion.

A 4K H.264 frame at 700 Mbit/s takes 195 ms to decode on one core here, most of a pass over
the video. ``threaded=True`` lets FFmpeg decode several frames at once on its own threads,
beside the caller's work on the frames before them (the same pixels, bit for bit), but a
decoder thread's error message cannot be tied to its frame: a threaded reader raises
:class:`ThreadedDecodeUnclean` at the first sign of damage, and :func:`threaded_first` runs the
pass again on one thread, where every damaged frame is named as above.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import av
import av.logging
import numpy as np

from ltmstore.capture.yuv import frame_to_rgb
from ltmstore.core import memory
from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import transfer_lut

__all__ = ["ALLOW_OPTION", "ThreadedDecodeUnclean", "VideoReader", "codec_warning",
           "threaded_first", "transfer_lut"]  # transfer_lut: re-exported

ALLOW_OPTION = "--allow-dropped-frames"
T = TypeVar("T")
LOSSLESS_CODECS = frozenset({"ffv1", "rawvideo", "huffyuv", "ffvhuff", "utvideo", "magicyuv",
                             "png", "qtrle"})
# H.264 cost a simulated 720 px canvas's LTM (20 s, 44.4 dB uncompressed) 9.5 dB of SNR_Y at a
# phone's usual 0.27 bits per pixel, 3.9 at 1, 2.6 at 2 and 2.2 at 4 (bench/codec_bitrate.py;
# docs/two-phones.md, "Record at a high bitrate"): below 2, ingest warns.
FAIR_BITS_PER_PIXEL = 2.0


def codec_warning(encoding: dict) -> str | None:
    """A line for the user where camera B's video (:meth:`VideoReader.encoding`) is lossy below
    :data:`FAIR_BITS_PER_PIXEL`, else None."""
    bpp, codec = encoding.get("bits_per_pixel"), encoding.get("codec")
    if codec in LOSSLESS_CODECS or bpp is None or bpp >= FAIR_BITS_PER_PIXEL:
        return None
    return (f"camera B's video is {codec} at {bpp:.2f} bits per pixel: H.264 below "
            f"{FAIR_BITS_PER_PIXEL:g} cost a simulated capture's LTM 2.6 dB or more (9.5 dB at a "
            f"phone's usual 0.27; docs/two-phones.md, \"Record at a high bitrate\"): where the "
            f"phone offers a higher bitrate or ProRes, record with it")


class ThreadedDecodeUnclean(Exception):
    """A threaded :class:`VideoReader` met a damaged, missing or truncated frame (which one it
    cannot tell): decode the video again on one thread."""


def threaded_first(run: Callable[[bool], T]) -> T:
    """``run(True)``, a pass over a video with a threaded :class:`VideoReader`; when that meets
    damage, ``run(False)``: the same pass on one thread, which names the frames (and fails or
    drops them as the reader is told)."""
    try:
        return run(True)
    except ThreadedDecodeUnclean:
        return run(False)


class VideoReader:
    """Decode a video frame by frame, as a context manager yielding RGB frames.

    Parameters
    ----------
    path : Path
        The video file.
    allow_dropped : bool, default False
        Leave out damaged and missing frames (counted in :attr:`dropped`) instead of failing.
    threaded : bool, default False
        Decode on FFmpeg's frame threads; any damaged, missing or truncated frame then raises
        :class:`ThreadedDecodeUnclean` (see :func:`threaded_first`).

    Attributes
    ----------
    fps : float
        Frames per second from the container.
    frame_count : int or None
        The frame count the container declares (or its duration times ``fps``), when it does.
    dropped : dict
        Frames left out so far, per reason (``damaged``, ``missing``).

    Notes
    -----
    Opening one fixes glibc's mmap threshold for the process
    (:func:`ltmstore.core.memory.map_large_buffers`): frame-sized buffers are mapped on their
    own and unmapped when freed, instead of piling up in the heap.
    """

    def __init__(self, path: Path, *, allow_dropped: bool = False,
                 threaded: bool = False) -> None:
        memory.map_large_buffers()  # each decoded frame's buffers leave with the frame
        self.path = path
        self.allow_dropped = allow_dropped
        self.threaded = threaded
        self.dropped = {"damaged": 0, "missing": 0}
        # frames of packets that could not be decoded, counted as damaged: not missing again
        # where their time stamps leave the gap
        self._undecoded = 0
        try:
            self._container = av.open(str(path))
            self._stream = self._container.streams.video[0]
            if threaded:
                self._stream.thread_type = "AUTO"
        except (av.error.FFmpegError, OSError, IndexError):
            self._container = None
            self._fail("FFmpeg cannot open it (not a video file, or an unsupported container "
                       "or codec; expected e.g. FFV1 .mkv or mp4v .mp4)")
        rate = self._stream.average_rate or self._stream.guessed_rate
        self.fps = float(rate) if rate else float("nan")
        if not (np.isfinite(self.fps) and self.fps > 0):
            self._fail(f"its frame rate {self.fps!r} is not a positive number")
        self.frame_count = self._declared_count()

    def _declared_count(self) -> int | None:
        stream = self._stream
        if stream.frames:
            return int(stream.frames)
        if stream.duration is not None and stream.time_base is not None:
            return round(float(stream.duration * stream.time_base) * self.fps)
        if self._container.duration:
            return round(self._container.duration / av.time_base * self.fps)
        return None

    def encoding(self) -> dict:
        """The video's codec (FFmpeg's name) and its bits per pixel: the stream's bit rate (the
        container's where the stream does not say) over its pixels per second (None: unknown)."""
        context = self._stream.codec_context
        rate = self._stream.bit_rate or self._container.bit_rate
        pixels = context.width * context.height * self.fps
        return {"codec": context.name,
                "bits_per_pixel": round(rate / pixels, 4) if rate and pixels > 0 else None}

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._container is not None:
            self._container.close()

    def __iter__(self) -> Iterator[np.ndarray]:
        for _, rgb in self.frames():
            yield rgb

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(index, rgb)``: the frame's number on the video's clock (its time is
        ``index / fps``) and its ``(H, W, 3)`` uint8 RGB values; damaged or missing frames fail,
        or are skipped with ``allow_dropped``."""
        for index, frame in self.decoded():
            yield index, frame_to_rgb(frame)

    def decoded(self) -> Iterator[tuple[int, av.VideoFrame]]:
        """:meth:`frames` as FFmpeg decoded them, before any conversion."""
        expected, damaged_until_key = 0, False
        for index, frame, errors in self._decoded():
            if errors and self.threaded:
                raise ThreadedDecodeUnclean("; ".join(errors))
            damaged_until_key = bool(errors) or (damaged_until_key and not frame.key_frame)
            if index > expected and (gap := self._not_undecoded(index - expected)):
                self._drop("missing", gap, f"frames {expected} to {index - 1} are missing from "
                           "its time stamps")
            expected = max(expected, index + 1)
            if damaged_until_key:
                why = "; ".join(errors) or "it predicts from a damaged frame"
                self._drop("damaged", 1, f"frame {index} is damaged ({why})")
                continue
            yield index, frame
        self._check_complete(expected)

    def _decoded(self) -> Iterator[tuple[int, av.VideoFrame, list[str]]]:
        """Decoded frames with their index and the decoder's error messages."""
        level, skip = av.logging.get_level(), av.logging.get_skip_repeated()
        av.logging.set_level(av.logging.ERROR)  # FFmpeg's messages reach the capture
        # PyAV drops a message that repeats the last one: a second decode of the same damaged
        # video (ingest scans it before it reads it) would then look clean.
        av.logging.set_skip_repeated(False)
        try:
            with av.logging.Capture(local=not self.threaded) as logs:
                try:
                    yield from self._frames_logged(logs)
                finally:
                    self._settle_threads()
        finally:
            av.logging.set_level(level)
            av.logging.set_skip_repeated(skip)

    def _settle_threads(self) -> None:
        """Let FFmpeg's decoding threads finish, their messages captured: flushing the decoder
        waits for them with the GIL released. Without it, a thread could still be logging a
        damaged frame when the decoder is freed, which waits for it with the GIL held while
        PyAV's log callback waits for the GIL (a suite run hung so on a damaged mp4; 1 run of
        3,000 reads beside two busy processes did), or log after the level is restored (PyAV's
        callback then prints a traceback)."""
        if self.threaded:
            self._stream.codec_context.flush_buffers()

    def _frames_logged(self, logs: list) -> Iterator[tuple[int, av.VideoFrame, list[str]]]:
        start, base = self._stream.start_time or 0, self._stream.time_base
        n = 0
        for packet in self._packets():
            for frame in self._decode(packet, n):
                errors = [f"{name}: {text.strip()}" for level, name, text in logs
                          if level <= av.logging.ERROR]
                logs.clear()
                index = n if frame.pts is None else round(
                    float((frame.pts - start) * base) * self.fps)
                n += 1
                yield index, frame, errors

    def _packets(self) -> Iterator[av.Packet]:
        """The stream's packets, ending at the first that cannot be read (a truncated file:
        the frame count check names it)."""
        try:
            yield from self._container.demux(self._stream)
        except av.error.FFmpegError:
            return

    def _decode(self, packet: av.Packet, n: int) -> list[av.VideoFrame]:
        try:
            return packet.decode()
        except av.error.FFmpegError as exc:
            self._drop("damaged", 1, f"the packet after frame {n} cannot be decoded ({exc})")
            self._undecoded += 1
            return []

    def _not_undecoded(self, absent: int) -> int:
        """How many of ``absent`` frames are missing, not the frames of packets already counted
        as damaged."""
        known = min(absent, self._undecoded)
        self._undecoded -= known
        return absent - known

    def _check_complete(self, n: int) -> None:
        if self.threaded and (n == 0 or self.frame_count is None or n < self.frame_count):
            raise ThreadedDecodeUnclean(f"{n} frames")
        if n == 0:
            self._fail("it yields no frames")
        if self.frame_count is None:
            if not self.allow_dropped:
                self._fail("its container declares neither a frame count nor a duration "
                           f"(damaged header?), so a truncation cannot be found; pass "
                           f"{ALLOW_OPTION} to ingest what it holds")
            return
        if n < self.frame_count and (absent := self._not_undecoded(self.frame_count - n)):
            self._drop("missing", absent, f"it ends after {n} of the {self.frame_count} frames "
                       "its header declares (truncated or corrupt file?)")

    def _drop(self, reason: str, count: int, why: str) -> None:
        if self.threaded:
            raise ThreadedDecodeUnclean(why)
        if not self.allow_dropped:
            self._fail(f"{why}; pass {ALLOW_OPTION} to leave such frames out")
        self.dropped[reason] += count

    def _fail(self, why: str) -> None:
        if self._container is not None:
            self._container.close()
        raise LtmError(f"video {str(self.path)!r} cannot be decoded: {why}")
