"""Classic RTI captures (a ``.lp`` light file and its images) to the same store as ingest.

A light direction ``(lx, ly, lz)`` maps onto the illumination plane at height ``h`` as
``r = h lx / lz``, ``s = h ly / lz``. The plane rectangle is ``[-E, E]^2``; lights outside it
(low lights land far out) stay in the store, flagged invalid (``pose_valid`` False, counted as
``outside_bounds``), never dropped.
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.acquisition import sha256_file
from ltmstore.capture.lp import decode_image, read_lp
from ltmstore.core.dims import Plane
from ltmstore.core.errors import LtmError
from ltmstore.core.store import begin_stage, new_store
from ltmstore.stages.frames import DEFAULT_CHUNK_FRAMES, STAGE, FrameSink, Lights, finish_ingest

# Default plane half-extent in units of the height: every light above atan(1/2) ~ 26.6 degrees of
# elevation lands inside the square, every light below atan(1/(2 sqrt 2)) ~ 19.5 degrees outside.
EXTENT_PER_HEIGHT = 2.0


def rti_lights(directions: np.ndarray, plane: Plane) -> Lights:
    """Project unit directions onto the plane and flag the lights outside its rectangle."""
    h = plane.height
    r = h * directions[:, 0] / directions[:, 2]
    s = h * directions[:, 1] / directions[:, 2]
    return Lights.classify(r, s, np.full_like(r, h), plane=plane, known=np.ones(len(r), bool),
                           z_tolerance=0.0)


def ingest_rti(lp_path: str | os.PathLike, store: str | os.PathLike, *, height: float = 1.0,
               extent: float | None = None, overwrite: bool = False, progress: bool = True,
               chunk_frames: int = DEFAULT_CHUNK_FRAMES) -> dict:
    """Ingest a classic RTI capture (sRGB images under known light directions) into a store.

    The store has the layout of :func:`ltmstore.stages.ingest.ingest`: ``t`` is the image index
    (an ordinal, as float64), ``pose_z`` the plane height, and lights outside the plane rectangle
    are flagged invalid and counted as ``outside_bounds``.

    Parameters
    ----------
    lp_path : str or PathLike
        The ``.lp`` light file.
    store : str or PathLike
        Where to create the Zarr store.
    height : float, default 1.0
        Height of the illumination plane above the object (plane units).
    extent : float, optional
        Half-width ``E`` of the square plane ``[-E, E]^2``; default ``2 * height`` (a light is
        inside when ``max(|lx|, |ly|) <= 2 lz``: all lights above 26.6 degrees of elevation).
    overwrite : bool, default False
        Replace an existing store instead of refusing.
    progress : bool, default True
        Show a progress bar.
    chunk_frames : int, default 32
        Images per chunk along ``t``.

    Returns
    -------
    dict
        The ingest record (``n_frames``, ``n_valid``, ``rejected``, ``seconds``, ...) and
        ``store``.
    """
    started = time.perf_counter()
    lp_path = Path(lp_path)
    plane = _plane(height, extent)
    names, directions = read_lp(lp_path)
    lights = rti_lights(directions, plane)
    digest = hashlib.sha256()
    with new_store(store, overwrite=overwrite) as group:
        begin_stage(group, STAGE)
        sink = FrameSink(group, transfer="srgb", chunk_frames=chunk_frames)
        bar = tqdm(zip(names, lights.valid, strict=True), total=len(names),
                   disable=not progress, unit="image", desc="ingest")
        for name, valid in bar:
            data = (lp_path.parent / name).read_bytes()
            digest.update(data)
            sink.add(decode_image(data, name), bool(valid), source=f"image {name!r}")
        # sha256 "images": of all image files concatenated in .lp order
        acquisition = {"source": "rti", "lp": lp_path.name, "plane": plane.to_json(),
                       "height": plane.height, "transfer": "srgb", "images": names,
                       "frame_size": list(sink.shape),
                       "sha256": {"lp": sha256_file(lp_path), "images": digest.hexdigest()}}
        info = {"frame_size": list(sink.shape), "chunk_frames": chunk_frames}
        record = finish_ingest(group, sink, np.arange(sink.n, dtype=np.float64), lights,
                               acquisition=acquisition, info=info, started=started)
    return {**record, "store": str(store)}


def _plane(height: float, extent: float | None) -> Plane:
    if not (np.isfinite(height) and height > 0):
        raise LtmError(f"height {height!r} must be a positive number (plane units)")
    e = EXTENT_PER_HEIGHT * height if extent is None else extent
    if not (np.isfinite(e) and e > 0):
        raise LtmError(f"extent {extent!r} must be a positive number (plane units)")
    return Plane(r=(-e, e), s=(-e, e), height=float(height))


