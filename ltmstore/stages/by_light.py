"""The light-major copy of an LTM: one chunk per lattice cell, for interactive relighting.

The store's ``ltm`` is written in shards of pixel tiles (the solver's unit); its inner chunks
split the lattice too, but a point light still touches every tile. Beside it, at the end of a
reconstruction, the same values are written light-major as ``ltm_by_light`` (and
``ltm_cb_by_light``, ``ltm_cr_by_light`` for a colour LTM): dims and coordinates of ``ltm``,
inner chunks of one lattice cell over the whole image (or over blocks of at most
:data:`MAX_CHUNK_PIXELS` pixels), shards of the ``ltm``'s own lattice chunk. A point light then
reads its 4 cells' planes (16 in 6D) and nothing else, and an area light only the cells it
covers: :mod:`ltmstore.stages.relight` uses the copy whenever the store has one. The copy costs
as many bytes as ``ltm`` itself.
"""

from __future__ import annotations

import itertools
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import zarr

from ltmstore.core import checksum
from ltmstore.core import store as st
from ltmstore.core.dims import CHROMA_LTM, LTM

if TYPE_CHECKING:  # a far-light reconstruct loads no xarray
    import xarray as xr

SUFFIX = "_by_light"
MAX_CHUNK_PIXELS = 1 << 20  # one chunk: at most 1024 x 1024 pixels of one cell (4 MB float32)
LTM_NAMES = (LTM, *CHROMA_LTM.values())
NAMES = tuple(f"{name}{SUFFIX}" for name in LTM_NAMES)


def by_light_name(name: str) -> str:
    """The name of the light-major copy of the LTM variable ``name``."""
    return f"{name}{SUFFIX}"


def pixel_chunk(image: tuple[int, int], limit: int = MAX_CHUNK_PIXELS) -> tuple[int, int]:
    """The whole image, halved along its longer side until at most ``limit`` pixels."""
    cy, cx = image
    while cy * cx > limit:
        if cy >= cx:
            cy = -(-cy // 2)
        else:
            cx = -(-cx // 2)
    return cy, cx


def write_by_light(group: zarr.Group, name: str = LTM, *, workers: int = 2) -> zarr.Array:
    """Write the light-major copy of the LTM variable ``name`` of ``group`` (replacing one).

    Parameters
    ----------
    group : zarr.Group
        An open store group (writable) holding ``name``.
    name : str
        ``ltm``, ``ltm_cb`` or ``ltm_cr``.
    workers : int
        Threads copying shards.

    Returns
    -------
    zarr.Array
        The copy, same shape, dtype, dims and compressors as ``name``.
    """
    source = group[name]
    dims = source.metadata.dimension_names
    lattice_chunk = source.chunks[2:]
    block = pixel_chunk(source.shape[:2])
    chunks = (*block, *(1,) * len(lattice_chunk))
    shards = (*block, *lattice_chunk)
    target = st.create_variable(group, by_light_name(name), dims, source.shape, chunks=chunks,
                                shards=shards, dtype=source.dtype,
                                compressors=checksum.FAST_COMPRESSORS)
    target.attrs.update({**source.attrs.asdict(), "light_major_copy_of": name})
    starts = [range(0, n, c) for n, c in zip(source.shape, shards, strict=True)]

    def copy(corner: tuple[int, ...]) -> None:
        region = tuple(slice(a, min(a + c, n))
                       for a, c, n in zip(corner, shards, source.shape, strict=True))
        target[region] = source[region]

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(copy, itertools.product(*starts)))
    return target


def light_major(ds: xr.Dataset, name: str = LTM) -> xr.DataArray:
    """``ds[name]`` read through its light-major copy when the store has one."""
    copy = by_light_name(name)
    return ds[copy] if copy in ds and ds[copy].shape == ds[name].shape else ds[name]
