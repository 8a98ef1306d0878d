"""Checksums of a store: every chunk carries a CRC32C, every chunk is written, damage is named.

Arrays are written with Zarr v3's ``crc32c`` codec last in their codec pipeline (inside each shard
for sharded arrays, whose index has its own), so a flipped byte makes the read fail instead of
returning a wrong value. Every chunk is written, even one that holds only the fill value, so a
missing chunk file is damage too (:mod:`ltmstore.core.integrity` finds it, and the rest of what
shows without reading). Stores written before this carry no checksums: they still open,
and only their missing metadata can be found.

A CRC32C says a chunk's bytes are those written, not that they lie where they were written: a
chunk moved, swapped with another or taken from another store passes its own check.
:func:`stored` (the CRC32Cs one stored part holds, read without its data) and :func:`damage_of`
(those CRC32Cs checked against the bytes, without decompressing them) are what
:mod:`ltmstore.core.integrity` keys by array and chunk to find them.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import google_crc32c  # zarr's crc32c codec computes with it
import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

# Codec pipeline tail of every array; `config` of every array (see the module docstring).
# Zstandard level 1: on the Toys-size samples (float32, 70 % NaN) 3.07x smaller than raw at
# 0.44 GB/s written, against 3.26x at 0.27 GB/s for level 3 (Zarr's default).
COMPRESSORS = (ZstdCodec(level=1), Crc32cCodec())
# The bulk floats, frames and every LTM: Blosc's byte shuffle, then LZ4 (lossless). Written
# 10-17x faster than Zstandard and read 3-6x faster, for 1-8 % more bytes: the Toys frames
# 1.26x smaller than raw at 2.5 GB/s against 1.28x at 0.14 GB/s (Zstandard level 3), the demo's
# ltm 1.28x at 2.5 GB/s against 1.38x at 0.18 GB/s (Blosc Zstandard level 5); Zstandard took
# 26-40 % of ``ltm ingest`` and ``ltm ingest-rti``. Blosc sets its type size from the array's
# dtype (float32, or float16 after ``--precision float16``).
FAST_COMPRESSORS = (BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"), Crc32cCodec())
ARRAY_CONFIG = {"write_empty_chunks": True}
# An array reopened from its metadata (a tile's worker, a resumed run) takes Zarr's global
# default, not the config it was created with: make the default write every chunk too.
zarr.config.set({"array.write_empty_chunks": True})
NO_CHECKSUMS = "carries no checksums (written before ltmstore checksummed its chunks)"


def has_checksums(array: zarr.Array) -> bool:
    """Whether ``array``'s chunks carry a CRC32C."""
    codecs = array.metadata.codecs
    inner = getattr(codecs[0], "codecs", ()) if len(codecs) == 1 else ()
    return any(isinstance(c, Crc32cCodec) for c in (*codecs, *inner))


def arrays(root: Path) -> Iterator[tuple[str, Path]]:
    """``(name, folder)`` of every array folder of the store at ``root``."""
    for child in sorted(root.iterdir()):
        if child.is_dir() and (child / "zarr.json").is_file():
            yield child.name, child


def _open(folder: Path) -> tuple[zarr.Array | None, str | None]:
    try:
        json.loads((folder / "zarr.json").read_text())
        return zarr.open_array(str(folder), mode="r", zarr_format=3), None
    except Exception as exc:  # noqa: BLE001 - any unreadable metadata is damage to name
        return None, f"{folder.name}/zarr.json cannot be read ({type(exc).__name__})"


def _grid(array: zarr.Array) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The stored parts (shards, or chunks) of ``array``: their shape and count per axis."""
    part = array.shards or array.chunks
    return part, tuple(-(-n // p) for n, p in zip(array.shape, part, strict=True))


def _key(name: str, index: tuple[int, ...]) -> str:
    return "/".join((name, "c", *map(str, index))) if index else f"{name}/c"


def group_damage(root: Path) -> str | None:
    """Why the group metadata of the store at ``root`` is damaged, or None."""
    try:
        meta = json.loads((root / "zarr.json").read_text())
        if meta.get("node_type") != "group":
            return "zarr.json is not a Zarr group"
    except (OSError, ValueError) as exc:
        return f"zarr.json cannot be read ({type(exc).__name__})"
    return None


def parts(root: Path, names: list[str]) -> int:
    """How many stored parts :func:`verify` reads of the arrays ``names``."""
    total = 0
    for name in names:
        array, _ = _open(root / name)
        if array is not None:
            total += math.prod(_grid(array)[1])
    return total


def verify(root: Path, names: list[str],
           advance: Callable[[], object] = lambda: None) -> tuple[list[str], list[str]]:
    """Read every chunk of the arrays ``names`` of the store at ``root``; check its checksum.

    Returns ``(damage, unchecked)``: one line per damaged part, and the arrays that carry no
    checksums. ``advance()`` is called after each part (a progress bar). The damage that shows
    without reading (:mod:`ltmstore.core.integrity`) is found before.
    """
    damage = []
    unchecked = []
    for name in names:
        array, _ = _open(root / name)
        if array is None:
            continue
        if not has_checksums(array):
            unchecked.append(name)
        part, counts = _grid(array)
        for index in itertools.product(*map(range, counts)):
            region = tuple(slice(i * p, (i + 1) * p) for i, p in zip(index, part, strict=True))
            try:
                array[region]
            except Exception as exc:  # noqa: BLE001 - every read failure is damage to name
                damage.append(f"{_key(name, index)} fails its check ({_reason(exc)})")
            advance()
    return damage, unchecked


def is_checksum_error(exc: Exception) -> bool:
    """Whether ``exc`` is Zarr's report of a chunk that fails its crc32c."""
    return "checksum" in str(exc)


def _reason(exc: Exception) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return "checksum mismatch" if is_checksum_error(exc) else text[:120]


@dataclass(frozen=True)
class ShardIndex:
    """The index of a shard (Zarr's ``sharding_indexed``): ``chunks`` inner chunks, each an
    ``(offset, nbytes)`` pair of little-endian uint64, at the end of the shard (or at its start),
    followed by a CRC32C where ``crc``; ``inner_crc``: each inner chunk ends with one."""

    chunks: int
    at_end: bool = True
    crc: bool = True
    inner_crc: bool = True

    @property
    def nbytes(self) -> int:
        return 16 * self.chunks + 4 * self.crc

    def entries(self, index: bytes) -> list[tuple[int, int]]:
        """``(offset, nbytes)`` of every inner chunk that is stored (not the all-ones pair of
        one that is not)."""
        pairs = np.frombuffer(index[: 16 * self.chunks], "<u8").reshape(-1, 2)
        return [(int(o), int(n)) for o, n in pairs[~(pairs == np.iinfo(np.uint64).max).all(1)]]


def _crc_holds(data: np.ndarray) -> bool:
    """Whether the bytes ``data`` (uint8) end with the CRC32C of those before it (as Zarr's codec
    writes it)."""
    return len(data) >= 4 and google_crc32c.value(data[:-4]) == int.from_bytes(
        data[-4:].tobytes(), "little")


def stored(read: Callable[[int, int], bytes], size: int, index: ShardIndex | None) -> bytes:
    """The CRC32Cs one stored part holds, without its data: its last 4 bytes (a chunk's CRC32C,
    the last codec ltmstore writes), or a shard's index and the last 4 bytes of every inner chunk
    it names. ``read(offset, n)`` reads the part's bytes, ``size`` is its length."""
    if index is None:
        return read(max(size - 4, 0), 4)
    raw = read(size - index.nbytes if index.at_end else 0, index.nbytes)
    if len(raw) < index.nbytes:
        return raw
    return raw + b"".join(read(o + n - 4, 4) for o, n in index.entries(raw)
                          if 4 <= n and o + n <= size)


def stored_in_file(path: str | os.PathLike, index: ShardIndex | None) -> bytes:
    """:func:`stored` of the file at ``path`` (a few small reads; the data is not read)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        size = os.fstat(fd).st_size
        return stored(lambda offset, n: os.pread(fd, n, max(offset, 0)), size, index)
    finally:
        os.close(fd)


def stored_in_bytes(data: bytes, index: ShardIndex | None) -> bytes:
    """:func:`stored` of a part read whole (``data``)."""
    return stored(lambda offset, n: data[max(offset, 0): max(offset, 0) + n], len(data), index)


def damage_of(data: bytes, index: ShardIndex | None) -> str | None:
    """Why the CRC32Cs stored in one part's bytes ``data`` (of a checksummed array) do not hold,
    or None: each one checked against the bytes it covers, nothing decompressed."""
    view = np.frombuffer(data, np.uint8)  # slices without copies
    if index is None:
        return None if _crc_holds(view) else "checksum mismatch"
    if len(data) < index.nbytes:
        return f"shard of {len(data)} bytes holds no index of {index.nbytes} bytes"
    start = len(data) - index.nbytes if index.at_end else 0
    raw = view[start: start + index.nbytes]
    if index.crc and not _crc_holds(raw):
        return "checksum mismatch (shard index)"
    for offset, n in index.entries(raw.tobytes()):
        if offset + n > len(data):
            return "a chunk its index names lies past the end of the shard"
        if index.inner_crc and not _crc_holds(view[offset: offset + n]):
            return "checksum mismatch"
    return None
