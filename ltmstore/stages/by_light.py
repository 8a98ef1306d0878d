"""The light-major copy of an LTM: one chunk per lattice cell, for interactive relighting.

The store's ``ltm`` is written in shards of pixel tiles (the solver's unit); its inner chunks
split the lattice too, but a point light still touches every tile. Beside it, at the end of a
reconstruction, the same values are written light-major as ``ltm_by_light`` (and
``ltm_cb_by_light``, ``ltm_cr_by_light`` for a colour LTM): dims and coordinates of ``ltm``,
inner chunks of one lattice cell over the whole image (or over blocks of at most
:data:`MAX_CHUNK_PIXELS` pixels, and of at most :data:`BAND_BYTES` per shard), shards of the
``ltm``'s own lattice chunk. A point light then reads its 4 cells' planes (16 in 6D) and nothing
else, and an area light only the cells it covers: :mod:`ltmstore.stages.relight` uses the copy
whenever the store has one. The copy costs as many bytes as ``ltm`` itself.
"""

from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import TYPE_CHECKING

import zarr

from ltmstore.core import checksum, memory
from ltmstore.core import store as st
from ltmstore.core.dims import CHROMA_LTM, LTM

if TYPE_CHECKING:  # a far-light reconstruct loads no xarray
    import xarray as xr
    from distributed import Client

SUFFIX = "_by_light"
MAX_CHUNK_PIXELS = 1 << 20  # one chunk: at most 1024 x 1024 pixels of one cell (4 MB float32)
BAND_BYTES = 256 << 20  # read and written at once by one band of the copy
LTM_NAMES = (LTM, *CHROMA_LTM.values())
NAMES = tuple(f"{name}{SUFFIX}" for name in LTM_NAMES)


def by_light_name(name: str) -> str:
    """The name of the light-major copy of the LTM variable ``name``."""
    return f"{name}{SUFFIX}"


def cell_major_name(name: str) -> str:
    """The LTM variable whose light-major copy is ``name`` (``name`` itself if it is none)."""
    return name.removesuffix(SUFFIX)


def pixel_chunk(image: tuple[int, int], limit: int = MAX_CHUNK_PIXELS) -> tuple[int, int]:
    """The whole image, halved along its longer side until at most ``limit`` pixels."""
    cy, cx = image
    while cy * cx > limit:
        if cy >= cx:
            cy = -(-cy // 2)
        else:
            cx = -(-cx // 2)
    return cy, cx


def write_by_light(group: zarr.Group, name: str = LTM, *, client: Client | None = None,
                   workers: int = 2, band_bytes: int = BAND_BYTES) -> zarr.Array:
    """Write the light-major copy of the LTM variable ``name`` of ``group`` (replacing one).

    The copy is written in bands of whole target shards (:func:`bands`): each band reads its
    cells of every pixel tile of ``name`` at once, which costs a third of reading each shard's
    cells apart (the per-shard index and per-chunk overhead of Zarr: 14 against 37 s for the
    1.6 GB LTM of 400 x 400 pixels on 50 x 50 cells).

    Parameters
    ----------
    group : zarr.Group
        An open store group (writable) holding ``name``.
    name : str
        ``ltm``, ``ltm_cb`` or ``ltm_cr``.
    client : distributed.Client, optional
        Copy the bands as tasks of this client's cluster (one task per band); without it, on
        ``workers`` threads of this process.
    workers : int
        Threads copying bands where there is no ``client``.
    band_bytes : int
        Bytes read and written at once by one band (at least one target shard).

    Returns
    -------
    zarr.Array
        The copy, same shape, dtype, dims and compressors as ``name``.
    """
    source = group[name]
    dims = source.metadata.dimension_names
    lattice_chunk = source.chunks[2:]
    # a target shard (the pixel block times ltm's lattice chunk) fits in a band: the band's
    # bytes bound what a copying worker holds (a whole 1024 x 1024 px block of 8 x 16 cells
    # would be 512 MB)
    shard_pixels = band_bytes // (source.dtype.itemsize * math.prod(lattice_chunk))
    block = pixel_chunk(source.shape[:2], max(1, min(MAX_CHUNK_PIXELS, shard_pixels)))
    chunks = (*block, *(1,) * len(lattice_chunk))
    shards = (*block, *lattice_chunk)
    target = st.create_variable(group, by_light_name(name), dims, source.shape, chunks=chunks,
                                shards=shards, dtype=source.dtype,
                                compressors=checksum.FAST_COMPRESSORS)
    target.attrs.update({**source.attrs.asdict(), "light_major_copy_of": name})
    regions = bands(source.shape, shards, band_bytes // source.dtype.itemsize)
    if client is None:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(partial(copy_band, source=source, target=target), regions))
    else:
        client.gather(client.map(copy_band, regions, source=source, target=target, pure=False))
    return target


def bands(shape: tuple[int, ...], shards: tuple[int, ...],
          limit: int) -> list[tuple[slice, ...]]:
    """Regions of whole ``shards`` that tile an array of ``shape``, each of at most ``limit``
    elements where one shard allows: the last dimensions are taken whole first (a band of a
    light-major copy then reads few, large pieces of each pixel tile)."""
    counts = [-(-n // c) for n, c in zip(shape, shards, strict=True)]
    take = [1] * len(shape)
    size = math.prod(shards)
    for dim in reversed(range(len(shape))):
        take[dim] = max(1, min(counts[dim], limit // size))
        size *= take[dim]
    steps = [t * c for t, c in zip(take, shards, strict=True)]
    starts = itertools.product(*(range(0, n, step) for n, step in zip(shape, steps, strict=True)))
    return [tuple(slice(a, min(a + step, n)) for a, step, n in zip(corner, steps, shape,
                                                                   strict=True))
            for corner in starts]


def copy_band(region: tuple[slice, ...], *, source: zarr.Array, target: zarr.Array) -> None:
    """Copy ``source[region]`` to ``target[region]`` (a region of whole target shards), with the
    process's freed heap given back before and after (:func:`~ltmstore.core.memory.trim`)."""
    memory.trim()
    target[region] = source[region]
    memory.trim()


def light_major(ds: xr.Dataset, name: str = LTM) -> xr.DataArray:
    """``ds[name]`` read through its light-major copy when the store has one."""
    copy = by_light_name(name)
    return ds[copy] if copy in ds and ds[copy].shape == ds[name].shape else ds[name]
