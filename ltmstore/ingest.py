"""Video frames and poses to the store: streaming, linearised, luminance plus chroma ratios.

Layout written (ARCHITECTURE.md section 3.2), for ``n`` frames of ``H x W`` pixels:

* coordinates ``t (t,)`` float64 seconds, ``y (H,)`` and ``x (W,)`` int64, ``channel`` ("cb", "cr");
* ``frames (t, y, x)`` float32 linear luminance Y (BT.601), chunks
  ``(chunk_frames, min(H, 256), min(W, 256))`` (16 x 16 pixels for registered 6D frames);
* ``pose_r, pose_s, pose_z (t,)`` float64 light position at each frame (NaN where the pose record
  does not cover the frame), plus ``pose_p, pose_q`` for 6D acquisitions; ``pose_valid (t,)`` bool;
* ``chroma (y, x, channel)`` float32: ``sum_t Cb / sum_t Y`` and ``sum_t Cr / sum_t Y`` over the
  valid frames (0 where ``sum_t Y == 0``): colour as a ratio to luminance, illumination invariant;
* group attribute ``acquisition`` (provenance, input hashes) and stage ``ingest``.

A frame is rejected (``pose_valid`` False) for the first of these reasons that applies:
``beyond_poses`` (its time lies outside the pose record or in a gap of it longer than
:data:`MAX_POSE_GAP_S`), ``out_of_plane`` (the light is further than the z tolerance from the
plane height; default :data:`Z_TOLERANCE_FRACTION` of the height, about a 10 % change of
irradiance by the inverse-square law) and ``outside_bounds`` (the light is outside the plane
rectangle, or the camera outside the view plane).

6D acquisitions (``view_plane`` in ``acquisition.json``, ``p, q`` columns in ``poses.csv``)
whose ``view_plane`` declares camera B (``distance``, ``intrinsics``, ``grid``): every frame is
registered onto the declared object-plane grid by the plane-induced homography of
camera B at that frame's interpolated ``(p, q)`` (:mod:`ltmstore.register`), after
linearisation; grid pixels outside the frame are NaN in ``frames`` (unobserved in that frame),
and chroma sums skip them.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import zarr
from tqdm.auto import tqdm

from ltmstore.acquisition import Acquisition, Poses, load_acquisition, load_poses
from ltmstore.dims import (
    CHANNEL,
    CHROMA,
    CHROMA_CHANNELS,
    CHROMA_SPREAD,
    FRAME_CHROMA,
    FRAMES,
    PIXEL_DIMS,
    POSES,
    VIEW_DIMS,
    Plane,
    T,
    X,
    Y,
    rgb_to_ycbcr,
)
from ltmstore.errors import LtmError
from ltmstore.register import ViewRig, rectify
from ltmstore.store import begin_stage, complete_stage, create_variable, new_store, write_coord
from ltmstore.transfer import decode

STAGE = "ingest"
ACQUISITION_ATTR = "acquisition"
DEFAULT_CHUNK_FRAMES = 32
SPATIAL_CHUNK = 256
# Registered (6D) frames: small spatial chunks, so that binning reads one pixel tile over the
# whole time axis at once (a 6D lattice is too large for per-time-block partial sums per tile).
REGISTERED_SPATIAL_CHUNK = 16
MIN_VALID_FRAMES = 8
Z_TOLERANCE_FRACTION = 0.05
# Longest pose interval interpolated across: a tracker's dropouts (60 Hz, up to 10 reports)
# are bridged, a light lost for longer (no board in phone A's view) is not guessed.
MAX_POSE_GAP_S = 0.25
# Measured over seeds 0-2: relief 0.035-0.038, icon 0.019-0.023, canvas 0.070-0.081.
CHROMA_TOLERANCE = 0.05  # RMS colour error of a luminance-only LTM, relative to the signal
# A video whose decoded frame count falls short of its header's by more than this is truncated.
TRUNCATION_SLACK = (2, 0.02)  # frames, fraction of the declared count


def transfer_lut(transfer: str) -> np.ndarray:
    """Linear light of each 8-bit code value, as a (256,) float32 table (see
    :func:`ltmstore.transfer.decode`)."""
    return decode(np.arange(256), transfer)


@dataclass(frozen=True)
class Lights:
    """Light position per frame and the reason, if any, each frame is rejected.

    The three rejection masks are exclusive: a frame counts under the first reason that applies.
    """

    r: np.ndarray
    s: np.ndarray
    z: np.ndarray
    beyond_poses: np.ndarray
    out_of_plane: np.ndarray
    outside_bounds: np.ndarray
    view: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def classify(cls, r: np.ndarray, s: np.ndarray, z: np.ndarray, *, plane: Plane,
                 known: np.ndarray, z_tolerance: float, view: dict[str, np.ndarray] | None = None,
                 view_plane: dict | None = None) -> Lights:
        """Flag each frame from its light (and camera) position.

        Parameters
        ----------
        r, s, z : ndarray
            Light position per frame (ignored where ``known`` is False, and set to NaN there).
        plane : Plane
            The illumination plane rectangle and height.
        known : ndarray of bool
            Where a position exists (the pose record covers the frame).
        z_tolerance : float
            Largest accepted ``|z - plane.height|``.
        view : dict, optional
            ``{"p": ..., "q": ...}`` camera positions (6D).
        view_plane : dict, optional
            ``{"p": [min, max], "q": [min, max]}``: bounds for ``view``.
        """
        def nan(values: np.ndarray) -> np.ndarray:
            return np.where(known, values, np.nan)

        r, s, z = nan(r), nan(s), nan(z)
        view = {k: nan(v) for k, v in (view or {}).items()}
        inside = plane.contains(r, s)
        for k, (lo, hi) in (view_plane or {}).items():
            inside &= (view[k] >= lo) & (view[k] <= hi)
        off = known & ~(np.abs(z - plane.height) <= z_tolerance)
        return cls(r=r, s=s, z=z, beyond_poses=~known, out_of_plane=off,
                   outside_bounds=known & ~off & ~inside, view=view)

    @property
    def valid(self) -> np.ndarray:
        return ~(self.beyond_poses | self.out_of_plane | self.outside_bounds)

    def rejected(self) -> dict[str, int]:
        """Number of frames rejected for each reason."""
        return {"beyond_poses": int(self.beyond_poses.sum()),
                "out_of_plane": int(self.out_of_plane.sum()),
                "outside_bounds": int(self.outside_bounds.sum())}


def lights_at(t: np.ndarray, poses: Poses, *, plane: Plane, z_tolerance: float,
              time_offset: float = 0.0, view_plane: dict | None = None) -> Lights:
    """Interpolate the poses (linearly) at frame times ``t`` and classify the frames.

    Pose times are shifted by ``time_offset`` onto the video's clock; frames outside the shifted
    pose record, or inside a gap of it longer than :data:`MAX_POSE_GAP_S` (a tracker that lost
    the light), are ``beyond_poses``: their position would be guessed, not measured.
    """
    t = np.asarray(t, dtype=np.float64)
    tp = poses.t + time_offset
    after = np.clip(np.searchsorted(tp, t), 1, len(tp) - 1)
    bridged = tp[after] - tp[after - 1]  # the pose interval interpolated across
    measured = (t == tp[after]) | (t == tp[after - 1])
    known = (t >= tp[0]) & (t <= tp[-1]) & ((bridged <= MAX_POSE_GAP_S) | measured)
    at = partial(np.interp, t, tp)
    view = {k: at(getattr(poses, k)) for k in VIEW_DIMS if getattr(poses, k) is not None}
    return Lights.classify(at(poses.r), at(poses.s), at(poses.z), plane=plane, known=known,
                           z_tolerance=z_tolerance, view=view, view_plane=view_plane)


def chroma_decision(residual: np.ndarray, energy: np.ndarray) -> dict:
    """Is chroma illumination-invariant enough for a luminance-only LTM?

    A luminance-only LTM predicts each frame's chroma as a fixed multiple of its luminance
    (``Cb = c Y``). ``residual`` ``(2, H, W)`` is the least-squares error energy of that
    prediction over the frames, per pixel and channel; ``energy`` ``(H, W)`` the luminance
    energy. The scene's chroma variation is ``sqrt(sum residual / sum energy)``, the RMS colour
    error relative to the signal; above :data:`CHROMA_TOLERANCE` the colour changes with the
    light (coloured highlights: gold leaf, metal) and a colour LTM is needed.
    """
    variation = float(np.sqrt(residual.sum() / max(float(energy.sum()), 1e-30)))
    return {"variation": variation, "tolerance": CHROMA_TOLERANCE,
            "invariant": variation <= CHROMA_TOLERANCE}


class FrameSink:
    """Stream 8-bit RGB frames into a store group as linear luminance, accumulating chroma.

    Frames are buffered in blocks of ``chunk_frames`` (one Zarr chunk along ``t``) and appended to
    ``frames``; Y, Cb and Cr are summed over the valid frames for the chroma ratios. Only one block
    of frames is ever held in memory.

    Parameters
    ----------
    group : zarr.Group
        The store group being written.
    transfer : {"srgb", "linear"}
        How code values encode light.
    chunk_frames : int
        Frames per chunk along ``t``.
    rig : ViewRig, optional
        6D: register every frame onto the rig's object grid (:func:`ltmstore.register.rectify`)
        at the camera position given to :meth:`add`.
    """

    def __init__(self, group: zarr.Group, *, transfer: str, chunk_frames: int,
                 rig: ViewRig | None = None) -> None:
        self._group = group
        self._rig = rig
        self._raw_shape: tuple[int, ...] | None = None
        self.observed = [0.0, 0]  # sum over valid frames of the observed grid fraction, count
        self._lut = transfer_lut(transfer)
        self._chunk_frames = _positive_int(chunk_frames, "chunk_frames")
        self._frames: zarr.Array | None = None
        self._buffer = np.empty((0, 0, 0), dtype=np.float32)
        self._chroma_buffer = np.empty((2, 0, 0, 0), dtype=np.float16)
        self._chroma: zarr.Array | None = None
        self._sums = np.zeros((3, 0, 0))  # sum over valid frames of Y, Cb, Cr
        self._moments = np.zeros((5, 0, 0))  # sums of Y^2, Cb Y, Cr Y, Cb^2, Cr^2
        self._pending = 0
        self.n = 0

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the frames (``(0, 0)`` before the first frame)."""
        return self._sums.shape[1:]

    def add(self, rgb8: np.ndarray, valid: bool, *, source: str,
            view: tuple[float, float] | None = None) -> None:
        """Append one ``(H, W, 3)`` uint8 RGB frame; ``valid`` frames count towards chroma.

        With a rig, ``view = (p, q)`` is the camera position of the frame (NaN: unknown).
        """
        if self._raw_shape is None:
            self._raw_shape = rgb8.shape[:2]
        if rgb8.shape != (*self._raw_shape, 3):
            raise LtmError(f"{source} is {rgb8.shape[1]}x{rgb8.shape[0]} pixels; expected "
                           f"{self._raw_shape[1]}x{self._raw_shape[0]} like the first frame")
        ycc = rgb_to_ycbcr(self._lut[rgb8])
        if self._rig is not None:
            ycc = rectify(ycc, self._rig, *(view if view is not None else (np.nan, np.nan)))
            if valid:
                self.observed[0] += float(np.isfinite(ycc[..., 0]).mean())
                self.observed[1] += 1
        if self._frames is None:
            self._start(ycc.shape[:2])
        self._buffer[self._pending] = ycc[..., 0]
        self._chroma_buffer[:, self._pending] = np.moveaxis(ycc[..., 1:], -1, 0)
        if valid:
            ycc = np.moveaxis(ycc if self._rig is None else np.nan_to_num(ycc), -1, 0)
            self._sums += ycc
            self._moments += [ycc[0] ** 2, ycc[1] * ycc[0], ycc[2] * ycc[0], ycc[1] ** 2,
                              ycc[2] ** 2]
        self._pending += 1
        self.n += 1
        if self._pending == self._chunk_frames:
            self._flush()

    def finish(self, t: np.ndarray) -> dict:
        """Write the last block, the ``t``, ``y``, ``x``, ``channel`` coordinates and chroma.

        Returns the chroma decision (:func:`chroma_decision`).
        """
        self._flush()
        if len(t) != self.n:
            raise ValueError(f"{len(t)} times for {self.n} frames")
        height, width = self.shape
        write_coord(self._group, T, np.asarray(t, dtype=np.float64), units="s")
        write_coord(self._group, Y, np.arange(height))
        write_coord(self._group, X, np.arange(width))
        write_coord(self._group, CHANNEL, np.array(CHROMA_CHANNELS, dtype=np.dtypes.StringDType()))
        luma, chroma = self._sums[0], self._sums[1:]
        ratio = np.divide(chroma, luma, out=np.zeros_like(chroma), where=luma > 0)
        arr = create_variable(self._group, CHROMA, (*PIXEL_DIMS, CHANNEL), (height, width, 2),
                              chunks=(*self._spatial_chunks(), 2), attrs={
                                  "long_name": "chroma as a ratio to luminance (Cb/Y, Cr/Y), "
                                               "luminance-weighted over valid frames"})
        arr[...] = np.moveaxis(ratio, 0, -1).astype(np.float32)
        energy, cross, square = self._moments[0], self._moments[1:3], self._moments[3:]
        residual = np.maximum(square - np.divide(cross**2, energy, out=np.zeros_like(cross),
                                                 where=energy > 0), 0)
        spread = np.sqrt(np.divide(residual, energy, out=np.zeros_like(residual),
                                   where=energy > 0))
        arr = create_variable(self._group, CHROMA_SPREAD, (*PIXEL_DIMS, CHANNEL),
                              (height, width, 2), chunks=(*self._spatial_chunks(), 2), attrs={
                                  "long_name": "RMS error of Cb, Cr predicted as a fixed ratio "
                                               "of Y, relative to the RMS of Y (per pixel)"})
        arr[...] = np.moveaxis(spread, 0, -1).astype(np.float32)
        return chroma_decision(residual, energy)

    def _start(self, shape: tuple[int, int]) -> None:
        self._sums = np.zeros((3, *shape))
        self._moments = np.zeros((5, *shape))
        self._buffer = np.empty((self._chunk_frames, *shape), dtype=np.float32)
        self._chroma_buffer = np.empty((2, self._chunk_frames, *shape), dtype=np.float16)
        chunks = (self._chunk_frames, *self._spatial_chunks())
        self._frames = create_variable(
            self._group, FRAMES, (T, *PIXEL_DIMS), (0, *shape), chunks=chunks,
            attrs={"long_name": "linear luminance Y (BT.601 weights)"},
        )
        self._chroma = create_variable(
            self._group, FRAME_CHROMA, (CHANNEL, T, *PIXEL_DIMS), (2, 0, *shape),
            chunks=(1, *chunks), dtype=np.float16,
            attrs={"long_name": "linear Cb, Cr per frame (for a colour LTM)"},
        )

    def _spatial_chunks(self) -> tuple[int, int]:
        side = SPATIAL_CHUNK if self._rig is None else REGISTERED_SPATIAL_CHUNK
        return tuple(min(n, side) for n in self.shape)

    def _flush(self) -> None:
        if self._pending:
            self._frames.append(self._buffer[: self._pending], axis=0)
            self._chroma.append(self._chroma_buffer[:, : self._pending], axis=1)
            self._pending = 0


def write_lights(group: zarr.Group, lights: Lights) -> None:
    """Write ``pose_r``, ``pose_s``, ``pose_z`` (and ``pose_p``, ``pose_q``) and ``pose_valid``."""
    name_r, name_s, name_z, name_valid = POSES
    columns = {name_r: lights.r, name_s: lights.s, name_z: lights.z,
               **{f"pose_{k}": v for k, v in lights.view.items()}, name_valid: lights.valid}
    for name, values in columns.items():
        arr = create_variable(group, name, (T,), values.shape, chunks=(max(len(values), 1),),
                              dtype=values.dtype, fill_value=False if values.dtype == bool
                              else np.nan)
        arr[...] = values


def finish_ingest(group: zarr.Group, sink: FrameSink, t: np.ndarray, lights: Lights, *,
                  acquisition: dict, info: dict, started: float) -> dict:
    """Check the valid frame count, write coordinates, poses, chroma, provenance; complete.

    Returns the stage record (also stored under stage ``ingest``).
    """
    n_valid = int(lights.valid.sum())
    if n_valid < MIN_VALID_FRAMES:
        raise LtmError(f"only {n_valid} of {sink.n} frames are valid (rejected: "
                       f"{lights.rejected()}); expected at least {MIN_VALID_FRAMES}")
    chroma = sink.finish(t)
    write_lights(group, lights)
    group.attrs[ACQUISITION_ATTR] = acquisition
    record = {"n_frames": sink.n, "n_valid": n_valid, "rejected": lights.rejected(),
              "chroma": chroma, **info,
              "seconds": round(time.perf_counter() - started, 3)}
    complete_stage(group, STAGE, record)
    return record


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


def ingest(acq_dir: str | os.PathLike, store: str | os.PathLike, *, overwrite: bool = False,
           z_tolerance: float | None = None, progress: bool = True,
           chunk_frames: int = DEFAULT_CHUNK_FRAMES, hashes: dict[str, str] | None = None) -> dict:
    """Decode an acquisition folder's video and poses into a new store.

    Parameters
    ----------
    acq_dir : str or PathLike
        The acquisition folder (ARCHITECTURE.md section 3.1).
    store : str or PathLike
        Where to create the Zarr store; written beside and moved into place when complete.
    overwrite : bool, default False
        Replace an existing store instead of refusing.
    z_tolerance : float, optional
        Largest accepted ``|z - height|`` of the light, in plane units; default
        :data:`Z_TOLERANCE_FRACTION` times the plane height.
    progress : bool, default True
        Show a progress bar.
    chunk_frames : int, default 32
        Frames per chunk along ``t``, and frames held in memory at once.
    hashes : dict, optional
        ``Acquisition.sha256()`` of the inputs when the caller has just computed it (the
        archive does, to judge staleness); otherwise the inputs are hashed here.

    Returns
    -------
    dict
        ``n_frames``, ``n_valid``, ``rejected`` (per reason), ``fps``, ``frame_size``,
        ``z_tolerance``, ``timings`` (``setup``: reading and hashing the inputs; ``frames``:
        decoding and writing) and ``seconds`` (total) (also stored as stage ``ingest``), and
        ``store``.

    Raises
    ------
    LtmError
        For a bad acquisition folder, an undecodable video, an existing store without
        ``overwrite`` or fewer than :data:`MIN_VALID_FRAMES` valid frames.
    """
    started = time.perf_counter()
    acq = load_acquisition(acq_dir)
    poses = load_poses(acq.poses)
    if acq.view_plane is not None and poses.p is None:
        raise LtmError(f"{str(acq.poses)}: acquisition.json declares a view_plane but the poses "
                       "have no p, q columns; expected header 't,r,s,z,p,q'")
    z_tolerance = _z_tolerance(z_tolerance, acq.plane)
    rig = _rig(acq)
    light = partial(lights_at, poses=poses, plane=acq.plane, z_tolerance=z_tolerance,
                    time_offset=acq.time_offset, view_plane=acq.view_plane)
    hashes = hashes or _sha256(acq)
    hashed = time.perf_counter()
    with VideoReader(acq.video) as video, new_store(store, overwrite=overwrite) as group:
        begin_stage(group, STAGE)
        sink = FrameSink(group, transfer=acq.transfer, chunk_frames=chunk_frames, rig=rig)
        bar = tqdm(video, total=video.frame_count, disable=not progress, unit="frame",
                   desc="ingest")
        for i, rgb in enumerate(bar):
            at = light(np.array([i / video.fps]))
            view = None
            if rig is not None:
                _check_frame_size(rgb, rig, acq.video)
                view = (float(at.view["p"][0]), float(at.view["q"][0]))
            sink.add(rgb, bool(at.valid[0]), source=f"video {str(acq.video)!r} frame {i}",
                     view=view)
        t = np.arange(sink.n) / video.fps
        timings = {"setup": round(hashed - started, 3),
                   "frames": round(time.perf_counter() - hashed, 3)}
        info = {"fps": video.fps, "frame_size": list(sink.shape), "z_tolerance": z_tolerance,
                "time_offset": acq.time_offset, "chunk_frames": chunk_frames, "timings": timings}
        if rig is not None:
            info["registration"] = {
                "camera_frame_size": [rig.intrinsics.height, rig.intrinsics.width],
                "observed_fraction_mean": sink.observed[0] / max(sink.observed[1], 1)}
        provenance = _provenance(acq, hashes, video, sink, rig)
        record = finish_ingest(group, sink, t, light(t), acquisition=provenance, info=info,
                               started=started)
    return {**record, "store": str(store)}


def _sha256(acq: Acquisition) -> dict[str, str]:
    try:
        return acq.sha256()
    except OSError as exc:
        raise LtmError(f"cannot read the inputs of {str(acq.folder)!r}: "
                       f"{exc.strerror or exc}") from exc


def _rig(acq: Acquisition) -> ViewRig | None:
    """Camera B of a 6D acquisition, when ``view_plane`` declares one (else the frames are taken
    as already registered on the object grid)."""
    view = acq.raw.get("view_plane")
    if acq.view_plane is None or not any(k in view for k in ("distance", "intrinsics", "grid")):
        return None
    return ViewRig.from_json(view, f"{acq.folder / 'acquisition.json'}: view_plane")


def _check_frame_size(rgb: np.ndarray, rig: ViewRig, video: Path) -> None:
    k = rig.intrinsics
    if rgb.shape[:2] != (k.height, k.width):
        raise LtmError(f"video {str(video)!r} frames are {rgb.shape[1]}x{rgb.shape[0]} pixels; "
                       f"view_plane intrinsics declare {k.width}x{k.height}")


def _provenance(acq: Acquisition, hashes: dict, video: VideoReader, sink: FrameSink,
                rig: ViewRig | None = None) -> dict:
    meta = {"source": "video", "folder": str(acq.folder), "video": acq.raw["video"],
            "poses": acq.raw["poses"], "sha256": hashes, "plane": acq.plane.to_json(),
            "transfer": acq.transfer, "time_offset": acq.time_offset, "fps": video.fps,
            "frame_size": list(sink.shape)}
    if acq.view_plane is not None:
        meta["view_plane"] = {**acq.view_plane, **(rig.to_json() if rig is not None else {})}
    return meta


def _z_tolerance(value: float | None, plane: Plane) -> float:
    if value is None:
        return Z_TOLERANCE_FRACTION * plane.height
    if not (np.isfinite(value) and value >= 0):
        raise LtmError(f"z_tolerance {value!r} must be a non-negative number (plane units)")
    return float(value)


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise LtmError(f"{name} {value!r} must be a positive integer")
    return int(value)

