"""Video frames and poses to the store: streaming, linearised, luminance plus chroma ratios.

Layout written (ARCHITECTURE.md section 3.2), for ``n`` frames of ``H x W`` pixels:

* coordinates ``t (t,)`` float64 seconds, ``y (H,)`` and ``x (W,)`` int64, ``channel`` ("cb", "cr");
* ``frames (t, y, x)`` float16 linear luminance Y (BT.601), chunks
  ``(chunk_frames, min(H, 256), min(W, 256))`` (16 x 16 pixels for registered 6D frames);
* ``pose_r, pose_s, pose_z (t,)`` float64 light position at each frame (NaN where the pose record
  does not cover the frame), plus ``pose_p, pose_q`` for 6D acquisitions; ``pose_valid (t,)`` bool;
  ``pose_axis_r, pose_axis_s, pose_axis_z (t,)``, phone A's LED axis, where the poses give it;
* ``chroma (y, x, channel)`` float32: ``sum_t Cb / sum_t Y`` and ``sum_t Cr / sum_t Y`` over the
  valid frames (0 where ``sum_t Y == 0``): colour as a ratio to luminance, illumination invariant;
* group attribute ``acquisition`` (provenance, input hashes) and stage ``ingest``.

A frame is rejected (``pose_valid`` False) for the first of these reasons that applies:
``beyond_poses`` (its time lies outside the pose record or in a gap of it longer than
:data:`MAX_POSE_GAP_S`), ``out_of_plane`` (the light is further than the z tolerance from the
plane height; default :data:`Z_TOLERANCE_FRACTION` of the height, about a 10 % change of
irradiance by the inverse-square law) and ``outside_bounds`` (the light is outside the plane
rectangle, or the camera outside the view plane).

Camera B as a phone films it (:mod:`ltmstore.stages.phone`): with ``camera_calibration`` in
``acquisition.json`` every frame is undistorted; a leading LED-off segment gives the room
light's image, subtracted from every frame (its frames are rejected as ``led_off``); a drift of
the camera's gain or white balance is estimated from the frames and divided out, or refused.
Where ``poses.csv`` gives phone A's LED axis (``axis_r, axis_s, axis_z``) the LED's ``cos^k``
beam about it is part of that estimate, so that a hand's wobble is not taken for drift, and its
exponent is recorded (``beam``); the axis is stored for the reconstruction's surface model.

6D acquisitions (``view_plane`` in ``acquisition.json``, ``p, q`` columns in ``poses.csv``)
whose ``view_plane`` declares camera B (``distance``, ``intrinsics``, ``grid``): every frame is
registered onto the declared object-plane grid by the plane-induced homography of
camera B at that frame's interpolated ``(p, q)`` (:mod:`ltmstore.capture.register`), after
linearisation; grid pixels outside the frame are NaN in ``frames`` (unobserved in that frame),
and chroma sums skip them.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.acquisition import Acquisition, load_acquisition, load_poses
from ltmstore.capture.register import ViewRig
from ltmstore.capture.undistort import Undistorter
from ltmstore.capture.video import VideoReader, threaded_first
from ltmstore.core.dims import Plane
from ltmstore.core.errors import LtmError
from ltmstore.core.paths import check_output
from ltmstore.core.store import begin_stage, new_store
from ltmstore.core.transfer import transfer_lut
from ltmstore.stages.frames import (
    DEFAULT_CHUNK_FRAMES,
    STAGE,
    FrameSink,
    Lights,
    finish_ingest,
    lights_at,
)
from ltmstore.stages.occlusion import occluded_frames
from ltmstore.stages.phone import Corrections, plan_corrections, scan_video

Z_TOLERANCE_FRACTION = 0.05


def ingest(acq_dir: str | os.PathLike, store: str | os.PathLike, *, overwrite: bool = False,
           z_tolerance: float | None = None, progress: bool = True,
           chunk_frames: int = DEFAULT_CHUNK_FRAMES, hashes: dict[str, str] | None = None,
           allow_dropped: bool = False, exposure_locked: bool = False,
           keep_chroma: bool = False) -> dict:
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
    allow_dropped : bool, default False
        Leave out damaged or missing video frames (counted as ``dropped_frames``) instead of
        failing (:class:`ltmstore.capture.video.VideoReader`).
    exposure_locked : bool, default False
        Camera B's exposure and white balance were locked: a drift of its gain that the video
        cannot measure (a path that rarely comes back to the same places) is left uncorrected
        instead of refused (recorded as ``drift.exposure_locked``); a measured one is still
        corrected, and auto exposure still refused.
    keep_chroma : bool, default False
        Keep ``frame_chroma`` (each frame's Cb, Cr) even when the colour is illumination
        invariant, for a colour LTM asked for with ``reconstruct(color=True)``. Otherwise it is
        kept only where the colour varies with the light (it is two thirds of the per-frame
        bytes).

    Returns
    -------
    dict
        ``n_frames``, ``n_valid``, ``rejected`` (per reason), ``fps``, ``frame_size``,
        ``z_tolerance``, ``timings`` (``setup``: reading and hashing the inputs; ``scan``: the
        first pass over the video; ``frames``: decoding and writing) and ``seconds`` (total);
        for a fixed camera B ``undistort``, ``ambient``, ``drift`` and, where the poses give
        the LED's axis, ``beam`` (what :mod:`ltmstore.stages.phone` found and corrected;
        ``rejected`` then counts ``led_off`` frames when the video starts with an LED-off lead)
        (also stored as stage ``ingest``), and ``store``.

    Raises
    ------
    LtmError
        For a bad acquisition folder, an undecodable video, a ``camera_calibration`` of
        another frame size, an existing store without ``overwrite``, a store path that is,
        lies in or holds the acquisition folder or one of its files, fewer than
        :data:`MIN_VALID_FRAMES` valid frames, or camera B's exposure or white balance drifting
        more than can be corrected (nothing is written then).
    """
    started = time.perf_counter()
    acq = load_acquisition(acq_dir)
    check_output(store, _inputs(acq_dir, acq), what="store")  # before hashing and decoding
    poses = load_poses(acq.poses)
    if acq.view_plane is not None and poses.p is None:
        raise LtmError(f"{str(acq.poses)}: acquisition.json declares a view_plane but the poses "
                       "have no p, q columns; expected header 't,r,s,z,p,q'")
    if acq.view_plane is None and poses.p is not None:
        raise LtmError(f"{str(acq.poses)}: the poses have p, q columns (a moving camera, 6D) "
                       "but acquisition.json declares no view_plane; expected 'view_plane': "
                       "{'p': [min, max], 'q': [min, max]}, or header 't,r,s,z' for a fixed "
                       "camera")
    z_tolerance = _z_tolerance(z_tolerance, acq.plane)
    rig = _rig(acq)
    light = partial(lights_at, poses=poses, plane=acq.plane, z_tolerance=z_tolerance,
                    time_offset=acq.time_offset, view_plane=acq.view_plane)
    hashes = hashes or _sha256(acq)
    hashed = time.perf_counter()
    corrections = _corrections(acq, rig, light, allow_dropped=allow_dropped,
                               exposure_locked=exposure_locked)
    scanned = time.perf_counter()
    write = partial(_write_frames, acq, store, rig, light, corrections, overwrite=overwrite,
                    progress=progress, chunk_frames=chunk_frames, z_tolerance=z_tolerance,
                    allow_dropped=allow_dropped, keep_chroma=keep_chroma, hashes=hashes,
                    times=(started, hashed, scanned))
    record = threaded_first(write)
    return {**record, "store": str(store)}


def _inputs(acq_dir: str | os.PathLike, acq: Acquisition) -> tuple:
    """What ingest reads: the acquisition's files and its whole folder (a store inside it
    would replace what lies there)."""
    return (acq.video, acq.poses, acq.camera_calibration, acq_dir)


def _write_frames(acq: Acquisition, store: str | os.PathLike, rig: ViewRig | None,
                  light: partial, corrections: Corrections | None, threaded: bool, *,
                  overwrite: bool, progress: bool, chunk_frames: int, z_tolerance: float,
                  allow_dropped: bool, keep_chroma: bool, hashes: dict[str, str],
                  times: tuple[float, float, float]) -> dict:
    """The pass that writes the store: every frame decoded, corrected and added; the stage
    record (``times``: when :func:`ingest` started, had hashed and had scanned)."""
    started, hashed, scanned = times
    with VideoReader(acq.video, allow_dropped=allow_dropped,
                     threaded=threaded) as video, new_store(
            store, overwrite=overwrite, inputs=_inputs(acq.folder, acq)) as group:
        begin_stage(group, STAGE)
        sink = FrameSink(group, transfer=acq.transfer, chunk_frames=chunk_frames, rig=rig)
        bar = tqdm(video.frames(), total=video.frame_count, disable=not progress, unit="frame",
                   desc="ingest")
        index = []
        lut = transfer_lut(acq.transfer, bits=8)
        for i, rgb in bar:
            at = light(np.array([i / video.fps]))
            view = None
            if rig is not None:
                _check_frame_size(rgb, rig, acq.video)
                view = (float(at.view["p"][0]), float(at.view["q"][0]))
            ycc = None if corrections is None else corrections.linear(i, rgb, lut, acq.video)
            valid = bool(at.valid[0]) and (corrections is None or corrections.lead_end is None
                                           or i >= corrections.lead_end)
            sink.add(rgb, valid, source=f"video {str(acq.video)!r} frame {i}", view=view,
                     ycc=ycc)
            index.append(i)
        t = np.array(index, dtype=np.float64) / video.fps
        timings = {"setup": round(hashed - started, 3),
                   "scan": round(scanned - hashed, 3),
                   "frames": round(time.perf_counter() - scanned, 3)}
        info = {"fps": video.fps, "frame_size": list(sink.shape), "z_tolerance": z_tolerance,
                "time_offset": acq.time_offset, "chunk_frames": chunk_frames, "timings": timings,
                "dropped_frames": dict(video.dropped), "video": video.encoding()}
        if corrections is not None:
            info.update(corrections.record)
        if rig is not None:
            info["registration"] = {
                "camera_frame_size": [rig.intrinsics.height, rig.intrinsics.width],
                "observed_fraction_mean": sink.observed[0] / max(sink.observed[1], 1)}
        provenance = _provenance(acq, hashes, video, sink, rig)
        lights = light(t)
        if corrections is not None and corrections.lead_end is not None:
            lights = replace(lights, led_off=np.array(index) < corrections.lead_end)
        record = finish_ingest(group, sink, t, _judge_occlusion(lights, sink, rig),
                               acquisition=provenance, info=info, started=started,
                               keep_chroma=keep_chroma)
    return record


def _corrections(acq: Acquisition, rig: ViewRig | None, light: partial, *,
                 allow_dropped: bool, exposure_locked: bool) -> Corrections | None:
    """Camera B's corrections (:mod:`ltmstore.stages.phone`): a fixed camera's video is scanned
    once for the LED-off lead and gain drift; a moving camera's is only undistorted."""
    undistort = (None if acq.camera_calibration is None
                 else Undistorter.from_file(acq.camera_calibration))
    if rig is not None or acq.view_plane is not None:
        if undistort is None:
            return None
        return Corrections(undistort, None, None, None, {"undistort": undistort.to_json()})
    lut = transfer_lut(acq.transfer, bits=8)
    scan = scan_video(acq.video, lut, allow_dropped=allow_dropped)
    if undistort is not None and scan.head:
        undistort.check_size(scan.head[0], acq.video)
    return plan_corrections(scan, light(scan.index / scan.fps), acq.plane, undistort=undistort,
                            lut=lut, exposure_locked=exposure_locked)


def _judge_occlusion(lights: Lights, sink: FrameSink, rig: ViewRig | None) -> Lights:
    """``lights`` with the occluded frames (:mod:`ltmstore.stages.occlusion`) rejected: 4D
    captures (a moving camera B changes the brightness too, which the model does not hold)."""
    if rig is not None or lights.view:
        return lights
    mask = occluded_frames(np.asarray(sink.brightness), lights.r, lights.s, lights.z,
                           lights.valid)
    return replace(lights, occluded=mask)


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
    if acq.object_extent is not None:
        meta["object"] = acq.object_extent
    if acq.view_plane is not None:
        meta["view_plane"] = {**acq.view_plane, **(rig.to_json() if rig is not None else {})}
    return meta


def _z_tolerance(value: float | None, plane: Plane) -> float:
    if value is None:
        return Z_TOLERANCE_FRACTION * plane.height
    if not (np.isfinite(value) and value >= 0):
        raise LtmError(f"z_tolerance {value!r} must be a non-negative number (plane units)")
    return float(value)
