"""The tile plan of a reconstruction, fixed before any work: pixel tiles and lattice chunks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import zarr

from ltmstore.core import store as st

METHOD_MAP = "method_map"  # (tile_y, tile_x) index into its attribute "methods"


@dataclass(frozen=True)
class TilePlan:
    """Pixel tiles (the unit of work, one ``ltm`` shard each) and the lattice chunks (inner
    chunks) of the store."""

    image: tuple[int, int]
    lattice: tuple[int, ...]
    tile: tuple[int, int]
    lattice_chunk: tuple[int, ...]

    @property
    def block(self) -> tuple[int, ...]:
        """One tile of whole LTFs: the Dask chunk of ``samples`` and ``ltm``."""
        return (*self.tile, *self.lattice)

    @property
    def shards(self) -> tuple[int, ...]:
        """The block, rounded up along the lattice to whole inner chunks (Zarr requires it)."""
        return (*self.tile, *(-(-n // c) * c for n, c in
                              zip(self.lattice, self.lattice_chunk, strict=True)))

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


def plan_tiles(image: tuple[int, int], lattice: tuple[int, ...], *, tile: int = 32,
               chunk_bytes: int = 64 * 1024, max_block_bytes: int = 64 * 2**20) -> TilePlan:
    """Square pixel tiles of side ``tile`` and lattice chunks of about ``chunk_bytes``.

    The lattice is split evenly along every axis (powers of two) until one inner chunk of a
    tile, in float32, is no larger than ``chunk_bytes``: a point-light query then reads one or
    a few inner chunks per tile instead of the whole shard. The tile side is halved while one
    tile of whole LTFs would exceed ``max_block_bytes`` (6D lattices: a solver holds several
    copies of its tile).
    """
    while tile > 1 and 4 * tile * tile * int(np.prod(lattice)) > max_block_bytes:
        tile = -(-tile // 2)
    tile_yx = (min(tile, image[0]), min(tile, image[1]))
    chunk = list(lattice)
    while 4 * np.prod(tile_yx) * np.prod(chunk) > chunk_bytes and max(chunk) > 1:
        axis = int(np.argmax(chunk))
        chunk[axis] = -(-chunk[axis] // 2)
    return TilePlan(image=tuple(image), lattice=tuple(lattice), tile=tile_yx,
                    lattice_chunk=tuple(chunk))


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
