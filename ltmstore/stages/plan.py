"""The tile plan of a reconstruction, fixed before any work: pixel tiles and lattice chunks."""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import psutil
import zarr

from ltmstore.core import store as st
from ltmstore.core.errors import LtmError

METHOD_MAP = "method_map"  # (tile_y, tile_x) index into its attribute "methods"


@dataclass(frozen=True)
class TilePlan:
    """Pixel tiles (the unit of work) and the lattice chunks (inner chunks) of the store; each
    ``ltm`` shard holds ``shard_tiles`` x ``shard_tiles`` tiles (one, where a tile is also the
    unit of resumption)."""

    image: tuple[int, int]
    lattice: tuple[int, ...]
    tile: tuple[int, int]
    lattice_chunk: tuple[int, ...]
    shard_tiles: int = 1

    @property
    def block(self) -> tuple[int, ...]:
        """One tile of whole LTFs: the Dask chunk of ``samples`` and ``ltm``."""
        return (*self.tile, *self.lattice)

    @property
    def shards(self) -> tuple[int, ...]:
        """The shard's tiles, rounded up along the lattice to whole inner chunks (Zarr
        requires it)."""
        return (*(t * self.shard_tiles for t in self.tile),
                *(-(-n // c) * c for n, c in zip(self.lattice, self.lattice_chunk, strict=True)))

    @property
    def chunks(self) -> tuple[int, ...]:
        return (*self.tile, *self.lattice_chunk)

    @property
    def grid(self) -> tuple[int, int]:
        """Tiles along ``y`` and ``x``: the shape of the tile completion marks."""
        return tuple(-(-n // t) for n, t in zip(self.image, self.tile, strict=True))

    @property
    def n_tiles(self) -> int:
        return int(np.prod(self.grid))

    def tile_region(self, index: tuple[int, int]) -> tuple[slice, slice]:
        """The pixel rows and columns of the tile at ``index`` (clipped to the image)."""
        return tuple(slice(i * t, min((i + 1) * t, n))
                     for i, t, n in zip(index, self.tile, self.image, strict=True))

    def shard_blocks(self) -> list[tuple[tuple[slice, slice], list[tuple[int, int]]]]:
        """Each shard's pixel rows and columns and its tiles, shard row by shard row: what one
        Zarr write replaces whole (a partial write would read the shard back and race with
        the write of its other tiles)."""
        k, (rows, cols) = self.shard_tiles, self.grid
        blocks = []
        for i in range(0, rows, k):
            for j in range(0, cols, k):
                tiles = [(a, b) for a in range(i, min(i + k, rows))
                         for b in range(j, min(j + k, cols))]
                (top, left), (bottom, right) = (self.tile_region(t) for t in (tiles[0], tiles[-1]))
                blocks.append(((slice(top.start, bottom.stop), slice(left.start, right.stop)),
                               tiles))
        return blocks

    def with_shards(self, min_shards: int, sides: Sequence[int] = (4, 2)) -> TilePlan:
        """The plan with the largest shards of ``sides`` tiles a side that still leave at
        least ``min_shards`` shards (work for every thread); one tile a shard if none does."""
        rows, cols = self.grid
        side = next((k for k in sides if -(-rows // k) * -(-cols // k) >= min_shards), 1)
        return replace(self, shard_tiles=side)


def plan_tiles(image: tuple[int, int], lattice: tuple[int, ...], *, tile: int = 32,
               chunk_bytes: int | None = None, max_block_bytes: int = 64 * 2**20) -> TilePlan:
    """Square pixel tiles of side ``tile`` and lattice chunks of about ``chunk_bytes``.

    The lattice is split along its longest axis, again and again, until one inner chunk of a
    tile, in float32, is no larger than ``chunk_bytes`` (default :data:`CHUNK_BYTES`, or
    :data:`CHUNK_BYTES_6D` for a 6-D lattice); each split takes a divisor of the axis where one
    is near (:func:`_split`), so that shards hold whole inner chunks and a tile's write replaces
    its shard instead of merging into a partly written one. A point-light query that has no
    light-major copy to read reads one or a few inner chunks per tile instead of the whole
    shard. The tile side is halved while one tile of whole LTFs would exceed
    ``max_block_bytes`` (6D lattices: a solver holds several copies of its tile).
    """
    if chunk_bytes is None:
        chunk_bytes = CHUNK_BYTES if len(lattice) <= 2 else CHUNK_BYTES_6D
    while tile > 1 and 4 * tile * tile * math.prod(lattice) > max_block_bytes:
        tile = -(-tile // 2)
    tile_yx = (min(tile, image[0]), min(tile, image[1]))
    chunk = list(lattice)
    while 4 * math.prod(tile_yx) * math.prod(chunk) > chunk_bytes and max(chunk) > 1:
        axis = int(np.argmax(chunk))
        chunk[axis] = _split(lattice[axis], chunk[axis])
    return TilePlan(image=tuple(image), lattice=tuple(lattice), tile=tile_yx,
                    lattice_chunk=tuple(chunk))


# Inner chunks of a tile of ``ltm``: 512 KiB (8 x 16 cells of 32 x 32 px). Against 64 KiB on a
# Notre Dame-b shard (32 x 80 cells, a throwaway microbenchmark): a tile's write 0.12 -> 0.034 s,
# reading a band for the light-major copy 0.30-0.43 -> 0.15 s; a point light read from ``ltm``
# itself (stores without the copy) 0.09 -> 0.10 s. 6-D lattices keep small chunks.
CHUNK_BYTES, CHUNK_BYTES_6D = 512 * 1024, 64 * 1024


def _split(n: int, chunk: int) -> int:
    """The next inner chunk length below ``chunk`` along an axis of ``n`` cells: the largest
    divisor of ``n`` below ``chunk`` and at least a quarter of it, else half of ``chunk``
    (rounded up)."""
    low = -(-chunk // 4)
    if chunk - low <= n // low - n // (chunk - 1):  # fewer lengths than quotients to try
        found = (d for d in range(chunk - 1, low - 1, -1) if n % d == 0)
    else:  # a huge axis (a refused lattice's plan): the quotients k = n / d, smallest first
        found = (n // k for k in range(-(-n // (chunk - 1)), n // low + 1)
                 if n % k == 0 and low <= n // k < chunk)
    return next(found, -(-chunk // 2))


# What one run holds in memory at once: the frame count of every cell (int64, resample's
# binning) and a tile of whole LTFs twice (its samples and its LTM, float32).
COUNT_BYTES, FLOAT_BYTES, BLOCK_COPIES = 8, 4, 2
# The best lossless compression assumed of a stored LTM before its size is called impossible
# (the smooth synthetic LTM of the ingest tests compresses 11.5 times, a real one far less).
MAX_COMPRESSION = 16


def check_fits(plan: TilePlan, store: str | os.PathLike, *, what: str, ltm_copies: int) -> None:
    """Refuse a reconstruction that cannot fit in this machine's memory or the store's disk.

    Parameters
    ----------
    plan : TilePlan
        The tile plan of the lattice over the image.
    store : str or PathLike
        The store to be written (its disk's free space counts).
    what : str
        The lattice as the user named it, for the message (``"--lattice 100000x100000"``).
    ltm_copies : int
        Dense LTM-sized float32 variables the store will hold (``ltm``, its colour LTMs, their
        light-major copies, the samples).

    Raises
    ------
    LtmError
        Naming the size, when the memory needed is more than the memory available now, or
        the LTM at :data:`MAX_COMPRESSION` times compression is more than the free disk.
    """
    cells = math.prod(plan.lattice)
    memory = cells * (COUNT_BYTES + BLOCK_COPIES * FLOAT_BYTES * math.prod(plan.tile))
    available = psutil.virtual_memory().available
    shape = f"{what} ({cells:,} cells over {plan.image[0]}x{plan.image[1]} pixels)"
    if memory > available:
        raise LtmError(f"{shape} needs at least {size_text(memory)} of memory (the frame count "
                       f"of every cell and a pixel tile of whole LTFs); {size_text(available)} "
                       "is available; expected a coarser lattice")
    stored = ltm_copies * _float32_bytes(plan)
    free = _free_bytes(store)
    if stored // MAX_COMPRESSION > free:
        raise LtmError(f"{shape} makes a store of {size_text(stored)} uncompressed (at least "
                       f"{size_text(stored // MAX_COMPRESSION)} compressed); the disk of "
                       f"{str(store)!r} has {size_text(free)} free; expected a coarser lattice")


# Stored bytes per float32 byte of the dense form, measured on Notre Dame-b (1024 x 1024 px,
# 32 x 80 cells, 2026-11-27): the ltm and its light-major copy (Blosc lz4) LTM_STORED, the
# samples (float16, 70 % of cells NaN, Zstd; 0.31 in float32) SAMPLES_STORED.
LTM_STORED, SAMPLES_STORED = 0.77, 0.17
# `--form auto` stores the dense form while its estimate takes at most this share of the free
# disk (room for the estimate's error and for everything else on the disk), else the factors.
DENSE_DISK_SHARE = 0.5


def choose_form(plan: TilePlan, store: str | os.PathLike, *, channels: int, light_major: bool,
                free: int | None = None) -> dict:
    """The stored form of ``--form auto``: ``dense`` while the dense store fits in
    :data:`DENSE_DISK_SHARE` of the free disk, else ``factored`` (a few percent of the bytes).

    Parameters
    ----------
    plan : TilePlan
        The tile plan of the lattice over the image.
    store : str or PathLike
        The store to be written (its disk's free space counts).
    channels : int
        LTMs written: 1, or 3 for a colour LTM (Y, Cb, Cr).
    light_major : bool
        Whether the dense form would also write each LTM's light-major copy.
    free : int, optional
        Free bytes to weigh against (default: the store's disk, now).

    Returns
    -------
    dict
        ``form``, ``dense_estimate_bytes`` (samples and LTMs in the dense form, at the bytes
        per float32 byte measured: :data:`LTM_STORED`, :data:`SAMPLES_STORED`) and
        ``free_bytes``.
    """
    copies = SAMPLES_STORED + LTM_STORED * (2 if light_major else 1)
    dense = int(channels * _float32_bytes(plan) * copies)
    free = _free_bytes(store) if free is None else int(free)
    form = "dense" if dense <= DENSE_DISK_SHARE * free else "factored"
    return {"form": form, "dense_estimate_bytes": dense, "free_bytes": free}


def _float32_bytes(plan: TilePlan) -> int:
    """Bytes of one LTM-sized float32 variable of ``plan``."""
    return FLOAT_BYTES * math.prod(plan.image) * math.prod(plan.lattice)


def _free_bytes(store: str | os.PathLike) -> int:
    """Free bytes on the disk of ``store`` (or of its nearest existing parent folder)."""
    return shutil.disk_usage(_existing_parent(store)).free


def size_text(n: int) -> str:
    """Bytes in binary units: ``74.5 GiB``, ``6.94 EiB``."""
    units = ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB")
    i = 0
    while n >= 1024 ** (i + 1) and i < len(units) - 1:
        i += 1
    return f"{n} bytes" if i == 0 else f"{n / 1024 ** i:.3g} {units[i]}"


def _existing_parent(path: str | os.PathLike) -> str:
    path = os.path.abspath(path)
    while not os.path.exists(path) and os.path.dirname(path) != path:
        path = os.path.dirname(path)
    return path


def write_method_map(group: zarr.Group, plan: TilePlan, chosen: np.ndarray, names: list[str],
                     how: str) -> None:
    """``method_map (tile_y, tile_x)``: the model each tile used, an index into the attribute
    ``methods`` (``-1`` for a tile without one); ``how`` says how it was chosen."""
    arr = st.create_variable(group, METHOD_MAP, ("tile_y", "tile_x"), plan.grid, chunks=plan.grid,
                             dtype=np.int16, fill_value=-1, attrs={
                                 "methods": list(names), "tile": list(plan.tile),
                                 "long_name": f"model chosen per pixel tile (index into "
                                              f"'methods') by {how}"})
    arr[...] = chosen
