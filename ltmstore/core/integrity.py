"""What a complete store holds, and the damage to it that shows without reading its data.

The one place that knows it: ``ltm check`` (before it reads every chunk), ``ltm info`` (a
damaged store is never ``complete``) and every reader, through
:func:`ltmstore.core.store.open_store`, refuse a store that fails these checks before any
image is made:

* every array's ``zarr.json`` is present and parses (as JSON and as Zarr array metadata);
* each known variable has its dims and data type (:data:`LAYOUT`), the codec chain ltmstore
  writes (ending with a CRC32C in a checksummed store) and the default chunk key encoding;
* every stored part (chunk, or shard) of a variable of a completed stage is a non-empty file,
  and no file lies outside the array's grid (Zarr would read a missing, empty or folder-shaped
  part as the fill value: NaN, or black); its first chunk decodes (one small read per array: a
  data type, chunk shape or codec that does not describe the bytes shows there);
* the variables the completed stages wrote are there (:func:`required`): ``r``, ``ltm_cb``,
  a far store's ``normal`` or ``exposure`` ...; and every dimension with a coordinate has it;
* every dimension has one size across the store, and the lattice the stage records name;
* no array carries an attribute that xarray's CF decoding applies to its values
  (:data:`CF_DECODED`: ``scale_factor``, ``add_offset``, ``_FillValue`` ...), which ltmstore
  never writes: plain ``xarray.open_zarr`` would return other values than those stored;
* each array is what the stage that wrote it recorded (:func:`record`, in the group attribute
  :data:`WRITTEN`, written by :func:`ltmstore.core.store.complete_stage`): every key of its
  ``zarr.json`` and every attribute (one added, removed or changed is named), and the stored
  CRC32C of every part at its key, so that a chunk moved, swapped with another, or taken from
  another store is named although its own checksum holds. :func:`inspect` reads the last 4 bytes
  of each part (a shard's index checksum); ``ltm check`` and ``ltm info`` (:func:`data_damage`)
  also the checksum of every inner chunk of a shard.

Stores written before ltmstore checksummed its chunks (no CRC32C anywhere) are held only to the
layout, sizes and coordinates: which variables they must hold is not known. Stores written before
it recorded what each stage wrote (no :data:`WRITTEN`), and arrays written by hand after the
stages completed (a notebook's), are held to the rest: what only a record shows is reported as
not verified (:attr:`Report.unverified`), never as damage.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import zarr

from ltmstore.core import checksum, factored
from ltmstore.core.checksum import is_checksum_error

COORDINATES = ("t", "y", "x", "r", "s", "p", "q", "channel", "color", "component")
SURFACE = ("normal", "albedo", "specular", "roughness", "ambient")
SURFACE_PREFIX = "physical+"  # a far store's surface blend (ltmstore.stages.surface.PREFIX)
SHADOW_MARK = "^shadows:"  # ...casting shadows (ltmstore.stages.surface.SHADOW_MARK)
FRAME_VARIABLES = ("frames", "frame_chroma")  # what `ltm compact` may drop
LATTICES = (("r", "s"), ("r", "s", "p", "q"))
F16, F32, F64 = "float16", "float32", "float64"
# The group attribute that records, per array, what the stage that wrote it wrote (:func:`record`).
WRITTEN = "written"
# Array attributes that xarray's CF decoding (open_zarr's defaults) applies to the values: a scale,
# an offset, masked values, an unsigned view, booleans, characters, times (``units`` "... since
# ...", :func:`cf_damage`). ltmstore writes none of them; its readers decode none of them.
CF_DECODED = ("scale_factor", "add_offset", "_FillValue", "missing_value", "_Unsigned", "dtype",
              "calendar", "_Encoding", "coordinates")
NOT_RECORDED = ("records nothing of how these arrays were written (a store written before "
                "ltmstore recorded it, or arrays added by hand after its stages completed): "
                "their attributes and chunk places are not verified")


def _layout() -> dict[str, tuple[tuple[tuple[str, ...], ...], tuple[str, ...]]]:
    """``name: (the dims it may have, the data types it may have)`` of every known variable."""
    pixels = ("y", "x")
    per_cell = tuple((*pixels, *lat) for lat in LATTICES)
    layout = {
        # measurements: float16 (float32 frames and samples in stores written before)
        "frames": ((("t", *pixels),), (F16, F32)),
        "frame_chroma": ((("channel", "t", *pixels),), (F16,)),
        "pose_valid": ((("t",),), ("bool",)),
        "count": (LATTICES, ("int32",)),
        "unsupported": ((pixels,), ("bool",)),
        "method_map": ((("tile_y", "tile_x"),), ("int16",)),
        "exposure": ((("t",),), (F32,)),
        "normal": (((*pixels, "component"),), (F32,)),
        "roughness": ((pixels,), (F32,)),
        "shadow_height": ((pixels,), (F32,)),
        **{f"pose_{k}": ((("t",),), (F64,)) for k in "rszpq"},
        **{k: (((*pixels, "channel"),), (F32,)) for k in ("chroma", "chroma_spread")},
        **{k: (per_cell, (F16, F32)) for k in ("samples", "samples_cb", "samples_cr")},
        **{k: (per_cell, (F32, F16)) for k in ("ltm", "ltm_cb", "ltm_cr", "ltm_by_light",
                                                "ltm_cb_by_light", "ltm_cr_by_light")},
        **{k: ((pixels, (*pixels, "color")), (F32,)) for k in ("albedo", "specular", "ambient")},
        "expected_error": ((pixels,), (F32,)),
        # the packed factors (ltmstore.core.factored) of either command's --form factored
        **{f"{k}_weights": (((f"factor_weight{k[3:]}",),), (F32, F16))
           for k in ("ltm", "ltm_cb", "ltm_cr")},
        **{f"{k}_basis": (((f"factor_row{k[3:]}", *LATTICES[0]),), (F32, F16))
           for k in ("ltm", "ltm_cb", "ltm_cr")},
        **{f"{k}_ranks": ((("factor_tile_y", "factor_tile_x"),), ("int32",))
           for k in ("ltm", "ltm_cb", "ltm_cr")},
        **{f"{k}_tile_weights": (((*pixels, "tile_rank"),), (F32,))
           for k in ("ltm", "ltm_cb", "ltm_cr")},  # staged by ltm reconstruct --form factored
        **{f"{k}_tile_basis": ((("tile_y", "tile_x", "tile_rank", *LATTICES[0]),), (F32,))
           for k in ("ltm", "ltm_cb", "ltm_cr")},
        **{k: (((k,),), (F64,)) for k in ("t", "r", "s", "p", "q")},
        **{k: (((k,),), ("int64",)) for k in ("y", "x")},
        **{k: (((k,),), ("string",)) for k in ("channel", "color", "component")},
    }
    return layout


LAYOUT = _layout()
ARRAY_TO_BYTES = ("bytes", "vlen-utf8")
COMPRESSORS = ("zstd", "blosc")
KEY_ENCODING = {"name": "default", "configuration": {"separator": "/"}}


@dataclass(frozen=True)
class Meta:
    """One array's ``zarr.json``, as far as the checks go."""

    folder: Path
    shape: tuple[int, ...]
    dtype: str
    dims: tuple[str, ...]
    part: tuple[int, ...]  # the shape of a stored part: a shard, or a chunk
    codecs: tuple[dict, ...]
    key_encoding: dict
    doc: dict = field(default_factory=dict, compare=False, repr=False)  # the parsed zarr.json

    @property
    def name(self) -> str:
        return self.folder.name

    def shard_index(self) -> checksum.ShardIndex | None:
        """The index of the array's shards (None when it is not sharded)."""
        if _codec_names(self.codecs) != ["sharding_indexed"]:
            return None
        config = self.codecs[0].get("configuration", {})
        inner = config.get("chunk_shape") or self.part
        chunk, index = _chain(self)
        return checksum.ShardIndex(
            math.prod(-(-p // max(int(i), 1)) for p, i in zip(self.part, inner, strict=False)),
            at_end=config.get("index_location", "end") == "end",
            crc="crc32c" in _codec_names(index), inner_crc="crc32c" in _codec_names(chunk))

    def keys(self) -> Iterator[str]:
        """The key of every stored part of the array (``name/c/i/j...``)."""
        counts = [-(-n // p) for n, p in zip(self.shape, self.part, strict=True)]
        if not counts:
            yield f"{self.name}/c"
            return
        for flat in range(math.prod(counts)):
            index = []
            for n in reversed(counts):
                flat, i = divmod(flat, n)
                index.append(str(i))
            yield "/".join((self.name, "c", *reversed(index)))


@dataclass(frozen=True)
class Report:
    """What :func:`inspect` found: one line per damaged part, the arrays whose metadata is
    damaged (not to be read), and those whose writing no record describes (:data:`WRITTEN`)."""

    lines: list[str]
    broken: set[str]
    unverified: list[str] = field(default_factory=list)


def read_meta(folder: Path) -> Meta | str:
    """The array metadata in ``folder``, or why it cannot be read."""
    where = f"{folder.name}/zarr.json"
    try:
        meta = json.loads((folder / "zarr.json").read_text())
        zarr.open_array(str(folder), mode="r", zarr_format=3)
        grid = meta["chunk_grid"]["configuration"]["chunk_shape"]
        dtype = meta["data_type"]
        return Meta(folder, tuple(int(n) for n in meta["shape"]),
                    dtype if isinstance(dtype, str) else json.dumps(dtype),
                    tuple(meta.get("dimension_names") or ()), tuple(int(n) for n in grid),
                    tuple(meta["codecs"]), meta.get("chunk_key_encoding", {}), meta)
    except FileNotFoundError:
        return f"{where} is missing"
    except IsADirectoryError:
        return f"{where} is a folder, not a file"
    except Exception as exc:  # noqa: BLE001 - any unreadable metadata is damage to name
        return f"{where} cannot be read ({type(exc).__name__})"


def _codec_names(codecs: tuple[dict, ...] | list[dict]) -> list[str]:
    return [c.get("name", "?") if isinstance(c, dict) else "?" for c in codecs]


def _chain(meta: Meta) -> tuple[list[dict], list[dict]]:
    """The codecs of each chunk, and those of the shard index (empty when not sharded)."""
    outer = list(meta.codecs)
    if _codec_names(outer) == ["sharding_indexed"]:
        config = outer[0].get("configuration", {})
        return list(config.get("codecs", [])), list(config.get("index_codecs", []))
    return outer, []


def has_checksum(meta: Meta) -> bool:
    """Whether the chunks of the array carry a CRC32C."""
    return "crc32c" in _codec_names(_chain(meta)[0])


def codec_damage(meta: Meta, checksummed: bool) -> str | None:
    """Why the codec chain of an array is not one ltmstore writes, or None."""
    chunk, index = _chain(meta)
    names = _codec_names(chunk)
    endian = [c.get("configuration", {}).get("endian", "little") for c in (*chunk, *index)
              if c.get("name") == "bytes"]
    where = f"{meta.name}/zarr.json"
    if any(e != "little" for e in endian):
        return f"{where}: bytes codec is {endian}, expected little-endian"
    if not checksummed:
        return None
    expected = (len(names) == 3 and names[0] in ARRAY_TO_BYTES and names[1] in COMPRESSORS
                and names[2] == "crc32c")
    if index and _codec_names(index) != ["bytes", "crc32c"]:
        expected = False
    if not expected:
        return (f"{where}: codecs {', '.join(names)} are not those ltmstore writes (an array "
                f"codec, zstd or blosc, then the crc32c every array of this store carries)")
    return None


def layout_damage(meta: Meta, checksummed: bool) -> list[str]:
    """Dims, data type, codecs and key encoding of an array that are not those it must have."""
    where = f"{meta.name}/zarr.json"
    found = []
    if meta.name in LAYOUT:
        dims, dtypes = LAYOUT[meta.name]
        if meta.dims not in dims:
            padded = meta.name.endswith("_weights") and meta.dims[:2] == ("y", "x")
            found.append(f"{where}: dims {meta.dims}, expected {' or '.join(map(str, dims))}"
                         + (" (the padded factored form written before 2026-11-28, which this "
                            "version does not read)" if padded else ""))
        if meta.dtype not in dtypes:
            found.append(f"{where}: data type {meta.dtype}, expected {' or '.join(dtypes)}")
    if len(meta.dims) != len(meta.shape) or len(meta.part) != len(meta.shape):
        found.append(f"{where}: shape {meta.shape}, dims {meta.dims} and chunks {meta.part} "
                     "disagree")
    if meta.key_encoding != KEY_ENCODING:
        found.append(f"{where}: chunk key encoding {meta.key_encoding}, expected {KEY_ENCODING}")
    codec = codec_damage(meta, checksummed)
    return found + ([codec] if codec else [])


def _files(folder: Path) -> dict[str, int]:
    """``{key: bytes}`` of every file under ``folder/c`` (keys as in :meth:`Meta.keys`), as
    ``os.walk`` finds them (a linked folder is not entered).

    One ``scandir`` per folder and keys built as strings: ``os.walk`` and a ``pathlib`` path
    per file made this 2.1 s of a 4K store's open (65,000 chunk files in 25,000 folders)."""
    found: dict[str, int] = {}

    def visit(path: str, prefix: str) -> None:
        try:
            entries = list(os.scandir(path))
        except OSError:  # as os.walk: a folder that cannot be listed holds nothing
            return
        for entry in entries:
            key = prefix + entry.name
            if entry.is_dir():
                if not entry.is_symlink():
                    visit(entry.path, key + "/")
                continue
            try:
                found[key] = entry.stat().st_size
            except OSError:
                found[key] = 0

    visit(os.fspath(folder / "c"), f"{folder.name}/c/")
    return found


def chunk_damage(root: Path, meta: Meta, files: dict[str, int] | None = None) -> list[str]:
    """Stored parts of an array that are missing, empty, folders, or outside its grid
    (``files``: :func:`_files` of the array, when already listed)."""
    files = dict(_files(root / meta.name) if files is None else files)
    found = []
    for key in meta.keys():
        size = files.pop(key, None)
        if size == 0:
            found.append(f"{key} is empty (0 bytes)")
        elif size is None:
            found.append(f"{key} is a folder, not a chunk file" if (root / key).is_dir()
                         else f"{key} is missing")
    if not found and not files:
        found += probe_damage(meta)
    if files:
        first = sorted(files)[0]
        more = f" and {len(files) - 1} more" if len(files) > 1 else ""
        found.append(f"{first}{more} lie outside the chunk grid of {meta.name}/zarr.json "
                     f"(shape {meta.shape}, parts {meta.part})")
    return found


def probe_damage(meta: Meta) -> list[str]:
    """Decode the first chunk of an array: its metadata (data type, chunk shape, codecs) must
    describe the bytes it holds (one small read per array)."""
    try:
        array = zarr.open_array(str(meta.folder), mode="r", zarr_format=3)
        array[tuple(slice(0, 1) for _ in meta.shape)]
    except Exception as exc:  # noqa: BLE001 - whatever fails to decode is damage to name
        text = " ".join(str(exc).split())[:120] or type(exc).__name__
        if is_checksum_error(exc):
            return [f"{next(meta.keys())} fails its check (checksum mismatch)"]
        return [f"{meta.name}/zarr.json does not describe its first chunk ({text})"]
    return []


def _digest(value: object) -> str:
    """A short digest of a JSON value (its canonical text)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _split(meta: Meta) -> tuple[dict, dict]:
    """An array's ``zarr.json``: its keys but the attributes, and its attributes."""
    doc = dict(meta.doc)
    attrs = doc.pop("attributes", None)
    return doc, attrs if isinstance(attrs, dict) else {}


def _parts(meta: Meta, files: dict[str, int]) -> str:
    """Digest of every part of an array: its key, size and last 4 bytes (the CRC32C of a
    chunk, the index checksum of a shard). One small read per part."""
    hashed = hashlib.sha256()
    for key in sorted(files):
        try:
            tail = checksum.stored_in_file(meta.folder.parent / key, None).hex()
        except OSError as exc:
            tail = type(exc).__name__
        hashed.update(f"{key.partition('/')[2]} {files[key]} {tail}\n".encode())
    return hashed.hexdigest()[:16]


def _chunks(meta: Meta, stored: dict[str, bytes]) -> str:
    """Digest of the CRC32C of every chunk (inside each shard) of an array at its key
    (``stored``: :func:`ltmstore.core.checksum.stored` of each part)."""
    hashed = hashlib.sha256()
    for key in sorted(stored):
        hashed.update(f"{key.partition('/')[2]} {stored[key].hex()}\n".encode())
    return hashed.hexdigest()[:16]


def _stored_in_files(meta: Meta, files: dict[str, int]) -> dict[str, bytes]:
    index = meta.shard_index()
    out = {}
    for key in files:
        try:
            out[key] = checksum.stored_in_file(meta.folder.parent / key, index)
        except OSError as exc:
            out[key] = type(exc).__name__.encode()
    return out


def record(folder: Path, stage: str) -> dict | None:
    """What ``stage`` wrote in the array at ``folder`` (None where its metadata cannot be read):
    a digest of its ``zarr.json`` but the attributes, of each of its attributes, of its parts' keys,
    sizes and CRC32Cs (:func:`_parts`), and, when sharded, of every inner chunk's CRC32C at its
    key (:func:`_chunks`). Small reads only: the data is not read again."""
    meta = read_meta(folder)
    if isinstance(meta, str):
        return None
    doc, attrs = _split(meta)
    files = _files(folder)
    entry = {"stage": stage, "metadata": _digest(doc),
             "attributes": {k: _digest(v) for k, v in attrs.items()},
             "parts": _parts(meta, files)}
    if meta.shard_index() is not None:
        entry["chunks"] = _chunks(meta, _stored_in_files(meta, files))
    return entry


def recorded(root: Path, records: dict, stage: str, names: Collection[str] | None) -> dict:
    """:data:`WRITTEN` of the store at ``root`` once ``stage`` completes: the records of
    ``records`` for arrays still there, and new ones (:func:`record`) for the arrays ``names``
    the stage wrote (every array where None), every coordinate, and every array not recorded yet
    (as in a store written before ltmstore recorded them)."""
    out = {}
    for folder in _folders(root):
        name = folder.name
        kept = records.get(name) if isinstance(records, dict) else None
        if kept is None or names is None or name in names or name in COORDINATES:
            kept = record(folder, stage)
        if kept is not None:
            out[name] = kept
    return out


def _cf(key: str, value: object) -> bool:
    """Whether xarray's CF decoding applies the attribute ``key: value`` to the values."""
    return key in CF_DECODED or (key == "units" and "since" in str(value))


def cf_damage(meta: Meta) -> list[str]:
    """Attributes of an array that xarray's CF decoding applies to its values (:data:`CF_DECODED`),
    none of which ltmstore writes: plain ``xarray.open_zarr`` would not return what is stored."""
    _, attrs = _split(meta)
    return [f"{meta.name}/zarr.json: attribute {key!r}, which ltmstore never writes (xarray's CF "
            "decoding applies it to the values)" for key in attrs if _cf(key, attrs[key])]


def record_damage(meta: Meta, entry: dict) -> list[str]:
    """The metadata of an array's ``zarr.json``, and each attribute, that differ from what the
    stage that wrote it recorded (:func:`record`): an attribute added, missing or changed."""
    stage = entry.get("stage", "?")
    where = f"{meta.name}/zarr.json"
    doc, now = _split(meta)
    found = []
    if _digest(doc) != entry.get("metadata"):
        found.append(f"{where}: its metadata (shape, chunks, codecs, fill value ...) is not "
                     f"what the {stage} stage wrote")
    wrote = entry.get("attributes")
    wrote = wrote if isinstance(wrote, dict) else {}
    for key in sorted(set(now) | set(wrote)):
        if key not in wrote:
            cf = " (xarray's CF decoding applies it to the values)" if _cf(key, now[key]) else ""
            found.append(f"{where}: attribute {key!r} was added after the {stage} stage wrote "
                         f"the array{cf}")
        elif key not in now:
            found.append(f"{where}: attribute {key!r} is missing (the {stage} stage wrote it)")
        elif _digest(now[key]) != wrote[key]:
            found.append(f"{where}: attribute {key!r} is not what the {stage} stage wrote")
    return found


def _misplaced(meta: Meta, stage: str) -> str:
    return (f"{meta.name}/c holds chunks the {stage} stage did not write there (moved, swapped "
            "with others, or from another store)")


def parts_damage(meta: Meta, entry: dict, files: dict[str, int]) -> list[str]:
    """Whether the parts of an array hold, at each key, the CRC32C (a shard: the index checksum)
    that the stage that wrote it recorded there."""
    if _parts(meta, files) == entry.get("parts"):
        return []
    return [_misplaced(meta, entry.get("stage", "?"))]


def required(attrs: dict, metas: dict[str, Meta]) -> dict[str, str]:
    """``{variable: stage}``: what the completed stages of a (checksummed) store wrote and its
    readers need, from the stage records in the group attributes ``attrs``.

    A store built through the library by hand (a notebook, a test: stage records without the
    fields ``ltm ingest`` and ``ltm reconstruct`` record) must hold only what its records say
    a reader needs: ``ltm`` and what goes with it."""
    records = attrs.get("stages", {})

    def done(stage: str) -> dict:
        entry = records.get(stage) or {}
        return entry if entry.get("complete") else {}

    acquisition = attrs.get("acquisition", {})
    far = acquisition.get("light_kind") == "far"
    need: dict[str, str] = {}
    if "n_frames" in done("ingest"):  # a store made by ltm ingest (not by hand, in a notebook)
        dropped = FRAME_VARIABLES if done("compact").get("frames_dropped") else ()
        kept_chroma = done("ingest").get("chroma", {}).get("frames_kept", True)
        names = ["frames", *(["frame_chroma"] if kept_chroma else []), "pose_r", "pose_s",
                 "pose_z", "pose_valid", "chroma", "chroma_spread",
                 *(["pose_p", "pose_q"] if "view_plane" in acquisition else [])]
        need.update({n: "ingest" for n in names if n not in dropped})
    reconstruct = done("reconstruct")
    colour = ["cb", "cr"] if reconstruct.get("color") else []
    if done("resample") and not far:
        need.update({n: "resample" for n in ["samples", "count",
                                             *(f"samples_{c}" for c in colour)]})
    if reconstruct:
        maps = ["expected_error", "unsupported", "method_map"] if "method" in reconstruct else []
        ltms = ["ltm", *(f"ltm_{c}" for c in colour)]
        maker = factored.factored_by({s: done(s) for s in ("reconstruct", "compact")})
        compacted = maker == "compact" and "ltm" not in metas
        if maker == "reconstruct" or compacted:  # either command's factors
            ltms = [f"{n}{part}" for n in ltms for part in ("_weights", "_basis", "_ranks")]
        if compacted:
            need.update({n: "compact" for n in ltms})
        need.update({n: "reconstruct" for n in [*ltms, *maps]
                     if n not in need})
        if reconstruct.get("exposure_fitted"):
            need["exposure"] = "reconstruct"
        if _has_surface(reconstruct, acquisition, metas.get("method_map"), far):
            need.update({n: "reconstruct" for n in SURFACE})
        if far and any(SHADOW_MARK in m for m in _methods(metas.get("method_map"))):
            need["shadow_height"] = "reconstruct"
    return need


def _has_surface(record: dict, acquisition: dict, method_map: Meta | None, far: bool) -> bool:
    """Whether the reconstruction wrote the surface maps (as ltmstore.stages.reconstruct and
    reconstruct_far do)."""
    if far:
        return any(m.startswith(SURFACE_PREFIX) for m in _methods(method_map))
    lattice = record.get("lattice", {}).get("dims", [])
    placed = "object" in acquisition if "placement" not in record \
        else bool((record["placement"] or {}).get("extent"))  # declared or estimated
    return record.get("method") in ("auto", "physical") and placed and len(lattice) == 2


def _methods(method_map: Meta | None) -> list[str]:
    """The method names a far store's ``method_map`` lists (none where it cannot be read)."""
    try:
        meta = json.loads((method_map.folder / "zarr.json").read_text()) if method_map else {}
    except (OSError, ValueError):
        return []
    return [str(m) for m in meta.get("attributes", {}).get("methods", [])]


def size_damage(metas: dict[str, Meta], attrs: dict) -> list[str]:
    """Dimensions whose size differs between arrays, from their coordinate, or from the
    lattice the reconstruct record names."""
    sizes: dict[str, tuple[int, str]] = {}
    for name in COORDINATES:  # a coordinate sets its dimension's size
        meta = metas.get(name)
        if meta is not None and meta.dims == (name,):
            sizes[name] = (meta.shape[0], name)
    found = []
    for meta in metas.values():
        for dim, n in zip(meta.dims, meta.shape, strict=False):
            size, source = sizes.setdefault(dim, (n, meta.name))
            if n != size:
                found.append(f"{meta.name} has {dim} = {n}, expected {size} (as {source})")
    lattice = (attrs.get("stages", {}).get("reconstruct") or {}).get("lattice") or {}
    if (attrs.get("stages", {}).get("reconstruct") or {}).get("complete"):
        for dim, n in zip(lattice.get("dims", []), lattice.get("shape", []), strict=False):
            if dim in sizes and sizes[dim][0] != n:
                found.append(f"{sizes[dim][1]} has {dim} = {sizes[dim][0]}, expected {n} (the "
                             "lattice of the reconstruct record)")
    return found


def inspect(root: Path, attrs: dict, *, complete: Callable[[str], bool]) -> Report:
    """Every damage to the store at ``root`` that shows without reading its data.

    Parameters
    ----------
    root : Path
        The store folder (its group metadata already read: ``attrs``).
    attrs : dict
        The group attributes (stage records, acquisition, :data:`WRITTEN`).
    complete : callable
        ``complete(name)``: whether variable ``name`` belongs to no stage or to a completed one
        (only those must hold every part, be consistent with the rest, and be what their stage
        recorded writing).
    """
    lines, broken, metas = [], set(), {}
    for folder in _folders(root):
        meta = read_meta(folder)
        if isinstance(meta, str):
            lines.append(meta)
            broken.add(folder.name)
        else:
            metas[folder.name] = meta
    checksummed = any(has_checksum(m) for m in metas.values())
    records, problem = _records(attrs)
    lines += [problem] if problem else []
    unrecorded = []
    for name, meta in metas.items():
        entry = records.get(name) if complete(name) else None
        found = layout_damage(meta, checksummed)
        if not found:
            found = record_damage(meta, entry) if entry else cf_damage(meta)
        if not found and complete(name):
            files = _files(meta.folder)
            found = chunk_damage(root, meta, files) if checksummed else []
            if not found and entry:
                found = parts_damage(meta, entry, files)
            elif not found:
                unrecorded.append(name)
        lines += found
        broken |= {name} if found else set()
    usable = {n: m for n, m in metas.items() if complete(n) and n not in broken}
    lines += size_damage(usable, attrs)
    present = set(metas) | broken
    need = required(attrs, metas) if checksummed else {}
    for name, stage in need.items():
        if name not in present:
            lines.append(f"{name} is missing (the {stage} stage wrote it)")
    dims = {d for n, m in usable.items() for d in m.dims}
    lines += [f"{d} is missing (the coordinate of dimension {d})" for d in COORDINATES
              if d in dims and d not in present]
    return Report(lines, broken, unrecorded)


def _records(attrs: dict) -> tuple[dict, str | None]:
    """The records of :data:`WRITTEN` (empty in a store written before them), or why they
    cannot be read."""
    records = attrs.get(WRITTEN, {})
    if isinstance(records, dict) and all(isinstance(e, dict) for e in records.values()):
        return records, None
    return {}, f"zarr.json: its attribute {WRITTEN!r} (what each stage wrote) cannot be read"


def _data_pass(meta: Meta, files: dict[str, int]) -> tuple[list[str], dict[str, bytes]]:
    """Read every part of an array whole: the CRC32Cs that do not hold
    (:func:`ltmstore.core.checksum.damage_of`, nothing decompressed), and those stored at each
    key (:func:`ltmstore.core.checksum.stored`)."""
    index, found, stored = meta.shard_index(), [], {}
    for key in sorted(files):
        try:
            data = (meta.folder.parent / key).read_bytes()
        except OSError as exc:
            found.append(f"{key} cannot be read ({exc.strerror or type(exc).__name__})")
            continue
        why = checksum.damage_of(data, index)
        if why:
            found.append(f"{key} fails its check ({why})")
        stored[key] = checksum.stored_in_bytes(data, index)
    return found, stored


def data_damage(root: Path, attrs: dict, report: Report, *,
                complete: Callable[[str], bool]) -> list[str]:
    """The damage only reading every byte shows, as ``ltm check`` finds it (for ``ltm info``:
    a store it names damaged is never complete).

    Each array recorded in :data:`WRITTEN` and checksummed is read whole, its CRC32Cs checked
    against its bytes (nothing decompressed: the records already hold its metadata to what was
    written, and the CRC32C of each chunk to its key); every other array is read as ``ltm check``
    reads it (:func:`ltmstore.core.checksum.verify`: each part decoded).
    """
    records, _ = _records(attrs)
    found = []
    for folder in _folders(root):
        meta = read_meta(folder)
        if folder.name in report.broken or isinstance(meta, str):
            continue
        entry = records.get(meta.name) if complete(meta.name) else None
        if entry is None or not has_checksum(meta):
            found += checksum.verify(root, [meta.name])[0]
            continue
        lines, stored = _data_pass(meta, _files(folder))
        found += lines
        if not lines and "chunks" in entry and _chunks(meta, stored) != entry["chunks"]:
            found.append(_misplaced(meta, entry.get("stage", "?")))
    return found


def shard_damage(root: Path, attrs: dict, report: Report, *,
                 complete: Callable[[str], bool]) -> list[str]:
    """(``ltm check``, which decodes every chunk besides) The sharded arrays whose inner chunks
    do not hold, at each key, the CRC32C the stage that wrote them recorded there: the index and
    the last 4 bytes of each inner chunk read (:func:`_chunks`), not their data."""
    records, _ = _records(attrs)
    found = []
    for name, entry in records.items():
        meta = read_meta(root / name)
        if (name in report.broken or not complete(name) or isinstance(meta, str)
                or "chunks" not in entry):
            continue
        if _chunks(meta, _stored_in_files(meta, _files(meta.folder))) != entry["chunks"]:
            found.append(_misplaced(meta, entry.get("stage", "?")))
    return found


def _folders(root: Path) -> Iterator[Path]:
    """Every folder of the store that is, or was, an array (it holds ``zarr.json`` or chunks)."""
    for child in sorted(root.iterdir()):
        if child.is_dir() and ((child / "zarr.json").exists() or (child / "c").exists()):
            yield child


def checksummed(root: Path) -> bool:
    """Whether any array of the store at ``root`` carries checksums (all of them then must)."""
    for folder in _folders(root):
        meta = read_meta(folder)
        if not isinstance(meta, str) and has_checksum(meta):
            return True
    return False
