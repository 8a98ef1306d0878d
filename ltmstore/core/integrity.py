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
* every dimension has one size across the store, and the lattice the stage records name.

Stores written before ltmstore checksummed its chunks (no CRC32C anywhere) are held only to the
layout, sizes and coordinates: which variables they must hold is not known.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import zarr

from ltmstore.core import factored
from ltmstore.core.checksum import is_checksum_error

COORDINATES = ("t", "y", "x", "r", "s", "p", "q", "channel", "color", "component")
SURFACE = ("normal", "albedo", "specular", "roughness", "ambient")
SURFACE_PREFIX = "physical+"  # a far store's surface blend (ltmstore.stages.surface.PREFIX)
FRAME_VARIABLES = ("frames", "frame_chroma")  # what `ltm compact` may drop
LATTICES = (("r", "s"), ("r", "s", "p", "q"))
F16, F32, F64 = "float16", "float32", "float64"


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

    @property
    def name(self) -> str:
        return self.folder.name

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
    """What :func:`inspect` found: one line per damaged part, and the arrays whose metadata is
    damaged (not to be read)."""

    lines: list[str]
    broken: set[str]


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
                    tuple(meta["codecs"]), meta.get("chunk_key_encoding", {}))
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


def chunk_damage(root: Path, meta: Meta) -> list[str]:
    """Stored parts of an array that are missing, empty, folders, or outside its grid."""
    files = _files(root / meta.name)
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
    return need


def _has_surface(record: dict, acquisition: dict, method_map: Meta | None, far: bool) -> bool:
    """Whether the reconstruction wrote the surface maps (as ltmstore.stages.reconstruct and
    reconstruct_far do)."""
    if far:
        try:
            meta = json.loads((method_map.folder / "zarr.json").read_text()) if method_map else {}
        except (OSError, ValueError):
            return False
        methods = meta.get("attributes", {}).get("methods", [])
        return any(str(m).startswith(SURFACE_PREFIX) for m in methods)
    lattice = record.get("lattice", {}).get("dims", [])
    placed = "object" in acquisition if "placement" not in record \
        else bool((record["placement"] or {}).get("extent"))  # declared or estimated
    return record.get("method") in ("auto", "physical") and placed and len(lattice) == 2


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
        The group attributes (stage records, acquisition).
    complete : callable
        ``complete(name)``: whether variable ``name`` belongs to no stage or to a completed one
        (only those must hold every part, and be consistent with the rest).
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
    for name, meta in metas.items():
        found = layout_damage(meta, checksummed)
        if not found and complete(name) and checksummed:
            found = chunk_damage(root, meta)
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
    return Report(lines, broken)


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
