"""Compact a reconstructed store: recompress its LTM, optionally in float16, and drop its frames.

After a complete reconstruction a near-light store relights from its ``ltm`` alone; the decoded
``frames`` (and ``frame_chroma``) are needed again only to reconstruct once more (re-ingest the
acquisition then). :func:`compact` rewrites the store on a linked copy beside it
(:func:`ltmstore.core.store.revised_store`) and swaps the copy in when it is complete, so a
failure or a kill leaves the store as it was (the copy is never reused: the next writer removes
it). A store with a stage that did not finish, or with a killed ``ltm reconstruct --overwrite``'s
revision beside it, is refused: finish that first.

What is done:

* every LTM variable is rewritten with :data:`ltmstore.core.checksum.LTM_COMPRESSORS` (lossless)
  in the chosen precision, with its light-major copy (:mod:`ltmstore.stages.by_light`) in a
  near-light store;
* ``precision="float16"`` (lossy) halves the LTM before compression; its cost, the SNR of the
  float16 LTM against the float32 one, is measured here and recorded;
* ``frames`` and ``frame_chroma`` are dropped unless ``keep_frames`` (a far-light store keeps
  them: it relights from them).

The stage ``compact`` in the store's provenance records what was done; ``ltm info`` shows it.
"""

from __future__ import annotations

import itertools
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import zarr

from ltmstore.core import checksum
from ltmstore.core import store as st
from ltmstore.core.dims import FRAME_CHROMA, FRAMES
from ltmstore.core.errors import LtmError
from ltmstore.core.lights import FAR, light_kind
from ltmstore.stages.by_light import LTM_NAMES, write_by_light

PRECISIONS = {"float32": np.float32, "float16": np.float16}
FRAME_VARIABLES = (FRAMES, FRAME_CHROMA)


def store_bytes(path: str | os.PathLike) -> int:
    """Bytes of every file of the store at ``path``."""
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def compact(path: str | os.PathLike, *, precision: str = "float32",
            keep_frames: bool = False) -> dict:
    """Recompress the LTM of a reconstructed store and drop its frames, atomically.

    Parameters
    ----------
    path : path-like
        A store whose ``reconstruct`` stage is complete.
    precision : {"float32", "float16"}
        The stored precision of the LTM variables: float32 is lossless; float16 is lossy (its
        SNR against float32, ``snr_db``, is measured and recorded). Readers through
        :func:`ltmstore.open_store` get float32 either way.
    keep_frames : bool
        Keep ``frames`` and ``frame_chroma`` (always kept for a far-light store).

    Returns
    -------
    dict
        ``bytes_before``, ``bytes_after``, ``precision``, ``snr_db`` (None when lossless),
        ``frames_dropped``, ``seconds``.
    """
    if precision not in PRECISIONS:
        raise LtmError(f"precision {precision!r} must be one of {', '.join(PRECISIONS)}")
    path = Path(os.path.abspath(path))
    group = st.open_group(path, mode="r")
    st.require_stage(group, "reconstruct", path)
    st.check_writable(path)
    far = light_kind(group.attrs.get("acquisition", {})) == FAR
    drop = [n for n in FRAME_VARIABLES if n in group] if not (keep_frames or far) else []
    start, before = time.perf_counter(), store_bytes(path)
    try:
        with st.writing(path) as real:
            _refuse_unfinished(path, real)
            with st.revised_store(real, resumable=False) as side:
                info = _compact_copy(real, side, PRECISIONS[precision], drop)
                info.update(precision=precision,
                            frames_dropped=bool(drop) or not _has_frames(side),
                            frames_kept_reason="far-light store: relit from its frames" if far
                            else None, bytes_before=before)
                info["seconds"] = time.perf_counter() - start
                side_group = zarr.open_group(str(side), mode="r+", zarr_format=3)
                st.complete_stage(side_group, "compact", info)
    except OSError as exc:
        raise LtmError(f"cannot compact store {str(path)!r}: {exc.strerror or exc}; the store "
                       "is untouched") from exc
    info["bytes_after"] = store_bytes(path)
    return info


def _refuse_unfinished(path: Path, real: Path) -> None:
    """Refuse a store with a stage that did not finish, in it or in a revision beside it.

    A killed ``ltm reconstruct --overwrite`` leaves its half-built revision beside the store
    (:func:`ltmstore.core.store.revision_path`, resumed by the next such run): compacting now
    would either take its samples of another lattice or throw its work away.
    """
    unfinished = [name for name, entry in st.stages(st.open_group(real, mode="r")).items()
                  if not entry.get("complete")]
    if unfinished:
        raise LtmError(f"store {str(path)!r}: stage {unfinished[0]!r} did not finish "
                       "(interrupted?); run it again to finish it, then compact")
    side = st.revision_path(real)
    if side.exists():
        raise LtmError(f"store {str(path)!r} has an unfinished `ltm reconstruct --overwrite` "
                       f"(interrupted?) building its new ltm in {str(side)!r}; run that "
                       f"reconstruct --overwrite again to finish it, or remove {str(side)!r} to "
                       "keep the current ltm, then compact")


def _has_frames(path: Path) -> bool:
    return (path / FRAMES).is_dir()


def _compact_copy(path: Path, side: Path, dtype, drop: list[str]) -> dict:
    """Rewrite the LTM variables of the linked copy ``side`` from the store at ``path``."""
    source = st.open_group(path, mode="r")
    target = zarr.open_group(str(side), mode="r+", zarr_format=3)
    signal = noise = 0.0
    near = light_kind(source.attrs.get("acquisition", {})) != FAR
    for name in LTM_NAMES:
        if name not in source:
            continue
        s, n = _rewrite(source[name], target, name, dtype)
        signal, noise = signal + s, noise + n
        if near:  # a far-light store relights from its frames, not from its ltm
            write_by_light(target, name)
    for name in drop:
        shutil.rmtree(side / name, ignore_errors=True)  # the copy's links: the store keeps its
    lossy = np.dtype(dtype) != np.float32
    snr = 10 * np.log10(signal / noise) if lossy and noise > 0 else None
    return {"snr_db": None if snr is None else float(snr), "dropped": drop}


def _rewrite(src: zarr.Array, group: zarr.Group, name: str, dtype) -> tuple[float, float]:
    """Write ``src`` as ``group[name]`` in ``dtype`` (same chunks and shards, LTM codecs);
    return the sums of squares of the values and of the rounding error."""
    dst = st.create_variable(group, name, src.metadata.dimension_names, src.shape,
                             chunks=src.chunks, shards=src.shards, dtype=dtype,
                             compressors=checksum.LTM_COMPRESSORS)
    dst.attrs.update(src.attrs.asdict())
    part = src.shards or src.chunks
    corners = itertools.product(*(range(0, n, c) for n, c in zip(src.shape, part, strict=True)))

    def copy(corner: tuple[int, ...]) -> tuple[float, float]:
        region = tuple(slice(a, min(a + c, n)) for a, c, n in zip(corner, part, src.shape,
                                                                  strict=True))
        values = src[region]
        stored = values.astype(dtype)
        dst[region] = stored
        finite = np.isfinite(values)
        error = values[finite].astype(np.float64) - stored[finite]
        return float(np.sum(values[finite].astype(np.float64) ** 2)), float(np.sum(error ** 2))

    with ThreadPoolExecutor(max_workers=2) as pool:
        sums = list(pool.map(copy, corners))
    return sum(s for s, _ in sums), sum(n for _, n in sums)

