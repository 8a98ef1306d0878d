"""The factored form's stored layout, and its writing tile by tile during a reconstruction
(``ltm reconstruct --form factored``: no dense LTM, no light-major copy).

Each tile's solver factors its LTFs (:func:`ltmstore.core.factored.factor_tile`) and writes
them into staging variables of one chunk row per tile, padded to the tile's full rank
(``{name}_tile_weights``, ``{name}_tile_basis``; only the rank chunks it uses are written).
Once every tile is solved, :func:`gather` packs them, each tile at its own rank, into the
layout ``ltm compact --form factored`` writes (:func:`create`, :class:`PackedWriter`), checks that
every tile is there, and removes the staging variables.
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


def create(group: zarr.Group, name: str, ranks: np.ndarray, image: tuple[int, int],
           lattice: tuple[int, int], lattice_chunk: tuple[int, int], dtype, tile: int,
           attrs: dict | None = None) -> tuple[zarr.Array, zarr.Array, factored.Packing]:
    """Create the packed factors of ``name`` (:mod:`ltmstore.core.factored`) for tiles of
    ``ranks``, and write the ranks: the weights in chunks of ``WEIGHT_CHUNK``, the basis in
    chunks of ``ROW_CHUNK`` rows of one cell (a point light reads its few cells), sharded by
    rows (one file holds every cell)."""
    packing = factored.Packing(ranks, image, tile)
    weight_dim, row_dim = factored.packed_dims(name)
    layout = (name, tile, [int(n) for n in image], [int(c) for c in lattice_chunk])
    attrs = {**(attrs or {}), **dict(zip(factored.LAYOUT_ATTRS, layout, strict=True))}
    stored = st.create_variable(group, factored.ranks_name(name), factored.TILE_DIMS,
                                packing.ranks.shape, chunks=packing.ranks.shape,
                                dtype=np.int32, fill_value=0)
    stored[:] = packing.ranks.astype(np.int32)
    rows = min(factored.ROW_CHUNK, packing.n_rows)
    weights = st.create_variable(
        group, factored.weights_name(name), (weight_dim,), (packing.n_weights,),
        chunks=(min(factored.WEIGHT_CHUNK, packing.n_weights),), dtype=dtype, fill_value=0,
        compressors=checksum.FAST_COMPRESSORS, attrs=attrs)
    basis = st.create_variable(
        group, factored.basis_name(name), (row_dim, "r", "s"), (packing.n_rows, *lattice),
        chunks=(rows, 1, 1), shards=(rows, *lattice), dtype=dtype, fill_value=0,
        compressors=checksum.FAST_COMPRESSORS, attrs=attrs)
    return weights, basis, packing


class PackedWriter:
    """Writes the packed factors block after block, in packed order, in whole stored chunks
    (shards): a block's range ends inside a chunk, whose rest the next block writes, and a
    chunk written twice would be read back, decoded and encoded again each time."""

    def __init__(self, weights: zarr.Array, basis: zarr.Array, packing: factored.Packing
                 ) -> None:
        self.packing = packing
        self.arrays = (weights, basis)
        self.pending: tuple[list, list] = ([], [])
        self.start = [0, 0]

    def write(self, tiles: tuple[slice, slice],
              parts: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]) -> None:
        """Add the factors of one block's ``tiles`` (``parts[i, j] = (weights (h, w, k), basis
        (k, r, s))`` of tile ``i, j``; tiles of other blocks are left alone), the block after
        the last one written."""
        span = self.packing.span(tiles)
        for n, values in enumerate(factored.pack(self.packing, tiles, parts)):
            if span[n].start != self.start[n] + sum(len(v) for v in self.pending[n]):
                raise ValueError(f"tiles {tiles}: blocks are written in packed order")
            self.pending[n].append(values)
        self._flush(whole=True)

    def close(self) -> None:
        """Write what is left (the last, partial chunk)."""
        self._flush(whole=False)

    def _flush(self, whole: bool) -> None:
        for n, array in enumerate(self.arrays):
            if not self.pending[n]:
                continue
            values = np.concatenate(self.pending[n])
            step = (array.shards or array.chunks)[0]
            stop = len(values) // step * step if whole else len(values)
            if stop:
                array[self.start[n]:self.start[n] + stop] = values[:stop].astype(array.dtype)
            self.pending[n][:] = [values[stop:]] if stop < len(values) else []
            self.start[n] += stop


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
           lattice_chunk: tuple[int, int], ranks: np.ndarray) -> None:
    """Pack the staging factors of ``name``, each tile at its rank in ``ranks``, into the
    stored layout (:func:`create`) block by block, refusing a tile that never wrote its
    factors; remove the staging.

    Raises
    ------
    LtmError
        Naming the first tile whose factors are missing (the reconstruct stage stays
        incomplete).
    """
    stage_w, stage_b = (group[n] for n in staging_names(name))
    ny, nx, _ = stage_w.shape
    side = tile[0]
    writer = PackedWriter(*create(group, name, ranks, (ny, nx), stage_b.shape[3:],
                                  lattice_chunk, np.float32, side))
    packing = writer.packing
    for tiles in packing.blocks():
        rows, cols = packing.pixels(tiles)
        i0, j0 = tiles[0].start, tiles[1].start
        top = int(packing.ranks[tiles].max())
        w = stage_w[rows, cols, :top]
        _check_every_tile(w, side, (i0, j0), name, group)
        b = stage_b[tiles[0], tiles[1], :top]
        parts = {(i, j): (w[(i - i0) * side:(i - i0 + 1) * side,
                            (j - j0) * side:(j - j0 + 1) * side, :packing.ranks[i, j]],
                          b[i - i0, j - j0, :packing.ranks[i, j]])
                 for i in range(i0, tiles[0].stop) for j in range(j0, tiles[1].stop)}
        writer.write(tiles, parts)
    writer.close()
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
