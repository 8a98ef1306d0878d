"""Frames and lights into a store: the part of ingest shared by videos and classic RTI captures.

:class:`FrameSink` streams RGB frames into ``frames`` as linear luminance and accumulates the
chroma ratios; :class:`Lights` holds each frame's light position and why it was rejected;
:func:`finish_ingest` writes the poses, chroma and provenance and completes the stage.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial

import cv2
import numpy as np
import zarr

from ltmstore.capture.acquisition import Poses
from ltmstore.capture.register import ViewRig, rectify
from ltmstore.core import checksum
from ltmstore.core.dims import (
    CHANNEL,
    CHROMA,
    CHROMA_CHANNELS,
    CHROMA_SPREAD,
    FRAME_CHROMA,
    FRAMES,
    OBSERVATION_DTYPE,
    PIXEL_DIMS,
    POSE_AXIS,
    POSES,
    VIEW_DIMS,
    Plane,
    T,
    X,
    Y,
    rgb_to_ycbcr,
)
from ltmstore.core.errors import LtmError
from ltmstore.core.store import complete_stage, create_variable, write_coord
from ltmstore.core.transfer import linearise, transfer_lut

STAGE = "ingest"
ACQUISITION_ATTR = "acquisition"
DEFAULT_CHUNK_FRAMES = 32
SPATIAL_CHUNK = 256
# Registered (6D) frames: small spatial chunks, so that binning reads one pixel tile over the
# whole time axis at once (a 6D lattice is too large for per-time-block partial sums per tile).
REGISTERED_SPATIAL_CHUNK = 16
MIN_VALID_FRAMES = 8
# Longest pose interval interpolated across: a tracker's dropouts (60 Hz, up to 10 reports)
# are bridged, a light lost for longer (no board in phone A's view) is not guessed.
MAX_POSE_GAP_S = 0.25
# Measured over seeds 0-2: relief 0.035-0.038, icon 0.019-0.023, canvas 0.070-0.081.
CHROMA_TOLERANCE = 0.05  # RMS colour error of a luminance-only LTM, relative to the signal
MOMENTS = ((0, 0), (1, 0), (2, 0), (1, 1), (2, 2))  # Y^2, Cb Y, Cr Y, Cb^2, Cr^2
# Frames x pixels from which the compiled pass over each frame pays for loading Numba (0.6-0.8 s
# of one core): NumPy's takes 1.8 ms per 0.16 MP frame against 0.6 ms, 159 against 66 ms at 4K.
COMPILED_WORK = 10**8
FLOAT32_SUM_FRAMES = 1024  # up to this many frames (known ahead) are summed in float32
BAND_PIXELS = 2**22  # a frame not yet converted is converted and summed this many pixels at a time
# ... as BAND_THREADS bands at once, each of BAND_PIXELS / BAND_THREADS into its thread's own
# arrays (OpenCV and the compiled sums free the GIL): 24 MP, 47 photographs, ingest-rti
# 23.8-24.4 -> 18.7-19.4 s, peak 1.86-1.87 -> 1.92-1.93 GiB
BAND_THREADS = 2
SPILLED = ("spilled_frames", "spilled_frame_chroma")  # frames held in bands until ingest ends
# Fewer frames held than this are spilled, more are written as chunks that deep. Measured on a
# 47-photograph capture (ingest-rti): 1 held (24 MP) 49 -> 22 s, 3 (12 MP) 13.9 -> 11.9 s, and
# the classic stage and relighting 10-25 % faster on the copy; 10 held (4 MP) 3.6 -> 4.3 s.
SPILL_BELOW = 8


@dataclass(frozen=True)
class Lights:
    """Light position per frame and the reason, if any, each frame is rejected.

    The rejection masks are exclusive: a frame counts under the first reason that applies.
    ``occluded`` (judged from the frames' brightness after the positions: see
    :mod:`ltmstore.stages.occlusion`) is None where occlusion was not judged; ``led_off``
    (the LED-off lead of a phone capture: :mod:`ltmstore.capture.lead`) is None where no lead
    was looked for. ``axis`` ``(n, 3)``: the LED's axis per frame (unit, plane coordinates;
    NaN where the poses do not cover the frame), None where the poses do not give it.
    """

    r: np.ndarray
    s: np.ndarray
    z: np.ndarray
    beyond_poses: np.ndarray
    out_of_plane: np.ndarray
    outside_bounds: np.ndarray
    view: dict[str, np.ndarray] = field(default_factory=dict)
    occluded: np.ndarray | None = None
    led_off: np.ndarray | None = None
    axis: np.ndarray | None = None

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
        placed = ~(self.beyond_poses | self.out_of_plane | self.outside_bounds)
        if self.led_off is not None:
            placed &= ~self.led_off
        return placed if self.occluded is None else placed & ~self.occluded

    def rejected(self) -> dict[str, int]:
        """Number of frames rejected for each reason."""
        counts = {"beyond_poses": int(self.beyond_poses.sum()),
                  "out_of_plane": int(self.out_of_plane.sum()),
                  "outside_bounds": int(self.outside_bounds.sum())}
        placed = ~(self.beyond_poses | self.out_of_plane | self.outside_bounds)
        if self.led_off is not None:
            counts["led_off"] = int((self.led_off & placed).sum())
        if self.occluded is not None:
            counts["occluded"] = int(self.occluded.sum())
        return counts


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
    lights = Lights.classify(at(poses.r), at(poses.s), at(poses.z), plane=plane, known=known,
                             z_tolerance=z_tolerance, view=view, view_plane=view_plane)
    if poses.axis is None:
        return lights
    axis = np.column_stack([at(poses.axis[:, k]) for k in range(3)])
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)  # interpolated: back to unit length
    return replace(lights, axis=np.where(known[:, None], axis, np.nan))


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
    of frames is ever held in memory. Where only a few frames may be held (large photographs:
    fewer than :data:`SPILL_BELOW`), blocks of ``held_frames`` are spilled into bands of whole
    rows (a few files per frame) and copied into ``frames`` in chunks of ``chunk_frames`` by
    :meth:`finish`: chunks of one frame would write and read hundreds of small files per frame.
    Otherwise the chunks are ``held_frames`` deep.

    Parameters
    ----------
    group : zarr.Group
        The store group being written.
    transfer : {"srgb", "linear"}
        How code values encode light.
    chunk_frames : int
        Frames per chunk along ``t``.
    held_frames : int, optional
        Most frames held in memory before they are written (default ``chunk_frames``).
    rig : ViewRig, optional
        6D: register every frame onto the rig's object grid
        (:func:`ltmstore.capture.register.rectify`) at the camera position given to :meth:`add`.
    expected_frames : int, optional
        How many frames will come (a classic capture's photographs): a short capture's frames
        are summed by NumPy, a long one's (or of unknown length) by a compiled kernel.
    """

    def __init__(self, group: zarr.Group, *, transfer: str, chunk_frames: int,
                 rig: ViewRig | None = None, expected_frames: int | None = None,
                 held_frames: int | None = None) -> None:
        self._group = group
        self._expected_frames = expected_frames
        self._rig = rig
        self._raw_shape: tuple[int, ...] | None = None
        self.observed = [0.0, 0]  # sum over valid frames of the observed grid fraction, count
        self._luts = {bits: transfer_lut(transfer, bits=bits) for bits in (8, 16)}
        self._chunk_frames = _positive_int(chunk_frames, "chunk_frames")
        self._held = min(self._chunk_frames, self._chunk_frames if held_frames is None
                         else _positive_int(held_frames, "held_frames"))
        self._frames: zarr.Array | None = None
        self._buffer = np.empty((0, 0, 0), dtype=OBSERVATION_DTYPE)
        self._chroma_buffer = np.empty((2, 0, 0, 0), dtype=OBSERVATION_DTYPE)
        self._chroma: zarr.Array | None = None
        self._sums = np.zeros((3, 0, 0))  # sum over valid frames of Y, Cb, Cr
        self._moments = np.zeros((5, 0, 0))  # sums of Y^2, Cb Y, Cr Y, Cb^2, Cr^2
        self._pending = 0
        self._scratch = threading.local()  # each thread's arrays of a band
        self._bands: ThreadPoolExecutor | None = None  # the threads converting bands
        self.n = 0
        self.brightness: list[float] = []  # mean linear luminance of each frame

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the frames (``(0, 0)`` before the first frame)."""
        return self._sums.shape[1:]

    def convert(self, rgb: np.ndarray, scratch: tuple[np.ndarray, np.ndarray] | None = None
                ) -> np.ndarray:
        """Linear Y, Cb, Cr ``(H, W, 3)`` float32 of an RGB frame, uint8 or uint16 (16-bit
        images keep 16 bits), into ``scratch`` (its linear RGB, then its Y, Cb, Cr) where
        given. Changes nothing in the sink, so decoding threads may convert frames ahead of
        :meth:`add`."""
        lut = self._luts[16 if rgb.dtype == np.uint16 else 8]
        if scratch is None:
            return rgb_to_ycbcr(linearise(rgb, lut))
        return rgb_to_ycbcr(linearise(rgb, lut, scratch[0]), scratch[1])

    def add(self, rgb8: np.ndarray, valid: bool, *, source: str,
            view: tuple[float, float] | None = None, ycc: np.ndarray | None = None) -> None:
        """Append one ``(H, W, 3)`` uint8 (or uint16) RGB frame; ``valid`` frames count towards
        chroma.

        With a rig, ``view = (p, q)`` is the camera position of the frame (NaN: unknown).
        ``ycc`` is the frame's :meth:`convert`, when already computed.
        """
        if self._raw_shape is None:
            self._raw_shape = rgb8.shape[:2]
        if rgb8.shape != (*self._raw_shape, 3):
            raise LtmError(f"{source} is {rgb8.shape[1]}x{rgb8.shape[0]} pixels; expected "
                           f"{self._raw_shape[1]}x{self._raw_shape[0]} like the first frame")
        if ycc is None and self._rig is None:  # converted a band of rows at a time
            height, width = rgb8.shape[:2]
            step = max(1, BAND_PIXELS // (BAND_THREADS * width))
            bands = [slice(top, min(top + step, height)) for top in range(0, height, step)]
        else:
            if ycc is None:
                ycc = self.convert(rgb8)
            if self._rig is not None:
                ycc = rectify(ycc, self._rig, *(view if view is not None else (np.nan, np.nan)))
            bands = [slice(0, ycc.shape[0])]
        if self._frames is None:
            self._start(rgb8.shape[:2] if ycc is None else ycc.shape[:2])
        if self._rig is not None and valid:
            self.observed[0] += float(np.isfinite(ycc[..., 0]).mean())
            self.observed[1] += 1
        if ycc is None and len(bands) > 1:  # disjoint rows of the sums and buffers: on threads
            parts = list(self._band_threads().map(
                lambda rows: self._add_band(rgb8, rows, valid), bands))
        elif ycc is None:  # a small frame: no thread to hand it to
            parts = [self._add_band(rgb8, bands[0], valid)]
        else:
            parts = [self._add_rows(ycc, bands[0], valid)]
        total, count = (sum(part[k] for part in parts) for k in (0, 1))
        self.brightness.append(total / count if count else np.nan)
        self._pending += 1
        self.n += 1
        if self._pending == self._held:
            self._flush()

    def _band_threads(self) -> ThreadPoolExecutor:
        """The threads converting bands, started by the first large frame and ended with the
        sink (by :meth:`finish`, or when a failed ingest drops it)."""
        if self._bands is None:
            self._bands = ThreadPoolExecutor(BAND_THREADS, thread_name_prefix="ltm-band")
            weakref.finalize(self, self._bands.shutdown, wait=False)
        return self._bands

    def _add_band(self, rgb8: np.ndarray, rows: slice, valid: bool) -> tuple[float, int]:
        """Convert, sum and buffer the rows ``rows`` of the pending frame ``rgb8``, in this
        thread's arrays (allocated once: arrays of a band allocated per band were kept by
        each thread's allocator, 0.1 GiB more at 24 MP)."""
        n, width = rgb8[rows].shape[:2]
        scratch = getattr(self._scratch, "arrays", None)
        if scratch is None or scratch[0].shape[0] < n:
            scratch = self._scratch.arrays = tuple(np.empty((n, width, 3), np.float32)
                                                   for _ in range(2))
        ycc = self.convert(rgb8[rows], tuple(a[:n] for a in scratch))
        return self._add_rows(ycc, rows, valid)

    def _add_rows(self, ycc: np.ndarray, rows: slice, valid: bool) -> tuple[float, int]:
        """Sum and buffer the rows ``rows`` of the pending frame, ``ycc`` ``(n, W, 3)``."""
        n = ycc.shape[0]
        planes = getattr(self._scratch, "planes", None)  # this thread's
        if planes is None or planes.shape[1] < n:
            planes = self._scratch.planes = np.empty((3, n, ycc.shape[1]), dtype=np.float32)
        planes = planes[:, :n]
        total, count = self._accumulate(ycc, planes, self._sums[:, rows],
                                        self._moments[:, rows], valid)
        slots = (self._buffer[self._pending, rows], *self._chroma_buffer[:, self._pending, rows])
        for plane, out in zip(planes, slots, strict=True):
            _to_half(plane, out)
        return total, count

    def lit(self) -> bool:
        """Whether any valid frame so far holds light (a black video is no capture)."""
        return bool(np.nanmax(self._sums[0], initial=0.0) > 0)

    def finish(self, t: np.ndarray) -> dict:
        """Write the last block, the ``t``, ``y``, ``x``, ``channel`` coordinates and chroma.

        Returns the chroma decision (:func:`chroma_decision`).
        """
        if len(t) != self.n:
            raise ValueError(f"{len(t)} times for {self.n} frames")
        self._flush()
        self._buffer = self._chroma_buffer = None  # memory for what follows
        self._scratch = threading.local()
        if self._bands is not None:
            self._bands.shutdown()
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
        decision = chroma_decision(residual, energy)
        if self._spilling:
            del energy, cross, square, residual, spread
            self._moments = None  # memory for the copy
            self._unspill()
        return decision

    def _start(self, shape: tuple[int, int]) -> None:
        frames = np.inf if self._expected_frames is None else self._expected_frames
        self._accumulate = _accumulator(frames * shape[0] * shape[1])
        # float32 sums hold a classic capture's few hundred frames to 1e-5 and halve its
        # memory (1.5 GiB of float64 at 24 MP); a video's thousands are summed in float64
        sums = np.float32 if frames <= FLOAT32_SUM_FRAMES else np.float64
        self._sums = np.zeros((3, *shape), dtype=sums)
        self._moments = np.zeros((5, *shape), dtype=sums)
        self._buffer = np.empty((self._held, *shape), dtype=OBSERVATION_DTYPE)
        self._chroma_buffer = np.empty((2, self._held, *shape), dtype=OBSERVATION_DTYPE)
        if self._spilling:
            band = (self._held, self._spatial_chunks()[0], shape[1])
            self._frames, self._chroma = self._create(SPILLED, 0, band)
        else:
            self._frames, self._chroma = self._create(
                (FRAMES, FRAME_CHROMA), 0, (self._held, *self._spatial_chunks()))

    @property
    def _spilling(self) -> bool:
        return self._held < min(self._chunk_frames, SPILL_BELOW)

    def _create(self, names: tuple[str, str], frames: int,
                chunks: tuple[int, int, int]) -> tuple[zarr.Array, zarr.Array]:
        """Arrays ``names`` of the frames' luminance and chroma, of ``frames`` frames."""
        shape = (frames, *self.shape)
        luminance = create_variable(
            self._group, names[0], (T, *PIXEL_DIMS), shape, chunks=chunks,
            dtype=OBSERVATION_DTYPE, attrs={"long_name": "linear luminance Y (BT.601 weights)"},
            compressors=checksum.FAST_COMPRESSORS)
        chroma = create_variable(
            self._group, names[1], (CHANNEL, T, *PIXEL_DIMS), (2, *shape), chunks=(1, *chunks),
            dtype=OBSERVATION_DTYPE,
            attrs={"long_name": "linear Cb, Cr per frame (for a colour LTM)"},
            compressors=checksum.FAST_COMPRESSORS)
        return luminance, chroma

    def _unspill(self) -> None:
        """Copy the spilled frames into ``frames`` and ``frame_chroma``, a chunk of frames and a
        band of rows at a time (whole chunks: nothing is read back), and remove the spill."""
        chunks = (self._chunk_frames, *self._spatial_chunks())
        targets = self._create((FRAMES, FRAME_CHROMA), self.n, chunks)
        for source, target in zip((self._frames, self._chroma), targets, strict=True):
            t_axis = target.ndim - 3
            for start in range(0, self.n, chunks[0]):
                for top in range(0, self.shape[0], chunks[1]):
                    block = (slice(None),) * t_axis + (slice(start, start + chunks[0]),
                                                        slice(top, top + chunks[1]))
                    target[block] = source[block]
        for name in SPILLED:
            del self._group[name]
        self._frames, self._chroma = targets

    def _spatial_chunks(self) -> tuple[int, int]:
        side = SPATIAL_CHUNK if self._rig is None else REGISTERED_SPATIAL_CHUNK
        return tuple(min(n, side) for n in self.shape)

    def _flush(self) -> None:
        if self._pending:
            self._frames.append(self._buffer[: self._pending], axis=0)
            self._chroma.append(self._chroma_buffer[:, : self._pending], axis=1)
            self._pending = 0


def _to_half(plane: np.ndarray, out: np.ndarray) -> None:
    """``out[...] = plane`` for a float32 ``(H, W)`` plane: into float16 by OpenCV's vectorised
    conversion (bit for bit NumPy's rounding, 4x faster than its cast on a 4K frame)."""
    if out.dtype == np.float16 and out.flags.c_contiguous:
        cv2.multiply(plane, 1.0, dst=out, dtype=cv2.CV_16F)
    else:
        out[...] = plane


def _accumulate(ycc: np.ndarray, planes: np.ndarray, sums: np.ndarray, moments: np.ndarray,
                valid: bool) -> tuple[float, int]:
    """:func:`ltmstore.stages.frame_sums.accumulate` for captures too short to repay loading
    it: a frame whose every pixel is finite (a photograph's) by OpenCV, one pass per sum
    (moments summed at OpenCV's precision, which may differ from NumPy's product in float32
    by its last bit); one with missing pixels by NumPy, masked."""
    cv2.split(ycc, list(planes))
    total = float(np.sum(planes[0], dtype=np.float64))
    if math.isfinite(total):  # a finite Y: every channel of the pixel is
        if valid:
            for plane, out in zip(planes, sums, strict=True):
                cv2.accumulate(plane, out)
            for (a, b), out in zip(MOMENTS, moments, strict=True):
                cv2.accumulateProduct(planes[a], planes[b], out)
        return total, planes[0].size
    missing = np.isnan(planes)
    finite = ~missing[0]
    total = float(np.sum(planes[0], where=finite, dtype=np.float64))
    count, values = int(np.count_nonzero(finite)), np.where(missing, np.float32(0), planes)
    if valid:
        sums += values
        product = np.empty_like(values[0])
        for k, (a, b) in enumerate(MOMENTS):
            moments[k] += np.multiply(values[a], values[b], out=product)
    return total, count


def _accumulator(work: float) -> Callable[..., tuple[float, int]]:
    """The pass over each frame for ``work`` frames x pixels: compiled from
    :data:`COMPILED_WORK` on."""
    if work < COMPILED_WORK:
        return _accumulate
    from ltmstore.stages.frame_sums import accumulate

    return accumulate


def write_lights(group: zarr.Group, lights: Lights) -> None:
    """Write ``pose_r``, ``pose_s``, ``pose_z`` (and ``pose_p``, ``pose_q``), ``pose_valid`` and,
    where the poses give the LED's axis, ``pose_axis_r``, ``pose_axis_s``, ``pose_axis_z``."""
    name_r, name_s, name_z, name_valid = POSES
    columns = {name_r: lights.r, name_s: lights.s, name_z: lights.z,
               **{f"pose_{k}": v for k, v in lights.view.items()}, name_valid: lights.valid,
               **({} if lights.axis is None
                  else dict(zip(POSE_AXIS, lights.axis.T, strict=True)))}
    for name, values in columns.items():
        arr = create_variable(group, name, (T,), values.shape, chunks=(max(len(values), 1),),
                              dtype=values.dtype, fill_value=False if values.dtype == bool
                              else np.nan)
        arr[...] = values


def finish_ingest(group: zarr.Group, sink: FrameSink, t: np.ndarray, lights: Lights, *,
                  acquisition: dict, info: dict, started: float,
                  keep_chroma: bool = True) -> dict:
    """Check the valid frame count, write coordinates, poses, chroma, provenance; complete.

    Without ``keep_chroma``, ``frame_chroma`` is removed when the colour is illumination
    invariant (:func:`chroma_decision`): only a colour LTM reads it, and the default
    reconstruction then writes none (the record's ``chroma.frames_kept`` says which).

    Returns the stage record (also stored under stage ``ingest``).
    """
    n_valid = int(lights.valid.sum())
    if n_valid < MIN_VALID_FRAMES:
        raise LtmError(f"only {n_valid} of {sink.n} frames are valid (rejected: "
                       f"{lights.rejected()}); expected at least {MIN_VALID_FRAMES}")
    if not sink.lit():
        raise LtmError(f"all {n_valid} valid frames are black (no light reached the camera); "
                       "expected a capture lit by the moving light")
    chroma = sink.finish(t)
    chroma["frames_kept"] = keep_chroma or not chroma["invariant"]
    if not chroma["frames_kept"]:
        del group[FRAME_CHROMA]
    write_lights(group, lights)
    group.attrs[ACQUISITION_ATTR] = acquisition
    record = {"n_frames": sink.n, "n_valid": n_valid, "rejected": lights.rejected(),
              "chroma": chroma, **info,
              "seconds": round(time.perf_counter() - started, 3)}
    complete_stage(group, STAGE, record)
    return record


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise LtmError(f"{name} {value!r} must be a positive integer")
    return int(value)
