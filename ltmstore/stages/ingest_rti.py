"""Classic RTI captures (a ``.lp`` light file and its images) to a far-light store.

A classic capture's lights are far lights: directions, the same for every pixel. The store keeps
them as such (:mod:`ltmstore.core.lights`): ``pose_r = lx``, ``pose_s = ly``, ``pose_z = lz``,
every light above the horizon valid (none is squeezed through a plane or dropped for lying far
out), and the acquisition record says ``light_kind: far`` with the units of ``r, s``.
``plane`` is the square ``[-1, 1]^2`` of direction cosines that holds the unit disk.

Photographs are 8-bit, 16-bit (PNG, TIFF, raw photographs developed linear by LibRaw) or
floating point (TIFF), all of one depth, each kept at its precision (the frames are linear
light). Their transfer (sRGB or linear) is declared, or read from the files
(:func:`ltmstore.capture.photographs.image_transfer`: a float or raw image is linear; a PNG's
``sRGB`` or ``gAMA`` chunk, an ICC profile's tone curve), else sRGB; a capture whose files say
two different things is refused. The store records the transfer, where it came from and the
depth (``acquisition.transfer``, ``transfer_source``, ``depth``: ``8-bit``, ``16-bit`` or
``float``).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import closing
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.acquisition import sha256_file
from ltmstore.capture.lp import hidden_lights, read_lp
from ltmstore.capture.photographs import (
    DEPTH_NAMES,
    decode_image,
    image_orientation,
    image_transfer,
    warn_orientations,
)
from ltmstore.core.dims import OBSERVATION_DTYPE
from ltmstore.core.errors import LtmError, brief
from ltmstore.core.lights import DISK, FAR, KIND_ATTR, coordinate_attrs
from ltmstore.core.paths import check_output
from ltmstore.core.store import begin_stage, new_store
from ltmstore.core.transfer import TRANSFERS, srgb_to_linear
from ltmstore.stages.frames import (
    BAND_PIXELS,
    DEFAULT_CHUNK_FRAMES,
    STAGE,
    FrameSink,
    Lights,
    finish_ingest,
)

# DISK: re-exported from core.lights
__all__ = ["DISK", "far_lights", "held_out_record", "ingest_rti"]

# Memory held by frames waiting to be written (one chunk along t) and, apart, by photographs
# decoded ahead of the writer: fewer frames held (spilled: FrameSink) and fewer ahead on large
# photographs, and
# photographs above BAND_PIXELS converted by the writer band by band, so that a 24 MP capture
# ingests in a bounded amount of memory (bench/ingest_memory.py).
BUFFER_BYTES = 256 * 2**20


def far_lights(directions: np.ndarray) -> Lights:
    """Every unit direction ``(n, 3)`` as a valid far light (``r, s, z = lx, ly, lz``)."""
    none = np.zeros(len(directions), dtype=bool)
    return Lights(r=directions[:, 0].copy(), s=directions[:, 1].copy(),
                  z=directions[:, 2].copy(), beyond_poses=none, out_of_plane=none,
                  outside_bounds=none)


def ingest_rti(lp_path: str | os.PathLike, store: str | os.PathLike, *,
               lights: Sequence[int] | None = None, holdout_every: int | None = None,
               overwrite: bool = False, transfer: str | None = None,
               progress: bool = True, chunk_frames: int = DEFAULT_CHUNK_FRAMES) -> dict:
    """Ingest a classic RTI capture (images under known light directions) into a store.

    The store has the layout of :func:`ltmstore.stages.ingest.ingest`: ``t`` is the image index
    (an ordinal, as float64) and the poses hold the light directions (a far-light store).

    Parameters
    ----------
    lp_path : str or PathLike
        The ``.lp`` light file.
    store : str or PathLike
        Where to create the Zarr store.
    lights : sequence of int, optional
        Keep only these lights (indices among the ``.lp`` file's lights above the horizon),
        e.g. to fit without held-out lights; default all.
    holdout_every : int, optional
        Leave out every ``holdout_every``-th light (lights ``k-1, 2k-1, ...``,
        :func:`ltmstore.capture.lp.hidden_lights`, the protocol of ``ltm evaluate
        --holdout-lights``) and record them in the ingest stage record: ``holdout_every`` and
        ``held_out``, per light its ``index``, ``image`` and ``direction``
        (:func:`held_out_record`), so that ``ltm info`` lists them and ``ltm evaluate
        --holdout-lights`` scores them without being told the number. Not with ``lights``.
    overwrite : bool, default False
        Replace an existing store instead of refusing (never the ``.lp`` file, one of its
        images or a folder holding them: :func:`ltmstore.core.paths.check_output`).
    transfer : {"srgb", "linear"}, optional
        How the photographs' values encode light, declared (then the files' marks are not
        read); default: what the first photograph says
        (:func:`ltmstore.capture.photographs.image_transfer`), else sRGB.
        Every photograph must have the first one's depth and, when not declared, say no other
        transfer. A floating-point photograph declared sRGB is decoded by sRGB's curve.
    progress : bool, default True
        Show a progress bar.
    chunk_frames : int, default 32
        Images per chunk along ``t``.

    Returns
    -------
    dict
        The ingest record (``n_frames``, ``n_valid``, ``rejected``, ``seconds``, ...;
        ``holdout_every`` and ``held_out`` with ``holdout_every``) and ``store``.
    """
    started = time.perf_counter()
    lp_path = Path(lp_path)
    if transfer is not None and transfer not in TRANSFERS:
        raise LtmError(f"transfer {transfer!r} is unknown; expected one of "
                       f"{', '.join(TRANSFERS)} (or none: read from the files)")
    names, directions = read_lp(lp_path)
    inputs = (lp_path, *(lp_path.parent / name for name in names))
    check_output(store, inputs, what="store")
    held_out = None
    if holdout_every is not None:
        if lights is not None:
            raise LtmError("give either lights or holdout_every, not both")
        hidden = hidden_lights(len(names), holdout_every)
        held_out = held_out_record(names, directions, hidden)
        lights = np.flatnonzero(~hidden).tolist()
    if lights is not None:
        keep = np.asarray(lights, dtype=int)
        if keep.size == 0 or keep.min() < 0 or keep.max() >= len(names):
            raise LtmError(f"lights {brief(lights)} must be indices of the {len(names)} "
                           f"lights of {str(lp_path)}")
        names, directions = [names[i] for i in keep], directions[keep]
    lights = far_lights(directions)
    digest = hashlib.sha256()
    first, says = _first_image(lp_path.parent, names[0])  # before the store: a bad one
    chosen = Transfer.choose(transfer, names[0], first, says)  # leaves none
    with new_store(store, overwrite=overwrite, inputs=inputs) as group:
        begin_stage(group, STAGE)
        pixels = first.shape[0] * first.shape[1]
        sink = FrameSink(group, transfer=chosen.transfer, expected_frames=len(names),
                         chunk_frames=chunk_frames,
                         held_frames=_frames_held(pixels, chunk_frames))
        # closing: the decoding threads end with an error too
        by_band = pixels > BAND_PIXELS
        # RGB, and its float32 Y, Cb, Cr
        decoded = pixels * (3 * first.dtype.itemsize + (0 if by_band else 3 * 4))
        with closing(_decoded(lp_path.parent, names, None if by_band else sink.convert,
                              ahead=max(1, BUFFER_BYTES // max(1, decoded)),
                              transfer=chosen.transfer)) as images:
            bar = tqdm(zip(names, lights.valid, images, strict=True), total=len(names),
                       disable=not progress, unit="image", desc="ingest")
            tagged, white = {}, 0
            for name, valid, (data, rgb, ycc, orientation, says) in bar:
                chosen.check(name, rgb.dtype, says)
                digest.update(data)
                sink.add(rgb, bool(valid), source=f"image {name!r}", ycc=ycc)
                white += int(_white(rgb))
                if orientation != 1:
                    tagged[name] = orientation
        if white == len(names):
            raise LtmError(f"all {white} photographs of {str(lp_path)} are white in every "
                           "pixel (saturated): nothing to relight; expected photographs "
                           "exposed to keep the object's detail")
        warn_orientations(tagged, len(names))
        # sha256 "images": of all image files concatenated in .lp order
        acquisition = {"source": "rti", KIND_ATTR: FAR, "lp": lp_path.name,
                       "lp_path": str(lp_path.resolve()), "plane": DISK.to_json(),
                       "coordinates": coordinate_attrs(FAR), "transfer": chosen.transfer,
                       "transfer_source": chosen.source, "depth": chosen.depth, "images": names,
                       "frame_size": list(sink.shape),
                       "sha256": {"lp": sha256_file(lp_path), "images": digest.hexdigest()}}
        info = {"frame_size": list(sink.shape), "chunk_frames": chunk_frames,
                **({"holdout_every": int(holdout_every), "held_out": held_out}
                   if held_out else {})}
        record = finish_ingest(group, sink, np.arange(sink.n, dtype=np.float64), lights,
                               acquisition=acquisition, info=info, started=started)
    return {**record, "store": str(store)}


def held_out_record(names: Sequence[str], directions: np.ndarray,
                    hidden: np.ndarray) -> list[dict]:
    """What the ingest stage records of the lights ``hidden`` (bool, one per light of the
    ``.lp``): per light its ``index`` (among the ``.lp`` file's lights above the horizon),
    ``image`` and ``direction``."""
    return [{"index": int(i), "image": names[i],
             "direction": [float(v) for v in directions[i]]} for i in np.flatnonzero(hidden)]


class Transfer:
    """The transfer and depth of a capture: chosen from its first photograph (or declared),
    and checked against every photograph (:meth:`check`)."""

    def __init__(self, transfer: str, source: str, declared: bool, first: str,
                 dtype: np.dtype) -> None:
        self.transfer, self.source, self.declared = transfer, source, declared
        self.first, self.dtype = first, np.dtype(dtype)
        self.depth = DEPTH_NAMES[self.dtype]

    @classmethod
    def choose(cls, declared: str | None, name: str, rgb: np.ndarray,
               said: tuple[str | None, str]) -> Transfer:
        """``declared``, or what the first photograph ``name`` (decoded: ``rgb``) says
        (``said``: :func:`~ltmstore.capture.photographs.image_transfer`), else sRGB."""
        says, source = said
        if declared is not None:
            return cls(declared, "declared", True, name, rgb.dtype)
        if says is None:
            return cls("srgb", f"default (the first image {name!r}: {source})", False, name,
                       rgb.dtype)
        return cls(says, f"the first image {name!r}: {source}", False, name, rgb.dtype)

    def check(self, name: str, dtype: np.dtype, says: tuple[str | None, str]) -> None:
        """Refuse, in one line naming it, a photograph of another depth or (not declared) one
        whose file says another transfer."""
        if np.dtype(dtype) != self.dtype:
            raise LtmError(f"image {name!r} is {DEPTH_NAMES[np.dtype(dtype)]}; expected "
                           f"{self.depth} like the first image {self.first!r} (one depth per "
                           "capture)")
        if not self.declared and says[0] not in (None, self.transfer):
            raise LtmError(f"image {name!r} says its transfer is {says[0]} ({says[1]}); the "
                           f"capture's is {self.transfer} ({self.source}): declare it with "
                           "--transfer srgb|linear")


def _first_image(folder: Path, name: str) -> tuple[np.ndarray, tuple[str | None, str]]:
    """A capture's first photograph decoded, and what its file says of its transfer (an
    unreadable one is refused here, before a store is made)."""
    path = folder / name
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LtmError(f"image {name!r} cannot be read: {exc.strerror or exc}") from None
    rgb = decode_image(data, name)
    return rgb, image_transfer(data, rgb.dtype, name)


def _white(rgb: np.ndarray) -> bool:
    """Whether an integer photograph is white in every pixel (saturated); a float one never
    is (light beyond 1 is kept)."""
    if rgb.dtype.kind != "u":
        return False
    top = np.iinfo(rgb.dtype).max
    # the first row first: almost every photograph has a pixel below white there, and a whole
    # photograph is slow to reduce
    return bool(rgb[0].min() == top) and bool(rgb.min() == top)


def _frames_held(pixels: int, requested: int) -> int:
    """``requested``, or fewer where that many frames of ``pixels`` would hold more than
    :data:`BUFFER_BYTES` before they are written."""
    per_frame = 3 * np.dtype(OBSERVATION_DTYPE).itemsize * pixels  # Y and Cb, Cr
    return min(requested, max(1, BUFFER_BYTES // max(1, per_frame)))  # a bad one: refused


def _decoded(folder: Path, names: Sequence[str],
             convert: Callable[[np.ndarray], np.ndarray] | None, *,
             workers: int | None = None, ahead: int | None = None, transfer: str = "srgb"
             ) -> Iterator[tuple[bytes, np.ndarray, np.ndarray | None, int,
                                 tuple[str | None, str]]]:
    """``(file bytes, RGB, convert(RGB), EXIF orientation, what the file says of its
    transfer)`` of each image in ``names``, in order (``convert`` None: ``None`` for the
    converted image). A floating-point image of an sRGB ``transfer`` is decoded to linear
    light by sRGB's curve (integer ones are, by ``convert``).

    A few threads read, decode and convert ahead of the caller (OpenCV and NumPy release the
    GIL); at most two images per thread wait, and at most ``ahead`` in all, so memory stays
    bounded on long captures and large photographs. An image that cannot be decoded raises
    when its turn comes.
    """
    def load(name: str) -> tuple[bytes, np.ndarray, np.ndarray, int, tuple[str | None, str]]:
        data = (folder / name).read_bytes()
        rgb = decode_image(data, name)
        says = image_transfer(data, rgb.dtype, name)
        if rgb.dtype.kind == "f" and transfer == "srgb":
            rgb = srgb_to_linear(rgb)
        return data, rgb, convert and convert(rgb), image_orientation(data, name), says

    workers = workers or max(1, min(4, os.cpu_count() or 1))
    depth = 2 * workers if ahead is None else min(2 * workers, ahead)
    todo = iter(names)
    with ThreadPoolExecutor(max_workers=min(workers, depth)) as pool:
        waiting = deque(pool.submit(load, name) for _, name in zip(range(depth), todo,
                                                                  strict=False))
        try:
            while waiting:
                image = waiting.popleft().result()
                for name in todo:  # keep the queue full: one in for one out
                    waiting.append(pool.submit(load, name))
                    break
                yield image
        finally:  # the caller stopped early (an error): decode nothing more
            for future in waiting:
                future.cancel()
