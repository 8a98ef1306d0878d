"""The reconstruct stage: resample the frames onto a lattice, then solve every pixel tile.

Plan, then execute: a frozen :class:`TilePlan` fixes the pixel tiles (the solver's unit and the
Zarr shard of ``ltm``) and the inner chunks that split the lattice, before any work is done.
Tiles run as Dask tasks on whatever cluster is given; each reads its samples from the store,
solves, and writes its own shard, so a tile is the unit of progress and of failure.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import dask.array as da
import numpy as np
import zarr
from distributed import Client, as_completed
from tqdm.auto import tqdm

from ltmstore import store as st
from ltmstore.dims import COUNT, LTM, SAMPLES, Lattice, Plane
from ltmstore.errors import LtmError
from ltmstore.resample import Binning, bin_frames, bin_positions, path_length
from ltmstore.solve import DEFAULT_METHOD, get_method

TARGET_RATIO = 0.29  # the paper's sampling ratio; the automatic lattice aims at it


@dataclass(frozen=True)
class TilePlan:
    """Pixel tiles (= ``ltm`` shards) and lattice chunks (inner chunks) of the store."""

    image: tuple[int, int]
    lattice: tuple[int, ...]
    tile: tuple[int, int]
    lattice_chunk: tuple[int, ...]

    @property
    def shards(self) -> tuple[int, ...]:
        return (*self.tile, *self.lattice)

    @property
    def chunks(self) -> tuple[int, ...]:
        return (*self.tile, *self.lattice_chunk)

    @property
    def n_tiles(self) -> int:
        return int(np.prod([-(-n // t) for n, t in zip(self.image, self.tile, strict=True)]))


def plan_tiles(image: tuple[int, int], lattice: tuple[int, ...], *, tile: int = 64,
               chunk_bytes: int = 256 * 1024) -> TilePlan:
    """Square pixel tiles of side ``tile`` and lattice chunks of about ``chunk_bytes``.

    The lattice is split evenly along every axis (powers of two) until one inner chunk of a
    tile, in float32, is no larger than ``chunk_bytes``: a point-light query then reads one or
    a few inner chunks per tile instead of the whole shard.
    """
    tile_yx = (min(tile, image[0]), min(tile, image[1]))
    chunk = list(lattice)
    while 4 * np.prod(tile_yx) * np.prod(chunk) > chunk_bytes and max(chunk) > 1:
        axis = int(np.argmax(chunk))
        chunk[axis] = -(-chunk[axis] // 2)
    return TilePlan(image=tuple(image), lattice=tuple(lattice), tile=tile_yx,
                    lattice_chunk=tuple(chunk))


def choose_lattice(plane: Plane, r: np.ndarray, s: np.ndarray, valid: np.ndarray, *,
                   target_ratio: float = TARGET_RATIO, max_cells: int = 64) -> Lattice:
    """The finest lattice whose sampling ratio ``K/M`` reaches ``target_ratio``.

    Candidate cell sizes follow the shorter plane side divided by ``n`` for ``n`` from
    ``max_cells`` down to 4; the first (finest) one the trajectory covers densely enough wins.
    """
    side = min(plane.r[1] - plane.r[0], plane.s[1] - plane.s[0])
    lattice = None
    for n in range(max_cells, 3, -1):
        lattice = Lattice.from_delta(plane, side / n)
        if bin_positions(lattice, (r, s), valid).ratio >= target_ratio:
            return lattice
    return lattice  # the coarsest candidate


def _solve_tile(samples: np.ndarray, *, out: zarr.Array, method: str, params: dict,
                ndim: int, block_info=None) -> np.ndarray:
    """Solve one pixel tile, write it to its shard, return ``[[seconds]]``."""
    start = time.perf_counter()
    (y0, y1), (x0, x1) = block_info[0]["array-location"][:2]
    batch = samples.reshape(-1, *samples.shape[2:])
    estimate = get_method(method)(batch, ndim=ndim, **params)
    out[y0:y1, x0:x1] = estimate.reshape(samples.shape)
    return np.full((1, 1), time.perf_counter() - start)


def _write_samples(group: zarr.Group, frames: da.Array, binning: Binning,
                   plan: TilePlan, client: Client) -> zarr.Array:
    lattice = binning.lattice
    for name, values in lattice.coords().items():
        st.write_coord(group, name, values)
    count = st.create_variable(group, COUNT, lattice.dims, lattice.shape, chunks=lattice.shape,
                               dtype=np.int32, fill_value=0)
    count[...] = binning.count
    samples = st.create_variable(group, SAMPLES, ("y", "x", *lattice.dims),
                                 (*plan.image, *lattice.shape), chunks=plan.shards)
    binned = bin_frames(frames, binning).rechunk(plan.shards)
    client.compute(da.store(binned, samples, lock=False, compute=False)).result()
    return samples


def reconstruct(path, *, client: Client, lattice: tuple[int, int] | None = None,
                delta_rs: float | None = None, method: str = DEFAULT_METHOD,
                params: dict | None = None, tile: int = 64, overwrite: bool = False,
                progress: bool = True) -> dict:
    """Resample and reconstruct the LTM of an ingested store, in place.

    Parameters
    ----------
    path : path-like
        The store (after ``ltm ingest``).
    client : distributed.Client
        The Dask cluster that runs the tiles.
    lattice, delta_rs : optional
        ``(R, S)`` cells, or the cell size; neither: :func:`choose_lattice`.
    method : str
        A name from :data:`ltmstore.solve.METHODS`.
    params : dict, optional
        Keyword arguments of the method.

    Returns
    -------
    dict
        What was done: lattice, K/M, path density, timings.
    """
    if lattice is not None and delta_rs is not None:
        raise LtmError("give either --lattice or --delta-rs, not both")
    get_method(method)
    params = dict(params or {})
    group = st.open_group(path, mode="r+")
    acq = st.require_stage(group, "ingest", path)
    if st.stages(group).get("reconstruct", {}).get("complete") and not overwrite:
        raise LtmError(f"store {str(path)!r} already has an ltm; pass --overwrite to recompute it")
    plane = Plane.from_json(group.attrs["acquisition"]["plane"])
    r, s = group["pose_r"][:], group["pose_s"][:]
    valid = group["pose_valid"][:]

    timings = {}
    start = time.perf_counter()
    chosen = "automatic" if lattice is None and delta_rs is None else "user"
    if lattice is not None:
        lat = Lattice.from_plane(plane, lattice)
    elif delta_rs is not None:
        lat = Lattice.from_delta(plane, delta_rs)
    else:
        lat = choose_lattice(plane, r, s, valid)
    binning = bin_positions(lat, (r, s), valid)
    if binning.k == 0:
        raise LtmError(f"no valid frame falls on the {lat.shape} lattice")
    frames_arr = group["frames"]
    frames = da.from_zarr(frames_arr)
    plan = plan_tiles(frames.shape[1:], lat.shape, tile=tile)

    st.begin_stage(group, "resample")
    st.begin_stage(group, "reconstruct")
    samples = _write_samples(group, frames, binning, plan, client)
    density = path_length(r, s, valid=valid) / plane.area
    st.complete_stage(group, "resample", {
        "lattice": lat.to_json(), "lattice_choice": chosen, "K": binning.k, "M": binning.m,
        "sampling_ratio": binning.ratio, "path_density": density,
        "frames_used": int((binning.cell >= 0).sum())})
    timings["resample_s"] = time.perf_counter() - start

    start = time.perf_counter()
    out = st.create_variable(group, LTM, ("y", "x", *lat.dims), (*plan.image, *lat.shape),
                             chunks=plan.chunks, shards=plan.shards)
    tiles = da.from_zarr(samples, chunks=plan.shards)
    seconds = tiles.map_blocks(_solve_tile, out=out, method=method, params=params,
                               ndim=len(lat.shape), drop_axis=list(range(2, tiles.ndim)),
                               chunks=(1, 1), dtype=float)
    futures = client.compute(list(seconds.to_delayed().ravel()))
    tile_seconds = []
    with tqdm(total=len(futures), desc="reconstruct tiles", disable=not progress) as bar:
        for fut in as_completed(futures):
            tile_seconds.append(float(fut.result().item()))
            bar.update()
    timings["solve_s"] = time.perf_counter() - start
    n_pixels = int(np.prod(plan.image))
    info = {
        "method": method, "params": params, "plan": asdict(plan), "lattice": lat.to_json(),
        "K": binning.k, "M": binning.m, "sampling_ratio": binning.ratio,
        "path_density": density, "timings": timings,
        "seconds_per_pixel": sum(tile_seconds) / n_pixels,
        "acquisition_sha256": acq.get("sha256"),
    }
    st.complete_stage(group, "reconstruct", info)
    return info
