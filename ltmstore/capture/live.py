"""A capture guided live (``ltm capture FOLDER``): the session behind the server's routes.

:class:`LiveSession` holds what the two phones have sent so far and writes the acquisition
folder. Phone A's frames are tracked one by one as they arrive (the project's own tracker:
:func:`ltmstore.capture.track.track_frame` on the ChArUco board, or the painting tracker); the
placed LED positions give the coverage of the lattice the capture heads for, counted by
:func:`ltmstore.core.binning.bin_positions`, the function ``ltm reconstruct`` counts ``K / M``
with (same validity: the LED inside the plane rectangle and within the height tolerance), and
the SNR to expect at that coverage (:mod:`ltmstore.capture.expected_snr`). The positions are
counted as ``ltm ingest`` will use them: the path sampled at camera B's frame rate, linearly
between tracked positions (:func:`path_samples`). The live frames serve this feedback only.

Both phones also record their camera (``MediaRecorder``) and upload the recording in numbered
chunks, each written atomically, so that a dropped connection loses nothing already sent. At
each phone's finish the chunks are joined; camera B's, where it is not constant-rate (a
browser's never is), is rewritten at a constant rate (:mod:`ltmstore.capture.constant_rate`);
phone A's is kept as sent and tracked whole (``ltm track``'s tracker, every frame at its own
time) for the poses.

The folder (an ordinary acquisition, ARCHITECTURE.md section 3.1, once finished)::

    CAPTURE_INCOMPLETE     while the capture is under way (one line); removed last
    .capture/              work files: a_chunks/N.part, b_chunks/N.part (removed when finished)
    video_b.mp4|.mkv|...   camera B's video (POST /api/b/finish)
    phone_a.webm|.mkv|...  phone A's video as recorded (POST /api/a/finish)
    poses.csv              LED t,r,s,z, every frame of phone A's video tracked (as `ltm track`),
                           t on that video's clock
    poses.frames.csv       every frame's status (as `ltm track`)
    acquisition.json       written last, atomically (POST /api/finish)

The clock offset between the two phones is not known here: ``ltm sync FOLDER`` estimates it.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.acquisition import FORMAT, INCOMPLETE_MARKER, write_text_atomic
from ltmstore.capture.calibrate import Intrinsics
from ltmstore.capture.constant_rate import first_rate, probe, rewrite_constant_rate
from ltmstore.capture.expected_snr import expected_snr, source
from ltmstore.capture.track import FramePose, write_tracks
from ltmstore.core.binning import bin_positions
from ltmstore.core.dims import Lattice, Plane
from ltmstore.core.errors import LtmError

WORK = ".capture"
PLACED = ("ok", "out_of_plane")  # statuses with a trustworthy LED position
VIDEO_TYPES = {"video/webm": ".webm", "video/mp4": ".mp4", "video/x-matroska": ".mkv",
               "video/quicktime": ".mov"}
PHONES = {"a": ("phone A", "phone_a"), "b": ("camera B", "video_b")}  # who, video file stem
MAX_CHUNKS = 100_000
INGEST_MAX_POSE_GAP_S = 0.25  # = stages.frames.MAX_POSE_GAP_S (capture/ cannot import it)
LIVE_MAX_GAP_S = 1.0  # live samples this far apart are bridged: phone A's video fills them
DEFAULT_RATE = 30  # camera B's frame rate until its first chunk tells it
INCOMPLETE_TEXT = ("capture under way or interrupted (ltm capture); camera B's video, phone A's "
                   "poses or acquisition.json may be missing")

Tracker = Callable[[np.ndarray, float], FramePose]
VideoTracker = Callable[[Path, tuple[int, int]], list[FramePose]]


@dataclass(frozen=True)
class LiveConfig:
    """What the capture heads for.

    Attributes
    ----------
    plane : Plane
        The illumination plane (rectangle and height), written to ``acquisition.json``.
    lattice : (int, int)
        Cells ``(R, S)`` the coverage is counted on (``ltm reconstruct --lattice RxS``).
    target_km : float
        ``K / M`` at which the capture is "enough".
    height_tolerance : float
        Largest ``|z - plane.height|`` of a usable frame (as ``ltm ingest``'s z tolerance).
    tracker : str
        ``"board"`` or ``"painting"``.
    transfer : str
        How camera B's code values encode light (``acquisition.json`` ``transfer``).
    """

    plane: Plane
    lattice: tuple[int, int]
    target_km: float
    height_tolerance: float
    tracker: str = "board"
    transfer: str = "srgb"

    def to_json(self) -> dict:
        """The page's ``/api/config`` answer."""
        return {"lattice": list(self.lattice),
                "plane": {"r": list(self.plane.r), "s": list(self.plane.s),
                          "height": self.plane.height},
                "target_km": self.target_km, "tracker": self.tracker,
                "height_tolerance": self.height_tolerance, "expected_snr_source": source()}


class RequestError(LtmError):
    """A request the session refuses, with its HTTP status (400, 409...)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


class LiveSession:
    """One capture into ``folder``: token, phone A's tracking and coverage, camera B's chunks.

    Parameters
    ----------
    folder : path
        The acquisition folder: created, or an existing empty folder.
    config : LiveConfig
        Plane, lattice, target and tolerances.
    tracker : callable
        A factory, keyed by image size, of ``(grey uint8 image, t) -> FramePose`` (the live
        frames): see :func:`board_tracker`.
    video_tracker : callable, optional
        ``(video path, frame size) -> [FramePose]``, every frame of phone A's recorded video
        (:func:`board_video_tracker`); without it phone A cannot finish.
    token : str, optional
        The session's secret (default: 32 random bytes, URL-safe).

    Methods are thread-safe (one lock); each raises :class:`RequestError` for a bad request.
    """

    def __init__(self, folder: str | os.PathLike, config: LiveConfig,
                 tracker: Callable[[tuple[int, int]], Tracker], *,
                 video_tracker: VideoTracker | None = None, token: str | None = None):
        self.folder = Path(folder)
        self.config = config
        self.token = token or secrets.token_urlsafe(32)
        self.lattice = Lattice.from_plane(config.plane, config.lattice)
        self._make_tracker = tracker
        self._track_video = video_tracker
        self._trackers: dict[tuple[int, int], Tracker] = {}
        self._lock = threading.Lock()
        self.poses: list[FramePose] = []  # every live frame of phone A, in order (page times)
        self.video_poses: list[FramePose] | None = None  # phone A's whole video, once finished
        self.mime: dict[str, str] = {}  # per phone, its recording's MIME type
        self._finishing: set[str] = set()
        self.b_rate: int | None = None  # camera B's frame rate, from its first chunk
        self.offset: float | None = None  # t_B = t_A + offset, once both videos are in
        self.offset_note: str | None = None  # why it is not known, when it could not be had
        self.b_finished: dict | None = None
        self.a_finished: dict | None = None
        self.finished = False
        self.listeners: list[Callable[[dict], None]] = []

    # -- the folder --------------------------------------------------------------------------

    def start(self) -> None:
        """Create the folder (or take an empty one) and mark it incomplete."""
        folder = self.folder
        if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
            raise LtmError(f"capture folder {str(folder)!r} exists and is not empty; expected a "
                           "new or empty folder (a capture never overwrites one)")
        try:
            (folder / WORK / "a_chunks").mkdir(parents=True, exist_ok=True)
            (folder / WORK / "b_chunks").mkdir(exist_ok=True)
        except OSError as exc:
            raise LtmError(f"cannot create capture folder {str(folder)!r}: "
                           f"{exc.strerror or exc}") from exc
        write_text_atomic(folder / INCOMPLETE_MARKER, INCOMPLETE_TEXT + "\n", what="marker")

    def check_token(self, value: str | None) -> bool:
        """Whether ``value`` is the session's token (constant-time comparison)."""
        return bool(value) and secrets.compare_digest(value.encode(), self.token.encode())

    # -- phone A -------------------------------------------------------------------------------

    def add_frame(self, jpeg: bytes, t: float) -> dict:
        """Track one JPEG frame of phone A taken at page time ``t`` (seconds); the answer of
        ``POST /api/a/frame``."""
        if not math.isfinite(t):
            raise RequestError(f"X-Frame-Time {t!r} must be a finite number of seconds")
        gray = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise RequestError(f"frame of {len(jpeg)} bytes is not a JPEG image")
        with self._lock:
            self._check_open(self.a_finished, "phone A")
            if self.poses and t <= self.poses[-1].t:
                raise RequestError(f"X-Frame-Time {t!r} does not come after the previous frame's "
                                   f"{self.poses[-1].t!r}; expected increasing times", 409)
            size = (gray.shape[1], gray.shape[0])
            if size not in self._trackers:
                self._trackers[size] = self._make_tracker(size)
            pose = self._flag_height(self._trackers[size](gray, t))
            self.poses.append(pose)
            answer = {"t": t, "placed": pose.status in PLACED,
                      "led": [float(v) for v in pose.led] if pose.status in PLACED else None,
                      "warning": self._warning(pose), **self._coverage()}
        self._notify()
        return answer

    def _flag_height(self, pose: FramePose) -> FramePose:
        if pose.status == "ok" and not self._in_height(pose.led[2]):
            return replace(pose, status="out_of_plane")
        return pose

    def _in_height(self, z: float) -> bool:
        return abs(z - self.config.plane.height) <= self.config.height_tolerance

    def _warning(self, pose: FramePose) -> str | None:
        if pose.status not in PLACED:
            return "lost"
        return None if self._in_height(pose.led[2]) else "height"

    def binning(self):
        """The :class:`~ltmstore.core.binning.Binning` of the path as ``ltm ingest`` will
        sample it (:func:`path_samples`): phone A's whole-video poses once it finished (gaps
        as ingest bridges them), the live frames until then (gaps up to
        :data:`LIVE_MAX_GAP_S`, which the video fills), at camera B's rate."""
        dense = self.video_poses is not None
        placed = [p for p in (self.video_poses if dense else self.poses) if p.status in PLACED]
        t = np.array([p.t for p in placed])
        led = np.array([p.led for p in placed]).reshape(-1, 3)
        if self.offset is not None:  # both videos in: camera B's own frames, as ingest
            frames_b = np.arange(self.b_finished["frames"]) / self.b_finished["fps"]
            led = path_at(t, led, frames_b - self.offset, INGEST_MAX_POSE_GAP_S)
        else:
            rate = (self.b_finished or {}).get("fps") or self.b_rate or DEFAULT_RATE
            led = path_samples(t, led, rate, INGEST_MAX_POSE_GAP_S if dense else LIVE_MAX_GAP_S,
                               keep_samples=not dense)
        r, s, z = led.T
        valid = ((np.abs(z - self.config.plane.height) <= self.config.height_tolerance)
                 & self.config.plane.contains(r, s))
        return bin_positions(self.lattice, (r, s), valid)

    def _coverage(self) -> dict:
        binning = self.binning()
        snr = expected_snr(binning.ratio)
        return {"coverage": {"covered": binning.k, "cells": binning.m,
                             "k_over_m": binning.ratio},
                "expected_snr_db": snr.db, "expected_snr_spread_db": snr.spread_db,
                "expected_snr_measured": snr.measured,
                "enough": binning.ratio >= self.config.target_km,
                "frames": len(self.poses),
                "placed_frames": sum(p.status in PLACED for p in self.poses)}

    def state(self) -> dict:
        """The answer of ``GET /api/state``."""
        with self._lock:
            binning = self.binning()
            cells = np.argwhere(binning.observed)
            return {"path": [[p.t, *map(float, p.led)] for p in self.poses if p.status in PLACED],
                    **self._coverage(), "covered_cells": cells.tolist(),
                    "b": {**self._chunk_counts("b"), "finished": self.b_finished is not None},
                    "a": {**self._chunk_counts("a"), "finished": self.a_finished is not None},
                    "time_offset": self.offset, "time_offset_note": self.offset_note,
                    "finished": self.finished}

    def finish_a(self, chunks: int) -> dict:
        """Phone A is done: its recording (chunks ``0 .. chunks - 1``) joined into
        ``phone_a.*`` as sent and tracked whole into ``poses.csv`` + ``poses.frames.csv``.

        Phone A's video is not made constant-rate: the tracker reads each frame's own time
        (:func:`ltmstore.capture.board.video_frames`), which a rewrite would round to its slot
        (up to a frame interval: millimetres of the LED's path), and only camera B's video is
        read at one rate (``ltm sync``, ``ltm ingest``)."""
        if self._track_video is None:
            raise RequestError("this server cannot track phone A's video (no video tracker)",
                               500)
        return self._finish_phone("a", chunks, self._finish_a_video)

    def _finish_a_video(self, video: Path, facts) -> dict:
        try:
            results = increasing([self._flag_height(p)
                                  for p in self._track_video(video, facts.size)])
        except LtmError as exc:
            raise RequestError(str(exc), 409) from exc
        placed = sum(p.status in PLACED for p in results)
        if placed < 2:
            raise RequestError(f"phone A's video has {placed} placed frame(s) of "
                               f"{len(results)}; expected the light tracked in at least 2", 409)
        write_tracks(self.folder / "poses.csv", results)
        with self._lock:
            self.video_poses = results
        return {"poses": "poses.csv", "placed_frames": placed}

    def finish_b(self, chunks: int) -> dict:
        """Camera B is done: its chunks ``0 .. chunks - 1`` joined into ``video_b.*``."""
        return self._finish_phone("b", chunks, lambda video, facts: {})

    # -- the phones' recordings -----------------------------------------------------------------

    def add_chunk(self, who: str, index: int, data: bytes, mime: str | None) -> dict:
        """Store chunk ``index`` of ``who``'s (``"a"``, ``"b"``) recording (idempotent)."""
        if not 0 <= index < MAX_CHUNKS:
            raise RequestError(f"chunk index {index} must lie in 0-{MAX_CHUNKS - 1}")
        with self._lock:
            self._check_open(self._done(who), PHONES[who][0])
            if mime:
                self.mime.setdefault(who, mime)
            part = self._work(f"{who}_chunks", f"{index:06d}.part")
            put(part, data)
            if who == "b" and index == 0:
                self.b_rate = first_rate(part)
            received = self._chunk_counts(who)["chunks"]
        self._notify()
        return {"index": index, "received": received}

    def _chunk_counts(self, who: str = "b") -> dict:
        parts = list((self.folder / WORK / f"{who}_chunks").glob("*.part"))
        return {"chunks": len(parts), "bytes": sum(p.stat().st_size for p in parts)}

    def _done(self, who: str) -> dict | None:
        return self.a_finished if who == "a" else self.b_finished

    def _finish_phone(self, who: str, chunks: int, then: Callable[[Path, object], dict]) -> dict:
        """Join ``who``'s chunks (camera B's made constant-rate), run ``then(video, facts)``
        and, once both videos are in, estimate their clock offset (outside the lock: the other
        phone keeps uploading); only then record the answer, so that POST /api/finish cannot
        count before the offset is known."""
        name, stem = PHONES[who]
        with self._lock:
            if self._done(who) is not None:
                return self._done(who)
            self._check_open(None, name)
            if who in self._finishing:
                raise RequestError(f"{name} is finishing already; ask again in a moment", 409)
            if not 0 < chunks <= MAX_CHUNKS:
                raise RequestError(f"chunks={chunks} must lie in 1-{MAX_CHUNKS}")
            self._finishing.add(who)
        try:
            joined = self._join(who, chunks)
            video, facts, frames = settle_video(joined, self.folder / stem, f"{name}'s recording",
                                                constant_rate=who == "b")
            answer = {"ok": True, "video": video.name, "frames": frames, "fps": facts.rate,
                      **then(video, facts)}
            with self._lock:
                other = self.b_finished if who == "a" else self.a_finished
            if other is not None:  # both videos in: before either counts as finished
                self._estimate_offset(video if who == "b" else self.folder / other["video"])
            with self._lock:
                if who == "a":
                    self.a_finished = answer
                else:
                    self.b_finished = answer
        finally:
            with self._lock:
                self._finishing.discard(who)
        self._notify()
        return answer

    def _estimate_offset(self, video_b: Path) -> None:
        """The clock offset between the two videos as ``ltm sync`` estimates it (not written:
        ``ltm sync FOLDER`` records it), so that the coverage counts camera B's own frames."""
        from ltmstore.capture.acquisition import Poses
        from ltmstore.capture.sync import video_offset

        placed = [p for p in self.video_poses if p.status in PLACED]
        led = np.array([p.led for p in placed])
        axis = np.array([p.axis for p in placed])  # as poses.csv has it (write_tracks)
        poses = Poses(t=np.array([p.t for p in placed]), r=led[:, 0], s=led[:, 1], z=led[:, 2],
                      axis=axis if np.isfinite(axis).all() else None)
        try:
            result = video_offset(video_b, self.config.transfer, poses, self.config.plane)
        except (LtmError, ValueError) as exc:  # no usable signal: count on phone A's clock
            self.offset_note = str(exc)
            return
        with self._lock:
            self.offset = float(result["time_offset"])

    def _join(self, who: str, chunks: int) -> Path:
        parts = [self._work(f"{who}_chunks", f"{i:06d}.part") for i in range(chunks)]
        missing = [str(i) for i, p in enumerate(parts) if not p.is_file()]
        if missing:
            shown = ", ".join(missing[:20]) + (" ..." if len(missing) > 20 else "")
            raise RequestError(f"chunks {shown} missing", 409)
        joined = self.folder / WORK / (f"{who}_joined" + video_suffix(self.mime.get(who)))
        with open(joined, "wb") as out:
            for part in parts:
                with open(part, "rb") as fh:
                    shutil.copyfileobj(fh, out)
        return joined

    # -- the whole capture -----------------------------------------------------------------------

    def finish(self) -> dict:
        """Both phones done: write ``acquisition.json`` last, then remove the marker."""
        with self._lock:
            if self.finished:
                return {"ok": True, "folder": str(self.folder)}
            waiting = [who for who, done in (("phone A", self.a_finished),
                                             ("camera B", self.b_finished)) if done is None]
            if waiting:
                raise RequestError(f"{' and '.join(waiting)} not finished yet; expected "
                                   "POST /api/a/finish and /api/b/finish first", 409)
            binning = self.binning()
            meta = {"format": FORMAT, "video": self.b_finished["video"], "poses": "poses.csv",
                    "plane": self.config.plane.to_json(), "transfer": self.config.transfer,
                    "phone_a": {"video": self.a_finished["video"],
                                "tracker": self.config.tracker},
                    "capture": {"tool": "ltm capture", "lattice": list(self.config.lattice),
                                "K": binning.k, "M": binning.m, "k_over_m": binning.ratio,
                                "frames_a": self.a_finished["frames"],
                                "frames_a_live": len(self.poses),
                                "counted_with_time_offset": self.offset,
                                "time_offset_note": self.offset_note,
                                "frames_b": self.b_finished["frames"],
                                "clock": "phone A and camera B clocks differ: run ltm sync"}}
            write_text_atomic(self.folder / "acquisition.json",
                              json.dumps(meta, indent=2) + "\n", what="acquisition")
            (self.folder / INCOMPLETE_MARKER).unlink()
            shutil.rmtree(self.folder / WORK, ignore_errors=True)
            self.finished = True
        self._notify()
        return {"ok": True, "folder": str(self.folder)}

    # -- helpers -------------------------------------------------------------------------------

    def _work(self, kind: str, name: str) -> Path:
        return self.folder / WORK / kind / name

    def _check_open(self, done: dict | None, who: str) -> None:
        if self.finished or done is not None:
            raise RequestError(f"{who} has already finished; start a new capture", 409)

    def _notify(self) -> None:
        if self.listeners:
            with self._lock:
                summary = {**self._coverage(), "b": self._chunk_counts("b"),
                           "a_finished": self.a_finished is not None,
                           "b_finished": self.b_finished is not None, "finished": self.finished}
            for listener in self.listeners:
                listener(summary)


def put(path: Path, data: bytes) -> None:
    """Write ``data`` beside ``path`` and move it into place (no fsync: a frame or a chunk
    needs to survive a dropped connection, not a power cut)."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise LtmError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from exc


def video_suffix(mime: str | None) -> str:
    """File suffix of camera B's video from its MIME type (``video/webm;codecs=vp8``)."""
    base = (mime or "video/webm").split(";")[0].strip().lower()
    return VIDEO_TYPES.get(base, ".webm")


def settle_video(joined: Path, stem: Path, what: str, *, constant_rate: bool = True):
    """Move a joined recording to ``stem`` + suffix as it is when it is constant-rate with a
    stated length (or ``constant_rate`` is False), else rewrite it at a constant rate
    (``stem.mp4``; the upload is dropped). Returns ``(video path, VideoFacts of the upload,
    frames of the video)``."""
    try:
        facts = probe(joined, what)
        if not constant_rate or (facts.regular and facts.declares_length):
            video = stem.with_name(stem.name + joined.suffix)
            os.replace(joined, video)
            return video, facts, len(facts.times)
        video = stem.with_name(stem.name + ".mp4")
        return video, facts, rewrite_constant_rate(joined, video, facts.rate, what=what)
    except LtmError as exc:
        raise RequestError(str(exc), 409) from exc
    finally:
        joined.unlink(missing_ok=True)


def increasing(poses: list[FramePose]) -> list[FramePose]:
    """The frames whose time comes after every earlier frame's: a browser's recording can hold
    two frames with one time stamp (seen: Chromium's WebM), which poses.csv cannot."""
    kept: list[FramePose] = []
    for pose in poses:
        if not kept or pose.t > kept[-1].t:
            kept.append(pose)
    return kept


def path_at(t: np.ndarray, led: np.ndarray, frames: np.ndarray, max_gap: float) -> np.ndarray:
    """The LED path ``(t, led (n, 3))`` at ``frames`` (times on the path's clock) by the rule
    of ``stages.frames.lights_at``: linear between two samples at most ``max_gap`` apart, or on
    a sample; frames outside the path or in a longer gap are left out. Returns ``(m, 3)``."""
    if len(t) < 2:
        return led[np.isin(t, frames)].reshape(-1, 3)
    frames = frames[(frames >= t[0]) & (frames <= t[-1])]
    after = np.clip(np.searchsorted(t, frames), 1, len(t) - 1)
    measured = (frames == t[after]) | (frames == t[after - 1])
    frames = frames[(t[after] - t[after - 1] <= max_gap) | measured]
    return np.column_stack([np.interp(frames, t, led[:, k]) for k in range(3)])


def path_samples(t: np.ndarray, led: np.ndarray, rate: float, max_gap: float, *,
                 keep_samples: bool = False) -> np.ndarray:
    """The LED path ``(t, led (n, 3))`` as ``ltm ingest`` samples it for a camera at ``rate``
    frames per second (the rule of ``stages.frames.lights_at``): positions linearly
    interpolated at the times ``k / rate`` (k whole) that lie between two samples at most
    ``max_gap`` apart or on a sample; with ``keep_samples`` also at every sample (the live
    path, whose samples the page draws). Returns ``(m, 3)``."""
    if len(t) < 2:
        return led.reshape(-1, 3)
    grid = np.arange(np.ceil(t[0] * rate), np.floor(t[-1] * rate) + 1) / rate
    return path_at(t, led, np.union1d(grid, t) if keep_samples else grid, max_gap)


def scaled_intrinsics(intr: Intrinsics, size: tuple[int, int]) -> Intrinsics:
    """``intr`` for frames of ``size`` (the page may send a scaled view of the calibrated
    camera); the aspect ratio must match."""
    w0, h0 = intr.image_size
    w, h = size
    if abs(w / h - w0 / h0) > 0.01:
        raise RequestError(f"phone A frame is {w}x{h} but the intrinsics are for {w0}x{h0}; "
                           "expected the calibrated camera's aspect ratio")
    if (w, h) == (w0, h0):
        return intr
    matrix = intr.matrix.copy()
    matrix[0] *= w / w0
    matrix[1] *= h / h0
    matrix[2] = [0, 0, 1]
    return replace(intr, image_size=(w, h), matrix=matrix)


def board_tracker(spec, intr: Intrinsics, config) -> Callable[[tuple[int, int]], Tracker]:
    """Per frame size, phone A's board tracker (:func:`ltmstore.capture.track.track_frame`)."""
    from ltmstore.capture.board import BoardDetector
    from ltmstore.capture.track import track_frame

    detector = BoardDetector(spec)

    def make(size: tuple[int, int]) -> Tracker:
        scaled = scaled_intrinsics(intr, size)
        return lambda gray, t: track_frame(detector, gray, t, scaled, config)

    return make


def board_video_tracker(spec, intr: Intrinsics, config) -> VideoTracker:
    """Phone A's whole video on the board (:func:`ltmstore.capture.track.track_video`), the
    intrinsics scaled to the video's frame size."""
    from ltmstore.capture.track import track_video

    def run(video: Path, size: tuple[int, int]) -> list[FramePose]:
        return track_video(video, spec, scaled_intrinsics(intr, size), config, progress=False)

    return run


def painting_trackers(image: str | os.PathLike, width: float, intr: Intrinsics,
                      config) -> tuple[Callable[[tuple[int, int]], Tracker], VideoTracker]:
    """Phone A's painting trackers (``ltmstore.capture.painting_track``): per frame size, the
    live one, and the whole-video one (``track_painting_video``); the map is loaded once."""
    try:
        from ltmstore.capture import painting_track as pt
    except ImportError as exc:
        raise LtmError("--painting needs the painting tracker (ltmstore.capture."
                       "painting_track), which this installation lacks; use --board") from exc
    path = Path(image)
    is_video = path.suffix.lower() in {".mp4", ".mkv", ".webm", ".mov", ".avi"}
    painting = (pt.PaintingMap.from_video if is_video else pt.PaintingMap.from_image)(path, width)

    def make(size: tuple[int, int]) -> Tracker:
        return pt.PaintingTracker(painting, scaled_intrinsics(intr, size), config).track_frame

    def run(video: Path, size: tuple[int, int]) -> list[FramePose]:
        # as `ltm track`: the shutter time estimated (None) for the motion-blurred map
        return pt.track_painting_video(video, painting, scaled_intrinsics(intr, size), config,
                                       shutter_s=None, progress=False)

    return make, run
