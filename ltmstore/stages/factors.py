"""The factored form's stored layout, and its writing tile by tile during a reconstruction
(``ltm reconstruct --form factored``: no dense LTM, no light-major copy).

Each tile's solver factors its LTFs (:func:`ltmstore.core.factored.factor_tile`) and writes
them into staging variables of one chunk row per tile, padded to the tile's full rank
(``{name}_tile_weights``, ``{name}_tile_basis``; only the rank chunks it uses are written).
Once every tile is solved, :func:`gather` copies them at the largest rank used into the layout
``ltm compact --form factored`` writes (:func:`create`), checks that every tile is there, and
removes the staging variables.
"""

from __future__ import annotations

import math

import numpy as np
import zarr

from ltmstore.core import checksum, factored
from ltmstore.core import store as st
from ltmstore.core.errors import LtmError

FORMS = ("dense", "factored")  # the stored forms of an LTM (ltm reconstruct / compact --form)
RANK_CHUNK = 64  # rank per staging chunk: a tile writes (and gather reads) only those it uses


def staging_names(name: str) -> tuple[str, str]:
    """The staging weights and basis of the LTM variable ``name``."""
    return f"{name}{factored.TILE_WEIGHTS}", f"{name}{factored.TILE_BASIS}"


def create(group: zarr.Group, name: str, image: tuple[int, int], lattice: tuple[int, int],
           lattice_chunk: tuple[int, int], dtype, tile: int, rank: int,
           attrs: dict | None = None) -> tuple[zarr.Array, zarr.Array]:
    """Create ``{name}_weights`` and ``{name}_basis`` (blocks of whole tiles; the basis in
    chunks of the dense LTM's lattice chunk, sharded by block)."""
    ny, nx = image
    ty, tx = -(-ny // tile), -(-nx // tile)
    block = (min(factored.BLOCK_TILES, ty), min(factored.BLOCK_TILES, tx))
    rank_dim = factored.rank_dim(name)
    attrs = {**(attrs or {}), "factored_form_of": name, "tile": tile}
    weights = st.create_variable(
        group, factored.weights_name(name), ("y", "x", rank_dim), (ny, nx, rank),
        chunks=(block[0] * tile, block[1] * tile, rank), dtype=dtype, fill_value=0,
        compressors=checksum.FAST_COMPRESSORS, attrs=attrs)
    basis = st.create_variable(
        group, factored.basis_name(name), (*factored.TILE_DIMS, rank_dim, "r", "s"),
        (ty, tx, rank, *lattice), chunks=(*block, rank, *lattice_chunk),
        shards=(*block, rank, *(-(-n // c) * c for n, c in zip(lattice, lattice_chunk,
                                                               strict=True))),
        dtype=dtype, fill_value=0, compressors=checksum.FAST_COMPRESSORS, attrs=attrs)
    return weights, basis


def create_staging(group: zarr.Group, name: str, image: tuple[int, int],
                   lattice: tuple[int, int], tile: tuple[int, int]) -> None:
    """Create the staging variables of ``name``: room for every tile's full rank."""
    full = min(math.prod(tile), math.prod(lattice))
    grid = tuple(-(-n // t) for n, t in zip(image, tile, strict=True))
    chunk = min(RANK_CHUNK, full)
    weights, basis = staging_names(name)
    st.create_variable(group, weights, ("y", "x", "tile_rank"), (*image, full),
                       chunks=(*tile, chunk), fill_value=0,
                       compressors=checksum.FAST_COMPRESSORS)
    st.create_variable(group, basis, ("tile_y", "tile_x", "tile_rank", "r", "s"),
                       (*grid, full, *lattice), chunks=(1, 1, chunk, *lattice), fill_value=0,
                       compressors=checksum.FAST_COMPRESSORS)


def write_tile(staging: tuple[zarr.Array, zarr.Array], where: tuple[slice, slice],
               index: tuple[int, int], weights: np.ndarray, basis: np.ndarray) -> None:
    """Write one tile's factors (``weights (h, w, k)``, ``basis (k, r, s)``) into its staging
    rows, up to its rank (zero, the fill value, beyond it); no other tile shares their chunks."""
    stage_w, stage_b = staging
    k = weights.shape[2]
    stage_w[(*where, slice(0, k))] = weights
    stage_b[(*index, slice(0, k))] = basis


def gather(group: zarr.Group, name: str, tile: tuple[int, int],
           lattice_chunk: tuple[int, int], rank: int) -> None:
    """Copy the staging factors of ``name`` at ``rank`` into the stored layout (:func:`create`)
    block by block, refusing a tile that never wrote its factors; remove the staging.

    Raises
    ------
    LtmError
        Naming the first tile whose factors are missing (the reconstruct stage stays
        incomplete).
    """
    stage_w, stage_b = (group[n] for n in staging_names(name))
    ny, nx, _ = stage_w.shape
    side = tile[0]
    weights, basis = create(group, name, (ny, nx), stage_b.shape[3:], lattice_chunk,
                            np.float32, side, rank)
    by, bx = (c // side for c in weights.chunks[:2])
    for ty0 in range(0, stage_b.shape[0], by):
        for tx0 in range(0, stage_b.shape[1], bx):
            rows = slice(ty0 * side, min((ty0 + by) * side, ny))
            cols = slice(tx0 * side, min((tx0 + bx) * side, nx))
            w = stage_w[rows, cols, :rank]
            _check_every_tile(w, side, (ty0, tx0), name, group)
            weights[rows, cols] = w
            basis[ty0:ty0 + by, tx0:tx0 + bx] = stage_b[ty0:ty0 + by, tx0:tx0 + bx, :rank]
    for staged in staging_names(name):
        del group[staged]


def _check_every_tile(w: np.ndarray, side: int, corner: tuple[int, int], name: str,
                      group: zarr.Group) -> None:
    """A tile's weights are orthonormal columns: all zero means the tile was never written."""
    h, wd = w.shape[:2]
    present = np.zeros((-(-h // side), -(-wd // side)), bool)
    for i, j in np.ndindex(present.shape):
        present[i, j] = np.any(w[i * side:(i + 1) * side, j * side:(j + 1) * side, 0])
    if not present.all():
        i, j = np.argwhere(~present)[0]
        where = str(getattr(group.store, "root", group.store))
        raise LtmError(f"store {where!r}: the factors of {name} are missing in "
                       f"{int((~present).sum())} tiles (first tile {corner[0] + i}, "
                       f"{corner[1] + j}); the reconstruct stage stays incomplete")
