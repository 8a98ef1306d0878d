"""Compact a reconstructed store: recompress its LTM, optionally in float16, and drop its frames.

After a complete reconstruction a near-light store relights from its ``ltm`` alone; the decoded
``frames`` (and ``frame_chroma``) are needed again only to reconstruct once more (re-ingest the
acquisition then). :func:`compact` rewrites the store on a linked copy beside it
(:func:`ltmstore.core.store.revised_store`) and swaps the copy in when it is complete, so a
failure or a kill leaves the store as it was (the copy is never reused: the next writer removes
it). A store with a stage that did not finish, or with a killed ``ltm reconstruct --overwrite``'s
revision beside it, is refused: finish that first.

What is done:

* every LTM variable is rewritten with :data:`ltmstore.core.checksum.FAST_COMPRESSORS` (lossless)
  in the chosen precision, with its light-major copy (:mod:`ltmstore.stages.by_light`) in a
  near-light store;
* ``precision="float16"`` (lossy) halves the LTM before compression; its cost, the SNR of the
  float16 LTM against the float32 one, is measured here and recorded;
* ``frames`` and ``frame_chroma`` are dropped unless ``keep_frames`` (a far-light store keeps
  them: it relights from them).

* ``form="factored"`` (lossy) stores each LTM variable as a per-tile basis and per-pixel
  weights (:mod:`ltmstore.core.factored`) at the least rank that keeps ``target_db`` in every
  pixel tile, in place of the dense array and its light-major copy;
  :func:`ltmstore.open_store` presents ``ltm`` (and its light-major view) as their lazy product,
  and relighting one point light computes ``W (B l)`` for its cells only. The SNR of the stored
  product against the dense float32 LTM is measured here and recorded.

The stage ``compact`` in the store's provenance records what was done; ``ltm info`` shows it.
"""

from __future__ import annotations

import itertools
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np
import zarr
from tqdm import tqdm

from ltmstore.core import checksum, factored
from ltmstore.core import store as st
from ltmstore.core.dims import EXPECTED_ERROR, FRAME_CHROMA, FRAMES, LTM, SAMPLES
from ltmstore.core.errors import LtmError
from ltmstore.core.lights import FAR, light_kind
from ltmstore.solve.validate import observed_range
from ltmstore.stages import factors
from ltmstore.stages.by_light import LTM_NAMES, by_light_name, write_by_light
from ltmstore.stages.factors import FORMS

PRECISIONS = {"float32": np.float32, "float16": np.float16}
FRAME_VARIABLES = (FRAMES, FRAME_CHROMA)


def store_bytes(path: str | os.PathLike) -> int:
    """Bytes of every file of the store at ``path``."""
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def compact(path: str | os.PathLike, *, precision: str = "float32",
            keep_frames: bool = False, form: str = "dense",
            target_db: float | None = None, tile: int = factored.DEFAULT_TILE,
            progress: bool = True) -> dict:
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
    form : {"dense", "factored"}
        ``factored``: a basis per pixel tile and per-pixel weights in ``precision``, in place of
        the dense LTM (lossy: ``snr_db`` is measured against the dense float32 LTM). A store
        that ``ltm reconstruct`` factored keeps its factors as they are (its frames are
        dropped; the record's ``form`` says ``factored``).
    target_db : float, optional
        The factored form's least SNR (dB) in every pixel tile, before rounding to
        ``precision``. None (the default): each tile keeps the singular values above the
        noise of the model's held-out error there
        (:func:`ltmstore.core.factored.heldout_threshold`, from the stored ``expected_error``;
        a colour LTM loses the same fraction of its energy as the luminance of its tile).
    tile : int
        The factored form's pixel tile side.
    progress : bool
        A progress bar over the tiles being factored.

    Returns
    -------
    dict
        ``bytes_before``, ``bytes_after``, ``precision``, ``form``, ``snr_db`` (None when
        lossless), ``frames_dropped``, ``seconds``; for the factored form also ``tile``,
        ``target_db`` or ``rank_rule`` (the rank rule) and ``ranks`` (min, mean, max
        over tiles, per LTM variable).
    """
    if precision not in PRECISIONS:
        raise LtmError(f"precision {precision!r} must be one of {', '.join(PRECISIONS)}")
    if form not in FORMS:
        raise LtmError(f"form {form!r} must be one of {', '.join(FORMS)}")
    if form == "factored" and not ((target_db is None or 0 < target_db < 150) and tile >= 1):
        raise LtmError(f"target SNR {target_db!r} dB must lie in (0, 150), tile {tile!r} >= 1")
    path = Path(os.path.abspath(path))
    group = st.open_group(path, mode="r")
    st.require_stage(group, "reconstruct", path)
    maker = factored.factored_by(st.stages(group))
    if maker == "compact":
        raise LtmError(f"store {str(path)!r} is already compacted to the factored form; run "
                       "ltm reconstruct --overwrite on a fresh ingest for a dense ltm")
    if form == "factored" and factored.weights_name(LTM) in group:
        raise LtmError(f"store {str(path)!r} already holds the factored form (ltm reconstruct "
                       "--form factored); expected a dense ltm to factor")
    st.check_writable(path)
    far = light_kind(group.attrs.get("acquisition", {})) == FAR
    drop = [n for n in FRAME_VARIABLES if n in group] if not (keep_frames or far) else []
    start, before = time.perf_counter(), store_bytes(path)
    try:
        with st.writing(path) as real:
            _refuse_unfinished(path, real)
            with st.revised_store(real, resumable=False) as side:
                info = (_compact_copy(real, side, PRECISIONS[precision], drop)
                        if form == "dense" else
                        _factor_copy(real, side, PRECISIONS[precision], drop, target_db, tile,
                                     progress))
                kept = maker == "reconstruct"  # its factors stay as they are
                info.update(precision=str(group[factored.weights_name(LTM)].dtype) if kept
                            else precision, form="factored" if kept else form,
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
                             compressors=checksum.FAST_COMPRESSORS)
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



def _factor_copy(path: Path, side: Path, dtype, drop: list[str], target_db: float | None,
                 tile: int, progress: bool) -> dict:
    """Replace every LTM variable of the linked copy ``side`` by its factors
    (:mod:`ltmstore.core.factored`); drop its light-major copy."""
    source = st.open_group(path, mode="r")
    target = zarr.open_group(str(side), mode="r+", zarr_format=3)
    signal = noise = 0.0
    ranks, stored = {}, {"dense_bytes": 0, "factor_bytes": 0}
    kept = {}  # per tile: the fraction of its luminance energy the factors left out
    for name in LTM_NAMES:
        if name not in source:
            continue
        if len(source[name].shape) != 4:
            raise LtmError(f"the factored form holds a 4D ltm (y, x, r, s); this store's "
                           f"{name} has dims {source[name].metadata.dimension_names}")
        if target_db is not None:
            rule = partial(_target_rule, target_db)
        elif name == LTM:
            rule = partial(_heldout_rule, *_heldout_inputs(source, path))
        else:  # a colour LTM leaves out as much of its energy as the luminance of its tile
            rule = partial(_luma_rule, kept)
        s, n, ranks[name], left = _write_factors(source[name], target, name, dtype, rule,
                                                 tile, progress)
        kept = left if name == LTM else kept
        signal, noise = signal + s, noise + n
        stored["factor_bytes"] += sum(store_bytes(side / n) for n in (
            factored.weights_name(name), factored.basis_name(name), factored.ranks_name(name)))
        for gone in (name, by_light_name(name)):
            if gone in target:
                stored["dense_bytes"] += store_bytes(side / gone)
                del target[gone]
    for name in drop:
        shutil.rmtree(side / name, ignore_errors=True)
    snr = 10 * np.log10(signal / noise) if noise > 0 else float("inf")
    rule = ({"target_db": target_db} if target_db is not None
            else {"rank_rule": factored.RANK_RULE})
    return {"snr_db": float(snr), "dropped": drop, "tile": tile, **rule, "ranks": ranks,
            **stored}


def _heldout_inputs(group: zarr.Group, path: Path) -> tuple[zarr.Array, zarr.Array]:
    """The store's per-pixel expected error and samples, from which the held-out rule sets
    each tile's rank; refused when the store lacks them."""
    missing = [n for n in (EXPECTED_ERROR, SAMPLES) if n not in group]
    if missing:
        raise LtmError(f"store {str(path)!r} has no {missing[0]} to set the factors' ranks "
                       "from the held-out error; give --target-snr DB")
    return group[EXPECTED_ERROR], group[SAMPLES]


def _target_rule(target_db: float, corner: tuple[int, int], values: np.ndarray) -> dict:
    return {"allowed": factored.target_budget(values, target_db)}


def _heldout_rule(error: zarr.Array, samples: zarr.Array, corner: tuple[int, int],
                  values: np.ndarray) -> dict:
    """:func:`ltmstore.core.factored.heldout_threshold` of the tile at ``corner``: the stored
    expected error (relative to the observed range) times the range of its samples."""
    where = tuple(slice(c, c + n) for c, n in zip(corner, values.shape[:2], strict=True))
    batch = np.asarray(samples[where], dtype=np.float32).reshape(-1, *samples.shape[2:])
    rms = np.asarray(error[where], np.float64).ravel() * observed_range(batch)
    return {"threshold": factored.heldout_threshold(rms, int(np.prod(values.shape[2:])))}


def _luma_rule(kept: dict, corner: tuple[int, int], values: np.ndarray) -> dict:
    return {"allowed": kept.get(corner, 0.0) * factored.energy(values)}


def _write_factors(src: zarr.Array, group: zarr.Group, name: str, dtype, rule,
                   tile: int, progress: bool) -> tuple[float, float, dict, dict]:
    """Factor ``src`` tile by tile (:func:`ltmstore.core.factored.factor_tile` with the
    arguments ``rule(corner, values)``) and write ``{name}_weights`` and ``{name}_basis``;
    return the sums of squares of the values and of the stored factors' error, the ranks used,
    and per tile corner the fraction of its energy left out."""
    ny, nx, *cells = src.shape
    corners = list(itertools.product(range(0, ny, tile), range(0, nx, tile)))

    def factor(corner: tuple[int, int]) -> tuple:
        y0, x0 = corner
        values = np.asarray(src[y0:y0 + tile, x0:x0 + tile], dtype=np.float32)
        if not np.isfinite(values).all():
            raise LtmError(f"{name} holds non-finite values in the tile at y={y0}, x={x0}: the "
                           "factored form needs a finite ltm")
        w, b = factored.factor_tile(values, **rule(corner, values))
        left = factored.left_out(values, b)
        w, b = w.astype(dtype), b.astype(dtype)
        error = values.astype(np.float64) - np.tensordot(w.astype(np.float32),
                                                         b.astype(np.float32), axes=1)
        return w, b, factored.energy(values), factored.energy(error), left

    with ThreadPoolExecutor(max_workers=2) as pool:
        bar = tqdm(pool.map(factor, corners), total=len(corners), desc=f"factor {name}",
                   unit="tile", disable=not progress)
        parts = dict(zip(corners, bar, strict=True))
    by_tile = {(y0 // tile, x0 // tile): part[:2] for (y0, x0), part in parts.items()}
    ranks = np.zeros((-(-ny // tile), -(-nx // tile)), int)
    for index, (w, _) in by_tile.items():
        ranks[index] = w.shape[2]
    writer = factors.PackedWriter(*factors.create(group, name, ranks, (ny, nx), cells,
                                                  src.chunks[2:], dtype, tile,
                                                  src.attrs.asdict()))
    for tiles in writer.packing.blocks():
        writer.write(tiles, by_tile)
    writer.close()
    return (sum(p[2] for p in parts.values()), sum(p[3] for p in parts.values()),
            {"min": int(ranks.min()), "mean": float(ranks.mean()), "max": int(ranks.max())},
            {corner: part[4] for corner, part in parts.items()})
