"""Create, write and open the Zarr v3 store of one acquisition.

Arrays are written with plain :mod:`zarr` (``dimension_names`` set), so the whole group opens as
one :class:`xarray.Dataset` with ``xarray.open_zarr(path, consolidated=False)``. Each stage records
its provenance under the group attribute ``stages`` and marks itself complete last, so an
interrupted stage never looks finished.
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import json
import os
import re
import shlex
import shutil
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import zarr
from zarr.abc.store import Store
from zarr.storage import WrapperStore

from ltmstore.core import checksum, factored, integrity
from ltmstore.core.dims import CHROMA_SAMPLES, SAMPLES
from ltmstore.core.errors import LtmError
from ltmstore.core.lock import locked
from ltmstore.core.paths import check_output
from ltmstore.core.provenance import software, summary
from ltmstore.core.swap import SwapJournalError, check_journal, journal_path, recover, swap_in

if TYPE_CHECKING:  # xarray loads in open_store: writing a store does not need it
    import xarray as xr

__all__ = ["swap_in"]  # re-exported: the archive swaps its stores in too

STAGES_ATTR = "stages"
REFINEMENT = "reconstruct_surface"  # a far-light store's second reconstruct stage
# Which variables each stage writes (to hide the output of stages that did not complete).
STAGE_VARIABLES = {
    "ingest": ("frames", "frame_chroma", "pose_r", "pose_s", "pose_z", "pose_p", "pose_q",
               "pose_valid", "pose_axis_r", "pose_axis_s", "pose_axis_z", "chroma",
               "chroma_spread"),
    "resample": ("samples", "count", "samples_cb", "samples_cr"),
    "reconstruct": ("ltm", "expected_error", "unsupported", "ltm_cb", "ltm_cr", "method_map",
                    "ltm_tiles_done", "ltm_cb_tiles_done", "ltm_cr_tiles_done",
                    "ltm_by_light", "ltm_cb_by_light", "ltm_cr_by_light",
                    # a far-light store's surface model (ltmstore.stages.surface)
                    "normal", "albedo", "specular", "roughness", "ambient", "exposure",
                    "shadow_height",
                    # the factored form `ltm compact --form factored` leaves (core.factored)
                    # and its staging during `ltm reconstruct --form factored`
                    *(f"{n}{part}" for n in ("ltm", "ltm_cb", "ltm_cr")
                      for part in (factored.WEIGHTS, factored.BASIS, factored.RANKS,
                                   factored.TILE_WEIGHTS, factored.TILE_BASIS))),
    # a far-light store's surface refinement (REFINEMENT), after the classic fit of
    # "reconstruct": the arrays only it writes
    "reconstruct_surface": ("normal", "albedo", "specular", "roughness", "ambient", "exposure",
                            "shadow_height"),
}
# The arrays each stage (re)writes, besides coordinates (:func:`complete_stage` records what it
# wrote in them): ``ltm compact`` rewrites the LTM variables; the surface refinement none of its
# own (it completes the reconstruct record again, which records them). Any other stage: every
# array.
RECORDED_BY = {**STAGE_VARIABLES, "compact": STAGE_VARIABLES["reconstruct"],
               "reconstruct_surface": ()}
# The LTM variables (luminance, colour, and their light-major copies): written float16 by a lossy
# ``ltm reconstruct --precision float16``, always opened as float32 by :func:`open_store`.
LTM_VARIABLES = ("ltm", "ltm_cb", "ltm_cr", "ltm_by_light", "ltm_cb_by_light", "ltm_cr_by_light")
SAMPLE_VARIABLES = (SAMPLES, *CHROMA_SAMPLES.values())
FRAMES_PER_TASK = 32  # open_store's Dask chunks hold at least this many frames


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


@contextmanager
def new_store(path: str | os.PathLike, *, overwrite: bool = False,
              inputs: Sequence[str | os.PathLike] = ()) -> Iterator[zarr.Group]:
    """Create a store at ``path`` atomically: build it beside, then move it into place.

    Refuses an existing path unless ``overwrite``, and even then anything but a store made by
    this program; refuses a path that is one of ``inputs``, lies inside one or holds one
    (:func:`ltmstore.core.paths.check_output`), before anything is written. Holds the store's
    write lock (:func:`ltmstore.core.lock.locked`) throughout; partial stores that dead
    processes left beside it are removed first. If the body raises, nothing is left at
    ``path`` and an existing store there is untouched.
    """
    check_output(path, inputs, what="store")  # before the lock file: nothing in an input
    path = Path(os.path.abspath(path))
    parent = path.parent
    if not parent.is_dir():
        raise LtmError(f"cannot create store {str(path)!r}: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise LtmError(f"cannot create store {str(path)!r}: folder {str(parent)!r} is not writable")
    check_journal(path)
    with locked(path):
        recover(path)
        _check_replaceable(path, overwrite=overwrite)
        remove_leftovers(path)
        tmp = parent / f".{path.name}.partial-{os.getpid()}"
        try:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            group.attrs[STAGES_ATTR] = {}
            yield group
            swap_in(tmp, path)
        except OSError as exc:
            _discard(tmp)
            raise LtmError(f"cannot write store {str(path)!r}: {exc.strerror or exc}") from exc
        except BaseException:
            _discard(tmp)
            raise


def settle_writes(timeout: float = 60.0) -> bool:
    """Wait until Zarr has no write in flight; returns whether that came within ``timeout``
    seconds.

    Zarr writes an array's chunks as concurrent tasks on its own event loop. When one fails (a
    full disk), the call raises at once while the other tasks go on writing: a folder removed
    right after the failure gets some of their files back (measured: 2-30 chunk files left on
    each of 5 full-disk trials), and a process that exits meanwhile prints "Task was destroyed
    but it is pending" under its one-line error.
    """
    from zarr.core.sync import sync

    async def rest() -> None:
        others = asyncio.all_tasks() - {asyncio.current_task()}
        await asyncio.gather(*others, return_exceptions=True)

    try:
        sync(rest(), timeout=timeout)
    except TimeoutError:
        return False
    return True


def _discard(folder: Path) -> None:
    """Remove a store folder that a failed write leaves, once Zarr's writes have settled (a
    write still going after a minute is left to the next writer's :func:`remove_leftovers`)."""
    settle_writes()
    shutil.rmtree(folder, ignore_errors=True)


def _check_replaceable(path: Path, *, overwrite: bool) -> None:
    """Refuse to build a store at ``path`` over anything that is not one of ours."""
    if not (path.exists() or path.is_symlink()):
        return
    if not overwrite:
        raise LtmError(f"store {str(path)!r} already exists; pass --overwrite to replace it")
    if not is_ltm_store(path):
        raise LtmError(f"{str(path)!r} exists and is not a store made by ltm; --overwrite "
                       "replaces only such stores (remove it yourself if it must go)")


def is_ltm_store(path: Path) -> bool:
    """Whether ``path`` is a store folder this program made (a Zarr group with stage records)."""
    try:
        meta = json.loads((path / "zarr.json").read_text())
        return (not path.is_symlink() and meta.get("node_type") == "group"
                and STAGES_ATTR in meta.get("attributes", {}))
    except (OSError, ValueError, AttributeError):
        return False


@contextmanager
def writing(path: str | os.PathLike) -> Iterator[Path]:
    """Hold the write lock of an existing store for the body, after finishing (or rolling back)
    a swap a killed process left and removing dead processes' leftovers beside it.

    Yields the store's resolved path (through symbolic links): where its swaps happen.
    """
    path = Path(os.path.realpath(path))
    check_journal(path)  # a journal that does not match its folder: refused, nothing touched
    with locked(path):
        recover(path)
        remove_leftovers(path)
        yield path


def _recover_unlocked(path: Path) -> None:
    """Before reading: finish a swap a killed process left, unless a live writer holds the
    store (it finishes its own swap)."""
    if journal_path(path).exists():
        try:
            with writing(path):
                pass
        except SwapJournalError:  # one that does not match its folder: said, never skipped
            raise
        except LtmError:  # a live writer holds the store
            pass


def remove_leftovers(path: Path) -> None:
    """Remove the partial stores and set-aside old stores that killed processes left beside
    ``path``, and the half-written chunk files left inside it and its revision
    (:data:`CHUNK_TEMPORARY`). The caller holds the store's lock, so no live process of ours is
    writing them."""
    for pattern in (f".{path.name}.partial-*", f".{path.name}.old-*"):
        for leftover in path.parent.glob(pattern):
            shutil.rmtree(leftover, ignore_errors=True)
    for root in (path, revision_path(path)):
        for folder, _, names in os.walk(root):
            for name in names:
                if CHUNK_TEMPORARY.search(name):
                    Path(folder, name).unlink(missing_ok=True)


# Zarr's local store writes a chunk to "<key>.<uuid4 hex>.partial", then renames it to its key:
# a process killed in between leaves the temporary file, which no reader uses but the damage
# check (rightly) counts as a file outside the chunk grid.
CHUNK_TEMPORARY = re.compile(r"\.[0-9a-f]{32}\.partial$")


def revision_path(path: str | os.PathLike) -> Path:
    """Where :func:`revised_store` builds the next (resumable) version of the store at ``path``
    (beside its resolved path)."""
    path = Path(os.path.realpath(path))
    return path.parent / f".{path.name}.revising"


@contextmanager
def revised_store(path: str | os.PathLike, *, resumable: bool = True) -> Iterator[Path]:
    """Revise an existing store on a linked copy beside it; swap the copy in only on success.

    The copy hard-links the store's files (no data is copied; Zarr replaces a file it rewrites
    rather than writing into it) and copies its metadata. The body gets the copy's path. If the
    body raises, the copy is removed and the store at ``path`` (resolved through symbolic
    links) is untouched.

    Parameters
    ----------
    path : path-like
        The store; the caller holds its write lock (:func:`writing`).
    resumable : bool
        The copy is :func:`revision_path`: a killed process leaves it for a later revision to
        resume, which reuses it when it holds the same ingest (record and variables). Otherwise
        the copy is a fresh one that the next writer removes (:func:`remove_leftovers`), never
        reused: a revision that is not resumable (``ltm compact``) cannot be mistaken for one
        that is, nor the other way round.
    """
    path = Path(os.path.realpath(path))
    side = (revision_path(path) if resumable
            else path.parent / f".{path.name}.partial-copy-{os.getpid()}")
    if not os.access(path.parent, os.W_OK):
        raise LtmError(f"cannot revise store {str(path)!r}: folder {str(path.parent)!r} is "
                       "not writable")
    if side.exists() and not (resumable and _same_ingest(path, side)):
        shutil.rmtree(side)
    try:
        if not side.exists():
            shutil.copytree(path, side, copy_function=_link_or_copy)
        yield side
        swap_in(side, path)
    except BaseException:
        _discard(side)
        raise


def _same_ingest(a: Path, b: Path) -> bool:
    """Whether the store ``b`` holds the ingest of the store ``a``: its record and every one of
    its variables that ``a`` holds."""
    try:
        group_a, group_b = open_group(a, mode="r"), open_group(b, mode="r")
        return (stages(group_b).get("ingest") == stages(group_a).get("ingest")
                and all(name in group_b for name in STAGE_VARIABLES["ingest"]
                        if name in group_a))
    except (LtmError, OSError, ValueError):
        return False


def _link_or_copy(src: str, dst: str) -> None:
    if Path(src).name != "zarr.json":
        try:
            os.link(src, dst)
            return
        except OSError:
            pass
    shutil.copy2(src, dst)


class CountingStore(WrapperStore):
    """Wraps a Zarr store and counts the reads and bytes it serves (to measure queries)."""

    def __init__(self, store: Store) -> None:
        super().__init__(store)
        self.reads = 0
        self.bytes_read = 0

    async def get(self, key, prototype, byte_range=None):
        buf = await self._store.get(key, prototype, byte_range)
        if buf is not None and not key.endswith("zarr.json"):
            self.reads += 1
            self.bytes_read += len(buf)
        return buf


def open_group(path: str | os.PathLike | Store, *, mode: str = "r") -> zarr.Group:
    """Open an existing store's group, with a clear error when it is not a store."""
    if isinstance(path, Store):
        return zarr.open_group(store=path, mode=mode, zarr_format=3)
    path = Path(path)
    _recover_unlocked(Path(os.path.realpath(path)))
    if not (path / "zarr.json").is_file():
        raise LtmError(f"store {str(path)!r} does not exist or is not a Zarr v3 store")
    try:
        group = zarr.open_group(str(path), mode=mode, zarr_format=3)
    except (ValueError, KeyError, TypeError, zarr.errors.BaseZarrError) as exc:
        raise LtmError(f"store {str(path)!r} is damaged: {str(path / 'zarr.json')!r} cannot be "
                       f"read ({' '.join(str(exc).split()) or type(exc).__name__})") from exc
    if STAGES_ATTR not in group.attrs:
        raise LtmError(f"store {str(path)!r} is a Zarr v3 group but not an ltmstore store (no "
                       f"{STAGES_ATTR!r} attribute); make one with ltm ingest or ltm simulate")
    _check_attribute_types(path, group.attrs.asdict())
    return group


# The group attributes every reader takes as JSON objects (a record per stage in STAGES_ATTR)
OBJECT_ATTRS = (STAGES_ATTR, "acquisition", integrity.WRITTEN)


def _check_attribute_types(path: Path, attrs: dict) -> None:
    """Refuse a store whose group attributes are not the JSON objects ltmstore writes (an
    edited ``stages``, a stage record or ``acquisition`` of another JSON type), naming it."""
    wrong = [(name, attrs[name]) for name in OBJECT_ATTRS
             if name in attrs and not isinstance(attrs[name], dict)]
    if not wrong and isinstance(attrs.get(STAGES_ATTR), dict):
        wrong = [(f"{STAGES_ATTR}.{stage}", record)
                 for stage, record in attrs[STAGES_ATTR].items() if not isinstance(record, dict)]
    if wrong:
        name, value = wrong[0]
        raise LtmError(f"store {str(path)!r} is damaged: its attribute {name!r} is a JSON "
                       f"{_json_type(value)}; expected an object as ltmstore writes it "
                       f"({str(path / 'zarr.json')!r} was edited)")


def _json_type(value) -> str:
    return {list: "array", str: "string", bool: "boolean", int: "number", float: "number",
            type(None): "null"}.get(type(value), type(value).__name__)


def write_coord(group: zarr.Group, name: str, values: np.ndarray, **attrs) -> None:
    """Write a 1-D coordinate variable ``name(name)``."""
    values = np.asarray(values)
    dtype = str if values.dtype.kind in "UO" else values.dtype  # variable-length UTF-8
    arr = group.create_array(name, shape=values.shape, dtype=dtype, chunks=values.shape or (1,),
                             dimension_names=(name,), overwrite=True,
                             compressors=checksum.COMPRESSORS, config=checksum.ARRAY_CONFIG)
    arr[...] = values
    arr.attrs.update(attrs)


def create_variable(
    group: zarr.Group,
    name: str,
    dims: Sequence[str],
    shape: Sequence[int],
    *,
    chunks: Sequence[int],
    dtype=np.float32,
    shards: Sequence[int] | None = None,
    fill_value=np.nan,
    attrs: dict | None = None,
    compressors: Sequence | None = None,
) -> zarr.Array:
    """Create an empty named-dimension array (overwriting one of the same name).

    ``compressors`` (default :data:`ltmstore.core.checksum.COMPRESSORS`) must end with a CRC32C.
    """
    if name in group:
        del group[name]
    arr = group.create_array(
        name,
        shape=tuple(int(n) for n in shape),
        chunks=tuple(int(c) for c in chunks),
        shards=None if shards is None else tuple(int(c) for c in shards),
        dtype=dtype,
        fill_value=fill_value,
        dimension_names=tuple(dims),
        overwrite=True,
        compressors=tuple(checksum.COMPRESSORS if compressors is None else compressors),
        config=checksum.ARRAY_CONFIG,
    )
    if attrs:
        arr.attrs.update(attrs)
    return arr


def check_writable(path: str | os.PathLike) -> None:
    """Refuse, before any write, a store folder this process cannot write into.

    Tries to create and remove a file there (honest for every user, root included).
    """
    probe = Path(path) / f".ltm-write-probe-{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise LtmError(f"store {str(path)!r} is not writable ({exc.strerror or exc}); expected "
                       "a store folder this user can write") from exc


def stages(group: zarr.Group) -> dict:
    """Provenance of every stage recorded in the store."""
    return dict(group.attrs.get(STAGES_ATTR, {}))


def refinement_pending(attrs: dict) -> bool:
    """Whether a store's attributes ``attrs`` record a far-light classic fit whose surface
    refinement (:data:`REFINEMENT`) was begun and not completed: relightable, not refined."""
    entry = attrs.get(STAGES_ATTR, {}).get(REFINEMENT)
    return isinstance(entry, dict) and not entry.get("complete")


def refinement_note(store: str | os.PathLike) -> str:
    """The note a reader of a store whose refinement is pending prints."""
    return (f"ltm: note: store {os.fspath(store)!r} holds its classic fit only: its surface "
            f"refinement is pending (`ltm reconstruct {shlex.quote(os.fspath(store))}` "
            "finishes it)")


def drop_stage_variables(group: zarr.Group, *names: str) -> None:
    """Delete the arrays an earlier run of the stages ``names`` left (:data:`STAGE_VARIABLES`)."""
    for stage in names:
        for name in STAGE_VARIABLES[stage]:
            if name in group:
                del group[name]


def begin_stage(group: zarr.Group, stage: str, info: dict | None = None) -> None:
    """Mark ``stage`` as started (and not complete) before writing any of its arrays.

    ``info`` (e.g. the run's parameters, to resume it) is recorded with the mark.
    """
    st = stages(group)
    st[stage] = {**(info or {}), "complete": False, "started": _now()}
    group.attrs[STAGES_ATTR] = st


def complete_stage(group: zarr.Group, stage: str, info: dict) -> None:
    """Record ``info`` for ``stage`` and mark it complete: always the last write of a stage.

    With it, what the stage wrote in each array (:data:`RECORDED_BY`), as
    :func:`ltmstore.core.integrity.recorded` records it (group attribute
    :data:`ltmstore.core.integrity.WRITTEN`): what ``ltm check`` and every reader hold the
    arrays to.
    """
    soft = software()
    st = stages(group)
    entry = dict(st.get(stage, {}))
    entry.update(info)
    entry.update({"complete": True, "finished": _now(),
                  "software": f"ltmstore {soft['version']}", "commit": soft["commit"]})
    st[stage] = entry
    update = {STAGES_ATTR: st}
    root = getattr(group.store, "root", None)  # a local store (not one in memory)
    if root is not None:
        update[integrity.WRITTEN] = integrity.recorded(
            Path(root) / group.path, group.attrs.get(integrity.WRITTEN, {}), stage,
            RECORDED_BY.get(stage))
    group.attrs.update(update)


def require_stage(group: zarr.Group, stage: str, path: str | os.PathLike) -> dict:
    """The record of a completed stage, or a clear error."""
    entry = stages(group).get(stage)
    if not entry or not entry.get("complete"):
        state = "incomplete (interrupted?)" if entry else "missing"
        raise LtmError(f"store {str(path)!r}: stage {stage!r} is {state}; run it first")
    return entry


def open_store(path: str | os.PathLike | Store) -> xr.Dataset:
    """Open a store as a lazy :class:`xarray.Dataset`, one Dask chunk per inner Zarr chunk
    (the frames': :data:`FRAMES_PER_TASK` frames at least, :func:`_frames_per_task`).

    Variables stored as float16 (the frames and samples always, a lossy reconstruction's LTM)
    come back as float32, so that reductions over them (a mean) accumulate in float32; those stored
    in the factored form (``ltm compact --form factored``) come back as the lazy float32 product
    of their factors, with a light-major view ``ltm_by_light`` computed from the same factors.

    ``path`` may also be a Zarr store object (e.g. a :class:`CountingStore`). Variables of
    stages that did not complete are dropped, so partial results are never served.

    The values are those stored: xarray's CF decoding is off (``decode_cf=False``), so an
    attribute such as ``scale_factor`` or ``_FillValue`` changes nothing read (ltmstore writes
    none; :func:`ltmstore.core.integrity.cf_damage` names one as damage), and a missing value is
    what ltmstore writes for it, the NaN fill value of its float arrays, read as it is.
    """
    import xarray as xr

    group = open_group(path)
    if not isinstance(path, Store):
        _refuse_damaged(Path(path), group)
        if not checksummed(Path(path)):
            warnings.warn(f"store {str(path)!r} {checksum.NO_CHECKSUMS}", NoChecksumWarning,
                          stacklevel=2)
    source = path if isinstance(path, Store) else str(path)
    ds = _frames_per_task(xr.open_zarr(source, consolidated=False, chunks={}, decode_cf=False),
                          source, group)
    incomplete = {
        name
        for stage, entry in stages(group).items()
        if not entry.get("complete")
        for name in STAGE_VARIABLES.get(stage, ())
    }
    ds = ds.drop_vars([v for v in incomplete if v in ds.variables])
    small = [n for n, v in ds.data_vars.items() if v.dims == ("t",)]  # poses: read them once
    if small:
        ds[small] = ds[small].compute()
    for name in (*LTM_VARIABLES, *integrity.FRAME_VARIABLES, *SAMPLE_VARIABLES):  # in float32
        if name in ds and ds[name].dtype == np.float16:
            encoding = ds[name].encoding  # how it is stored: chunks, float16
            ds[name] = ds[name].astype(np.float32)
            ds[name].encoding = encoding
    ds = _derive_factored(ds, group)
    ds.attrs = {k: v for k, v in group.attrs.asdict().items() if k != integrity.WRITTEN}
    ds.encoding["source"] = path  # where readers of the stored factors find them
    return ds


def _frames_per_task(ds: xr.Dataset, source: str | Store, group: zarr.Group) -> xr.Dataset:
    """``ds`` with its frames read at least :data:`FRAMES_PER_TASK` frames a Dask task along
    ``t`` (a whole number of stored chunks; the other variables one task per chunk). A 24 MP
    classic capture ingested before ``ingest-rti`` spilled its frames
    (:class:`ltmstore.stages.frames.FrameSink`) stores one photograph a chunk: one task per
    chunk was 345,000 tasks to relight it, whose scheduling took longer than the relighting."""
    import xarray as xr

    frames = group.get(integrity.FRAME_VARIABLES[0])
    if frames is None or frames.chunks[0] >= FRAMES_PER_TASK:
        return ds
    names = [name for name in integrity.FRAME_VARIABLES if name in ds]
    merged = xr.open_zarr(source, consolidated=False, decode_cf=False,
                          chunks={"t": frames.chunks[0] * (FRAMES_PER_TASK // frames.chunks[0])},
                          drop_variables=[n for n in ds.data_vars if n not in names])
    return ds.assign({name: merged[name] for name in names})


def _derive_factored(ds: xr.Dataset, group: zarr.Group) -> xr.Dataset:
    """Present each LTM variable stored in the factored form (:mod:`ltmstore.core.factored`)
    as its lazy product ``(y, x, r, s)``, and its light-major view (one cell per chunk)."""
    import xarray as xr

    parts = {name: tuple(f(name) for f in (factored.weights_name, factored.basis_name,
                                           factored.ranks_name)) for name in LTM_VARIABLES[:3]}
    names = [n for n, part in parts.items() if n not in ds and all(v in ds for v in part)]
    for name in names:
        weights, basis, ranks = parts[name]
        ds.encoding.setdefault("kept_weights", {})[name] = factored.Kept(  # for relighting
            group[weights], factored.KEPT_BYTES // len(names))
        tile = int(group[basis].attrs["tile"])
        coords = {k: ds[k] for k in ("y", "x", "r", "s") if k in ds.coords}
        attrs = {k: v for k, v in ds[basis].attrs.items() if k not in factored.LAYOUT_ATTRS}
        cells = tuple(group[basis].attrs["lattice_chunk"])
        tile_ranks = np.asarray(group[ranks][...])
        for view, chunk in ((name, cells), (f"{name}_by_light", (1, 1))):
            data = factored.derived(group[weights], group[basis], tile_ranks, tile, chunk)
            ds[view] = xr.DataArray(data, dims=("y", "x", "r", "s"), coords=coords,
                                    attrs=attrs)
    return ds


def store_summary(path: str | os.PathLike) -> dict:
    """:func:`summary` of the store at ``path`` (a clear error when it is not a store).

    A store that ``ltm check`` (:func:`verify_store`) would call damaged is never ``complete``;
    ``damaged`` lists what is wrong. What shows without reading data is looked for first
    (:func:`damage`); a store complete so far then has every byte read
    (:func:`ltmstore.core.integrity.data_damage`: each CRC32C checked against its bytes and
    its key, nothing decompressed, in the arrays whose writing the store records; the others
    decoded as ``ltm check`` decodes them).
    """
    try:
        group = open_group(path)
        attrs = group.attrs.asdict()
    except (OSError, ValueError) as exc:
        raise LtmError(f"store {str(path)!r} cannot be read: {exc}") from exc
    info = {"store": str(path), **summary(attrs), "checksums": checksummed(Path(path))}
    found = _inspect(Path(path), group)
    damaged = found.lines
    if not damaged and info.get("complete"):
        damaged = integrity.data_damage(Path(path), attrs, found,
                                        complete=_complete_variables(group))
    if damaged:
        info.update(complete=False, damaged=damaged)
    return info


class NoChecksumWarning(UserWarning):
    """A store written before chunks carried checksums: damage to its data cannot be found."""


def checksummed(path: Path) -> bool:
    """Whether the store at ``path`` carries checksums (any of its arrays: then every one must,
    :mod:`ltmstore.core.integrity`), or holds no array yet."""
    return integrity.checksummed(path)


def _complete_variables(group: zarr.Group) -> Callable[[str], bool]:
    """Whether a variable belongs to no stage or to a completed one."""
    done = {name for stage, entry in stages(group).items() if not entry.get("complete")
            for name in STAGE_VARIABLES.get(stage, ())}
    return lambda name: name not in done


def damage(path: Path, group: zarr.Group) -> list[str]:
    """Damage found without reading data (:func:`ltmstore.core.integrity.inspect`): what a
    complete store must hold and does not, or holds in the wrong shape."""
    return _inspect(path, group).lines


def _inspect(path: Path, group: zarr.Group) -> integrity.Report:
    return integrity.inspect(path, group.attrs.asdict(), complete=_complete_variables(group))


def _refuse_damaged(path: Path, group: zarr.Group) -> None:
    damaged = damage(path, group)
    if damaged:
        more = f" (and {len(damaged) - 1} more)" if len(damaged) > 1 else ""
        raise LtmError(f"store {str(path)!r} is damaged: {damaged[0]}{more}; "
                       f"run ltm check {str(path)!r}")


def verify_store(path: str | os.PathLike, *, progress: bool = True) -> dict:
    """Read every chunk of every variable of the store at ``path`` and check it.

    Returns
    -------
    dict
        ``store``, ``parts`` (how many were read), ``damaged`` (one line per damaged part),
        ``unchecked`` (variables written without checksums) and ``unverified`` (variables whose
        attributes and chunk places no record holds: those of a store written before ltmstore
        recorded what its stages wrote, or added by hand after,
        :data:`ltmstore.core.integrity.NOT_RECORDED`).
    """
    from tqdm.auto import tqdm

    path = Path(path)
    problem = checksum.group_damage(path) if (path / "zarr.json").exists() else None
    if problem:
        return {"store": str(path), "parts": 0, "damaged": [problem], "unchecked": [],
                "unverified": []}
    group = open_group(path)
    found = _inspect(path, group)
    readable = [name for name, _ in checksum.arrays(path) if name not in found.broken]
    with tqdm(total=checksum.parts(path, readable), desc="check", unit="part",
              disable=not progress) as bar:
        damaged, unchecked = checksum.verify(path, readable, advance=bar.update)
    if checksummed(path):  # an array without checksums among checksummed ones is damage
        unchecked = []
    failed = found.broken | {line.partition("/")[0] for line in damaged}  # read, not placed
    misplaced = integrity.shard_damage(path, group.attrs.asdict(),
                                       integrity.Report(found.lines, failed),
                                       complete=_complete_variables(group))
    return {"store": str(path), "parts": bar.n, "damaged": found.lines + damaged + misplaced,
            "unchecked": unchecked, "unverified": found.unverified}
