"""The reconstruct stage: resample the frames onto a lattice, then solve every pixel tile.

Plan, then execute: a frozen :class:`TilePlan` fixes the pixel tiles (the solver's unit and the
Zarr shard of ``ltm``) and the inner chunks that split the lattice, before any work is done.
Tiles run as Dask tasks on whatever cluster is given; each reads its samples from the store,
solves, and writes its own shard, so a tile is the unit of progress and of failure.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass

import dask.array as da
import numpy as np
import zarr
from distributed import Client, as_completed
from tqdm.auto import tqdm

from ltmstore import store as st
from ltmstore.cluster import dask_client
from ltmstore.confidence import expected_error, flag_unsupported
from ltmstore.dims import (
    CHROMA_CHANNELS,
    CHROMA_LTM,
    CHROMA_SAMPLES,
    COUNT,
    EXPECTED_ERROR,
    FRAME_CHROMA,
    LTM,
    SAMPLES,
    UNSUPPORTED,
    Lattice,
    Plane,
)
from ltmstore.errors import LtmError
from ltmstore.resample import Binning, bin_frames, bin_positions, path_length
from ltmstore.solve import DEFAULT_METHOD, Geometry, get_method
from ltmstore.solve.select import Choice, choose_params

TARGET_RATIO = 0.29  # the paper's sampling ratio; the automatic lattice aims at it


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
    def n_tiles(self) -> int:
        return int(np.prod([-(-n // t) for n, t in zip(self.image, self.tile, strict=True)]))


def plan_tiles(image: tuple[int, int], lattice: tuple[int, ...], *, tile: int = 32,
               chunk_bytes: int = 64 * 1024) -> TilePlan:
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


def _solve_tile(samples: np.ndarray, *, out: dict[str, zarr.Array], method: str, params: dict,
                geometry: Geometry, auto: bool, block_info=None) -> np.ndarray:
    """Solve one pixel tile and write its ``ltm`` shard and confidence maps.

    Returns ``[[record]]``: seconds, the parameters used and the held-out errors behind them.
    """
    start = time.perf_counter()
    (y0, y1), (x0, x1) = block_info[0]["array-location"][:2]
    batch = samples.reshape(-1, *samples.shape[2:])
    choice = (choose_params(batch, geometry, method, params=params, seed=y0 * 65536 + x0)
              if auto else Choice(params=params, errors={}))
    estimate = get_method(method)(batch, geometry, **choice.params)
    tile = samples.shape[:2]
    if EXPECTED_ERROR in out:  # the luminance pass also maps the confidence
        out[UNSUPPORTED][y0:y1, x0:x1] = flag_unsupported(batch, geometry).reshape(tile)
        out[EXPECTED_ERROR][y0:y1, x0:x1] = expected_error(
            batch, geometry, method, params=choice.params, folds=1).reshape(tile)
    out[LTM][y0:y1, x0:x1] = estimate.reshape(samples.shape)
    record = {"seconds": time.perf_counter() - start, "params": choice.params,
              "heldout": choice.errors}
    result = np.empty((1, 1), dtype=object)
    result[0, 0] = record
    return result


def _write_lattice(group: zarr.Group, binning: Binning) -> None:
    lattice = binning.lattice
    for name, values in lattice.coords().items():
        st.write_coord(group, name, values)
    count = st.create_variable(group, COUNT, lattice.dims, lattice.shape, chunks=lattice.shape,
                               dtype=np.int32, fill_value=0)
    count[...] = binning.count


def _write_samples(group: zarr.Group, name: str, frames: da.Array, binning: Binning,
                   plan: TilePlan, client: Client) -> zarr.Array:
    lattice = binning.lattice
    samples = st.create_variable(group, name, ("y", "x", *lattice.dims),
                                 (*plan.image, *lattice.shape), chunks=plan.block)
    binned = bin_frames(frames, binning, tile=plan.tile).rechunk(plan.block, method="tasks")
    client.compute(da.store(binned, samples, lock=False, compute=False)).result()
    return samples


def reconstruct(path, *, client: Client | None = None, scheduler: str | None = None,
                lattice: tuple[int, int] | None = None, delta_rs: float | None = None,
                method: str = DEFAULT_METHOD, params: dict | None = None, auto: bool = True,
                color: bool | None = None, tile: int = 32, overwrite: bool = False,
                progress: bool = True) -> dict:
    """Resample and reconstruct the LTM of an ingested store, in place.

    Parameters
    ----------
    path : path-like
        The store (after ``ltm ingest``).
    client : distributed.Client, optional
        The Dask cluster that runs the tiles; without it one is started for the run
        (:func:`ltmstore.cluster.dask_client` with ``scheduler``) once the inputs are checked.
    scheduler : str, optional
        Address of an existing Dask scheduler (used when no ``client`` is given).
    lattice, delta_rs : optional
        ``(R, S)`` cells, or the cell size; neither: :func:`choose_lattice`.
    method : str
        A name from :data:`ltmstore.solve.METHODS`.
    params : dict, optional
        Keyword arguments of the method.
    auto : bool
        Choose the method's regularisation per tile by held-out error
        (:mod:`ltmstore.solve.select`); parameters given in ``params`` stay fixed.
    color : bool, optional
        Also reconstruct Cb and Cr LTMs (``ltm_cb``, ``ltm_cr``: a colour LTM). Default: when
        ingest found that the chroma varies with the light (``stages.ingest.chroma``).
    tile : int
        Pixel tile side: the unit of work and the ``ltm`` shard.
    overwrite : bool
        Recompute an existing ``ltm``.

    Returns
    -------
    dict
        What was done: lattice, K/M, path density, timings.
    """
    if lattice is not None and delta_rs is not None:
        raise LtmError("give either --lattice or --delta-rs, not both")
    if int(tile) != tile or tile < 1:
        raise LtmError(f"--tile {tile!r} must be a positive whole number of pixels")
    get_method(method)
    group = st.open_group(path, mode="r+")
    st.require_stage(group, "ingest", path)
    if st.stages(group).get("reconstruct", {}).get("complete") and not overwrite:
        raise LtmError(f"store {str(path)!r} already has an ltm; pass --overwrite to recompute it")
    if color is None:
        color = not st.stages(group)["ingest"].get("chroma", {}).get("invariant", True)
    if color and FRAME_CHROMA not in group:
        raise LtmError(f"store {str(path)!r} has no per-frame chroma for a colour LTM; "
                       "ingest it again with this version")
    run = dict(lattice=lattice, delta_rs=delta_rs, method=method, params=dict(params or {}),
               auto=auto, color=color, tile=tile, progress=progress)
    if client is not None:
        return _reconstruct(group, client, **run)
    with dask_client(scheduler) as own:
        return _reconstruct(group, own, **run)


def _pick_lattice(plane: Plane, r, s, valid, lattice, delta_rs) -> tuple[Lattice, str]:
    if lattice is not None:
        return Lattice.from_plane(plane, lattice), "user"
    if delta_rs is not None:
        return Lattice.from_delta(plane, delta_rs), "user"
    return choose_lattice(plane, r, s, valid), "automatic"


def _reconstruct(group: zarr.Group, client: Client, *, lattice, delta_rs, method: str,
                 params: dict, auto: bool, color: bool, tile: int, progress: bool) -> dict:
    plane = Plane.from_json(group.attrs["acquisition"]["plane"])
    r, s, valid = group["pose_r"][:], group["pose_s"][:], group["pose_valid"][:]
    timings = {}
    start = time.perf_counter()
    lat, chosen = _pick_lattice(plane, r, s, valid, lattice, delta_rs)
    binning = bin_positions(lat, (r, s), valid)
    if binning.k == 0:
        raise LtmError(f"no valid frame falls on the {lat.shape} lattice")
    frames = da.from_zarr(group["frames"])
    plan = plan_tiles(frames.shape[1:], lat.shape, tile=tile)

    st.begin_stage(group, "resample")
    st.begin_stage(group, "reconstruct")
    for name in (*st.STAGE_VARIABLES["resample"], *st.STAGE_VARIABLES["reconstruct"]):
        if name in group:  # an earlier run's output, possibly on another lattice
            del group[name]
    _write_lattice(group, binning)
    samples = _write_samples(group, SAMPLES, frames, binning, plan, client)
    channels = {}
    if color:
        chroma = da.from_zarr(group[FRAME_CHROMA])
        channels = {c: _write_samples(group, CHROMA_SAMPLES[c], chroma[i], binning, plan, client)
                    for i, c in enumerate(CHROMA_CHANNELS)}
    density = path_length(r, s, valid=valid) / plane.area
    sampling = {"lattice": lat.to_json(), "lattice_choice": chosen, "K": binning.k,
                "M": binning.m, "sampling_ratio": binning.ratio, "path_density": density}
    st.complete_stage(group, "resample", {
        **sampling, "frames_used": int((binning.cell >= 0).sum())})
    timings["resample_s"] = time.perf_counter() - start

    start = time.perf_counter()
    out = {LTM: st.create_variable(group, LTM, ("y", "x", *lat.dims), (*plan.image, *lat.shape),
                                   chunks=plan.chunks, shards=plan.shards),
           EXPECTED_ERROR: st.create_variable(group, EXPECTED_ERROR, ("y", "x"), plan.image,
                                              chunks=plan.tile),
           UNSUPPORTED: st.create_variable(group, UNSUPPORTED, ("y", "x"), plan.image,
                                           chunks=plan.tile, dtype=bool, fill_value=True)}
    geometry = Geometry(lattice=lat, height=plane.height)
    records = _solve_tiles(samples, out, plan, geometry, method, params, auto, client, progress)
    for c, chroma_samples in channels.items():  # the colour LTM: same method, default params
        chroma_out = {LTM: st.create_variable(group, CHROMA_LTM[c], ("y", "x", *lat.dims),
                                              (*plan.image, *lat.shape), chunks=plan.chunks,
                                              shards=plan.shards)}
        _solve_tiles(chroma_samples, chroma_out, plan, geometry, method, params, False, client,
                     progress)
    timings["solve_s"] = time.perf_counter() - start
    info = {**sampling, "method": method, "params": params, "auto": auto, "color": color,
            "chosen_per_tile": summarise_choices(records), "plan": asdict(plan),
            "timings": timings,
            "seconds_per_pixel": sum(r["seconds"] for r in records) / int(np.prod(plan.image))}
    st.complete_stage(group, "reconstruct", info)
    return info


def _solve_tiles(samples: zarr.Array, out: dict[str, zarr.Array], plan: TilePlan,
                 geometry: Geometry, method: str, params: dict, auto: bool, client: Client,
                 progress: bool) -> list[dict]:
    """Run one Dask task per pixel tile; return each tile's record."""
    tiles = da.from_zarr(samples, chunks=plan.block)
    records = tiles.map_blocks(_solve_tile, out=out, method=method, params=params,
                               geometry=geometry, auto=auto,
                               drop_axis=list(range(2, tiles.ndim)), chunks=(1, 1), dtype=object)
    futures = client.compute(list(records.to_delayed().ravel()))
    done = []
    with tqdm(total=len(futures), desc="reconstruct tiles", disable=not progress) as bar:
        for fut in as_completed(futures):
            done.append(fut.result().item())
            bar.update()
    return done


def summarise_choices(records: list[dict]) -> dict:
    """How many tiles chose each parameter setting."""
    counts: dict[str, int] = {}
    for rec in records:
        key = json.dumps(rec["params"], sort_keys=True)
        counts[key] = counts.get(key, 0) + 1
    return counts
