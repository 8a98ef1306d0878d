"""The reconstruct stage: resample the frames onto a lattice, then solve every pixel tile.

Plan, then execute: a frozen :class:`TilePlan` fixes the pixel tiles (the solver's unit and the
Zarr shard of ``ltm``) and the inner chunks that split the lattice, before any work is done.
Resampling runs one Dask task per square region of whole tiles, reading its frames from the
store and writing its samples (:func:`resample_regions`); then up to 2 x 2 neighbouring tiles
run per task (:func:`tile_groups`), on whatever cluster is given: each tile reads its samples
from the store, solves, writes its own shard and then its done-mark, so a tile is the unit of
progress and of failure, and a task lasts about a second or more. In the
factored form (``form="factored"``) a tile writes its factors instead (:mod:`.factors`),
gathered into the stored layout once every tile is solved.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from dataclasses import asdict, dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import zarr
from tqdm.auto import tqdm

from ltmstore.core import checksum, factored, memory
from ltmstore.core import store as st
from ltmstore.core.binning import cell_means, revisited, segments
from ltmstore.core.dims import (
    CHROMA_CHANNELS,
    CHROMA_LTM,
    CHROMA_SAMPLES,
    COUNT,
    EXPECTED_ERROR,
    FRAME_CHROMA,
    LTM,
    OBSERVATION_DTYPE,
    POSE_AXIS,
    SAMPLES,
    UNSUPPORTED,
    Lattice,
    Plane,
    object_pixels,
)
from ltmstore.core.errors import LtmError, LtmWarning
from ltmstore.core.lights import DISK, FAR, light_kind
from ltmstore.solve import DEFAULT_METHOD, Geometry, get_method
from ltmstore.solve.select import (
    AUTO,
    AUTO_LABELS,
    Choice,
    MethodChoice,
    choose_method,
    choose_params,
    finalists,
)
from ltmstore.stages import factors
from ltmstore.stages import surface as sf
from ltmstore.stages.by_light import write_by_light
from ltmstore.stages.factors import FORMS
from ltmstore.stages.plan import (
    TilePlan,
    check_fits,
    choose_form,
    plan_tiles,
    size_text,
    write_method_map,
)
from ltmstore.stages.resample import (
    Binning,
    bin_frames,
    bin_positions,
    lattice_6d,
    path_length,
    region_side,
    resample_region,
    view_positions,
)

if TYPE_CHECKING:  # Dask loads where a near-light run needs it: a far-light run never does
    from collections.abc import Callable

    from distributed import Client

TILES = "tiles"  # key of the tile completion marks in a tile's outputs
FACTORS = "factors"  # key of the staging factors in a tile's outputs (the factored form)
# auto chooses once per image (choose_for_image) from this many pixels of this many tiles
IMAGE_PIXELS = 256
IMAGE_TILES = 16
TARGET_RATIO = 0.29  # the paper's sampling ratio; the automatic lattice aims at it
# A lattice given by the user that leaves K/M below this is refused unless forced: the solve
# grows with M while all but a few cells are guessed (1000 x 1000 on a test capture: K/M 0.0003).
MIN_RATIO = 0.02
# The held-out choice of a regularisation (the surface model's residual weight) hides the cells
# of whole seconds of a handheld video together: a phone's codec puts a key frame about every
# second, and cells a second of the path took share its errors.
SEGMENT_S = 1.0
# ... where the path passed beside most of its cells in another second
# (ltmstore.core.binning.revisited); where its passes lie apart, a hidden second has no other
# pass near it and the residual's value cannot show: the cells are hidden one by one. On the
# 720 px simulated canvas and relief, 16 x 16 lattice: 0.85 of the cells filmed for 20 s (path
# density 32), where whole seconds hidden (and the model alone the default) relit 0.9-1.5 dB
# above single cells; 0.37 filmed for 5 s (path density 8), where they relit 0.3-0.9 dB below;
# the tests' 32 px relief filmed 8.7 s at path density 14: 0.55, the model alone 0.7 dB below.
MIN_REVISITED = 0.7
# A pixel's light transport is capped at this many times the brightest it was seen: a model may
# put a highlight where no frame came near, but not one the data cannot bound. On 720 px
# simulated captures the truth's peak over all cells was at most 2.8 (relief) and 8.6 (canvas,
# its varnish) times the pixel's brightest sample; a relief's physical fit with a lobe of
# roughness 0.025 fitted to a highlight's flank put 145 times it in an unobserved cell (SNR_Y
# 2.2 dB over the whole image).
EXTRAPOLATION_CAP = 10.0


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


def _solve_tiles_task(tiles: list[tuple[int, int]], *, source: zarr.Array, plan: TilePlan,
                      **solve) -> list[dict]:
    """One Dask task: read the samples of each tile of ``tiles`` from ``source``, solve it and
    write it (:func:`_solve_tile`, keyword arguments ``solve``); their records."""
    records = []
    for ty, tx in tiles:
        (y0, y1), (x0, x1) = plan_rows(plan, ty, tx)
        samples = np.asarray(source[y0:y1, x0:x1], dtype=np.float32)
        records.append(_solve_tile(samples, (ty, tx), (y0, x0), plan.image, **solve))
    return records


def _solve_tile(samples: np.ndarray, index: tuple[int, int], origin: tuple[int, int],
                image: tuple[int, int], *, out: dict[str, zarr.Array], method: str,
                params: dict, geometry: Geometry, auto: bool, extent: dict | None = None,
                chosen: ImageChoice | None = None,
                fractions: np.ndarray | None = None) -> dict:
    """Solve one pixel tile (number ``index``, first pixel ``origin`` of an ``image``) and
    write its ``ltm`` shard (or its factors) and confidence maps; ``extent`` (the acquisition's
    ``object``) places the tile's pixels on the object plane; ``chosen``: the finalists of
    ``auto`` for the whole image (:func:`choose_for_image`), that the tile chooses between
    (None: ``method`` is ``auto``'s whole choice, or a named method); ``fractions``: per tile,
    the fraction of its energy a colour LTM's factors may leave out (the luminance's, from its
    held-out error).

    Returns its record: seconds, the parameters used and the held-out errors behind them.
    """
    from ltmstore.solve.confidence import expected_error, flag_unsupported  # SciPy: here
    from ltmstore.solve.validate import observed_range

    start = time.perf_counter()
    (y0, x0), tile = origin, samples.shape[:2]
    y1, x1 = y0 + tile[0], x0 + tile[1]
    batch = samples.reshape(-1, *samples.shape[2:])
    seed = y0 * 65536 + x0
    if extent is not None:
        geometry = geometry.with_pixels(object_pixels(extent, image, slice(y0, y1),
                                                      slice(x0, x1)))
    label, method_error = method, None
    if chosen is not None:  # the finalists meet in each tile; its regularisation too
        label, method, params, method_error = chosen.pick(batch, geometry, seed=seed)
        choice = (choose_params(batch, geometry, method, params=params, seed=seed)
                  if auto else Choice(params=params, errors={}))
    else:
        if method == AUTO:  # the method and model size first, then its regularisation
            picked = choose_method(batch, geometry, seed=seed)
            label, method, params = picked.label, picked.method, {**picked.params}
            method_error = picked.errors.get(label)
        choice = (choose_params(batch, geometry, method, params=params, seed=seed)
                  if auto else Choice(params=params, errors={}))
    surface, warm = None, None
    if method == "physical":  # the surface's maps, and the start of the held-out fold's fit
        from ltmstore.solve import physical

        estimate, surface = physical.solve_surface(batch, geometry, **choice.params)
        warm = {"start": physical.parameters(surface)}
    else:
        estimate = get_method(method)(batch, geometry, **choice.params)
    ty, tx = index
    _check_finite(estimate, batch, ty, tx)
    if sf.NORMAL in out:  # every chunk is written: NaN where the tile chose another method
        _write_surface_tile(out, surface, (slice(y0, y1), slice(x0, x1)), tile)
    error = None
    if EXPECTED_ERROR in out:  # the luminance pass also maps the confidence
        estimate = capped(np.maximum(estimate, 0), batch)  # never negative (Cb, Cr may be)
        out[UNSUPPORTED][y0:y1, x0:x1] = flag_unsupported(batch, geometry).reshape(tile)
        error = expected_error(batch, geometry, method, params=choice.params, folds=1,
                               per_pixel=warm)
        out[EXPECTED_ERROR][y0:y1, x0:x1] = error.reshape(tile)
    record = {"method": label, "tile": [int(ty), int(tx)], "params": choice.params,
              "heldout": choice.errors, "method_error": method_error}
    where = (slice(y0, y1), slice(x0, x1))
    if FACTORS in out:
        values = estimate.reshape(samples.shape)
        if not np.isfinite(values).all():
            raise LtmError(f"the solution of tile {ty}, {tx} is not finite everywhere: the "
                           "factored form needs a finite ltm; nothing of it was written")
        if error is None:  # a colour LTM leaves out the fraction its tile's luminance did
            w, b = factored.factor_tile(values, fractions[ty, tx] * factored.energy(values))
        else:
            w, b = factored.factor_tile(values, threshold=factored.heldout_threshold(
                error * observed_range(batch), int(np.prod(samples.shape[2:]))))
        factors.write_tile(out[FACTORS], where, (ty, tx), w, b)
        record.update(rank=int(w.shape[2]), fraction=factored.left_out(values, b))
    else:
        out[LTM][where] = estimate.reshape(samples.shape)
    record["seconds"] = time.perf_counter() - start
    out[TILES][ty, tx] = json.dumps(record, default=float)  # the tile is done: written last
    memory.trim()  # the tile's temporaries leave the worker's heap
    return record


def capped(estimate: np.ndarray, batch: np.ndarray) -> np.ndarray:
    """``estimate`` at most :data:`EXTRAPOLATION_CAP` times each pixel's brightest observed
    sample (rows of ``batch``; a pixel observed nowhere is left as it is)."""
    flat = batch.reshape(len(batch), -1)
    seen = np.isfinite(flat).any(axis=1)
    ceiling = np.full(len(batch), np.inf, dtype=np.float32)
    ceiling[seen] = EXTRAPOLATION_CAP * np.nanmax(flat[seen], axis=1)
    return np.minimum(estimate, ceiling.reshape(-1, *([1] * (estimate.ndim - 1))))


def _check_finite(estimate: np.ndarray, batch: np.ndarray, ty: int, tx: int) -> None:
    """Refuse a tile whose solution is not finite wherever its samples are (before it is
    written: :func:`check_solved` then only needs every tile's shard to be there)."""
    bad = (np.isfinite(batch) & ~np.isfinite(estimate.reshape(batch.shape))).reshape(
        len(batch), -1).any(axis=1)
    if bad.any():
        raise LtmError(f"the solution of tile {ty}, {tx} is not finite at {int(bad.sum())} "
                       "observed pixels; nothing of it was written")


@dataclass(frozen=True)
class ImageChoice:
    """What ``auto`` chose once for a whole image (``method``) and the finalists that each
    tile chooses between (:func:`~ltmstore.solve.select.finalists`)."""

    method: MethodChoice
    labels: tuple[str, ...]

    def pick(self, batch: np.ndarray, geometry: Geometry, *,
             seed: int = 0) -> tuple[str, str, dict, float | None]:
        """A tile's label, method, fixed parameters and held-out error: the finalist with the
        lowest held-out error on the tile (:func:`~ltmstore.solve.select.choose_method` among
        ``labels``)."""
        picked = self.method
        if len(self.labels) > 1:
            picked = choose_method(batch, geometry, seed=seed, labels=self.labels)
        return picked.label, picked.method, dict(picked.params), picked.errors.get(picked.label)


def choose_for_image(samples: zarr.Array, plan: TilePlan, geometry: Geometry,
                     extent: dict | None, *, seed: int = 0) -> ImageChoice:
    """``auto``'s candidates (:func:`~ltmstore.solve.select.choose_method`) weighed once for
    the whole image, on :data:`IMAGE_PIXELS` pixels drawn from up to :data:`IMAGE_TILES`
    tiles spread over it, down to the finalists that each tile then weighs on its own pixels:
    the best interpolating method and the physical model. All candidates in every tile cost
    about a second per tile (the RBF systems, the triangulation), and the tiles chose among
    the same few (toys-size canvas, icon and relief: ``physical``, ``rbf`` and ``cs+rbf``)."""
    batch, geometry = image_sample(samples, plan, geometry, extent, seed=seed)
    picked = choose_method(batch, geometry, seed=seed, pixels=len(batch))
    return ImageChoice(method=picked,
                       labels=finalists(picked) if picked.errors else (picked.label,))


def image_sample(samples: zarr.Array, plan: TilePlan, geometry: Geometry,
                 extent: dict | None, *, seed: int = 0) -> tuple[np.ndarray, Geometry]:
    """:data:`IMAGE_PIXELS` pixels' samples ``(n, *lattice)`` drawn from up to
    :data:`IMAGE_TILES` tiles spread over the image, and their geometry (placed by
    ``extent``)."""
    rng = np.random.default_rng(seed)
    ty, tx = plan.grid
    picks = np.unique(np.linspace(0, ty * tx - 1, min(IMAGE_TILES, ty * tx)).round().astype(int))
    rows, where = [], []
    per_tile = -(-IMAGE_PIXELS // len(picks))
    for index in picks:
        (y0, y1), (x0, x1) = plan_rows(plan, *divmod(int(index), tx))
        block = np.asarray(samples[y0:y1, x0:x1], dtype=np.float32)
        flat = block.reshape(-1, *block.shape[2:])
        take = np.sort(rng.choice(len(flat), size=min(per_tile, len(flat)), replace=False))
        rows.append(flat[take])
        if extent is not None:
            where.append(object_pixels(extent, plan.image, slice(y0, y1), slice(x0, x1))[take])
    batch = np.concatenate(rows)
    if extent is not None:
        geometry = geometry.with_pixels(np.concatenate(where))
    return batch, geometry


def led_beam(group: zarr.Group, plan: TilePlan, geometry: Geometry,
             extent: dict | None) -> tuple[Geometry, dict | None]:
    """``geometry`` with the exponent of the LED's ``cos^k`` beam of a near-light capture
    placed by ``extent`` (None: no surface model, no beam), and its record: ingest's
    estimate (poses with the LED's axis, tilted: ingest records an axis held level as the
    profile's, not estimated), refined by held-out error where each cell's axis is known
    (:func:`ltmstore.stages.surface.refine_led_exponent`); else the held-out choice of
    :func:`ltmstore.stages.surface.choose_led_exponent` on a sample of the image's pixels,
    from what the axis's wobble measured (:func:`ltmstore.stages.surface.wobble_exponent`)."""
    if extent is None:
        return geometry, None
    beam = _ingest_beam(group)
    estimated = beam.get("source") == "estimated"
    if estimated and geometry.led_axis is None:
        k = float(beam["exponent"])
        return replace(geometry, led_exponent=k), {"exponent": k, "source": "ingest"}
    batch, placed = image_sample(group[SAMPLES], plan, geometry, extent)
    if estimated:
        k, record = sf.refine_led_exponent(batch, placed, float(beam["exponent"]),
                                           float(beam["stderr"]))
    else:
        k, record = sf.choose_led_exponent(batch, placed, default=sf.wobble_exponent(beam))
    return replace(geometry, led_exponent=k), record


def _ingest_beam(group: zarr.Group) -> dict:
    """Ingest's record of the LED's beam (``source``, ``exponent``...; empty where none)."""
    return st.stages(group).get("ingest", {}).get("beam") or {}


def plan_rows(plan: TilePlan, ty: int, tx: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """Pixel rows and columns ``((y0, y1), (x0, x1))`` of tile ``(ty, tx)``."""
    (h, w), (th, tw) = plan.image, plan.tile
    return (ty * th, min((ty + 1) * th, h)), (tx * tw, min((tx + 1) * tw, w))


def _write_surface_tile(out: dict[str, zarr.Array], surface, where: tuple[slice, slice],
                        tile: tuple[int, int]) -> None:
    """A tile's physical surface (:class:`ltmstore.solve.physical.Surface`, or None: NaN) into
    its maps."""
    def value(name: str, shape: tuple[int, ...]) -> np.ndarray:  # map names = Surface fields
        return np.full(shape, np.nan) if surface is None else getattr(surface, name).reshape(shape)

    out[sf.NORMAL][where] = value(sf.NORMAL, (*tile, 3))
    for name in (sf.ALBEDO, sf.SPECULAR, sf.ROUGHNESS, sf.AMBIENT):
        out[name][where] = value(name, tile)


def _create_surface_maps(group: zarr.Group, plan: TilePlan) -> None:
    """Empty (NaN) near-light surface maps: luminance albedo, lobe strength, roughness and floor
    ``(y, x)`` and the unit ``normal (y, x, component)``, filled by the tiles that choose the
    physical model."""
    st.write_coord(group, sf.COMPONENT, np.array(["x", "y", "z"]))
    st.create_variable(group, sf.NORMAL, ("y", "x", sf.COMPONENT), (*plan.image, 3),
                       chunks=(*plan.tile, 3))
    for name in (sf.ALBEDO, sf.SPECULAR, sf.ROUGHNESS, sf.AMBIENT):
        st.create_variable(group, name, ("y", "x"), plan.image, chunks=plan.tile)


def _write_lattice(group: zarr.Group, binning: Binning) -> None:
    lattice = binning.lattice
    for name, values in lattice.coords().items():
        st.write_coord(group, name, values)
    count = st.create_variable(group, COUNT, lattice.dims, lattice.shape, chunks=lattice.shape,
                               dtype=np.int32, fill_value=0)
    count[...] = binning.count


def _write_samples(group: zarr.Group, name: str, frames: zarr.Array, binning: Binning,
                   plan: TilePlan, client: Client, *, channel: int | None = None,
                   progress: bool = False) -> zarr.Array:
    """Resample the stored ``frames`` (``channel`` of them: a chroma channel) onto the lattice
    into the variable ``name``: one task per pixel region of a near-light lattice
    (:func:`~ltmstore.stages.resample.resample_region`, reading its frames from the store),
    Dask's binning of frames chunks on a 6D one."""
    lattice = binning.lattice
    samples = st.create_variable(group, name, ("y", "x", *lattice.dims),
                                 (*plan.image, *lattice.shape), chunks=plan.block,
                                 dtype=OBSERVATION_DTYPE)
    if len(lattice.shape) > 2:
        import dask.array as da

        lazy = da.from_zarr(frames)[() if channel is None else channel]
        binned = (bin_frames(lazy, binning, tile=plan.tile).rechunk(plan.block, method="tasks")
                  .astype(OBSERVATION_DTYPE))
        client.compute(da.store(binned, samples, lock=False, compute=False)).result()
        return samples
    regions = resample_regions(plan, frames.chunks[-2:], frames.shape[-3])
    # the arrays sent once, as futures: Distributed keys a keyword argument over 100 kB by its
    # name ("count"), and a fine lattice's then failed the scheduler's assertion (300 x 300)
    cells, count = client.scatter([binning.cell, binning.count.reshape(-1).astype(np.float32)],
                                  broadcast=True, hash=False)
    futures = client.map(resample_region, regions, frames=frames, samples=samples,
                         cells=cells, count=count, channel=channel, pure=False)
    _gather(futures, desc="resample regions", progress=progress)
    return samples


def resample_regions(plan: TilePlan, frames_chunk: tuple[int, int],
                     n_frames: int) -> list[tuple[slice, slice]]:
    """The pixel regions of the resample tasks: squares of whole tiles
    (:func:`~ltmstore.stages.resample.region_side`), clipped to the image."""
    side = [region_side(t, c, n_frames) for t, c in zip(plan.tile, frames_chunk, strict=True)]
    (h, w), (sy, sx) = plan.image, side
    return [(slice(y, min(y + sy, h)), slice(x, min(x + sx, w)))
            for y in range(0, h, sy) for x in range(0, w, sx)]


def _gather(futures: list, *, desc: str, progress: bool, total: int | None = None,
            size: Callable[[object], int] = lambda result: 1) -> list:
    """The futures' results in completion order, under a progress bar of ``total`` steps
    (default: one per future; ``size(result)`` steps for each); the first error is raised."""
    from distributed import as_completed

    done = []
    with tqdm(total=len(futures) if total is None else total, desc=desc,
              disable=not progress) as bar:
        for fut in as_completed(futures):
            done.append(fut.result())
            bar.update(size(done[-1]))
    return done


def reconstruct(path, *, client: Client | None = None, scheduler: str | None = None,
                lattice: tuple[int, int] | None = None, delta_rs: float | None = None,
                method: str = DEFAULT_METHOD, params: dict | None = None, auto: bool = True,
                color: bool | None = None, tile: int | None = None, overwrite: bool = False,
                resume: bool = True, force: bool = False, light_major: bool = True,
                form: str = AUTO, keep_frames: bool = False, stage: str = "all",
                progress: bool = True) -> dict:
    """Resample and reconstruct the LTM of an ingested store.

    A store without a complete ``ltm`` is written in place (an interrupted run of the same
    parameters is resumed). Recomputing a complete one (``overwrite``) builds the new ``ltm`` on
    a linked copy beside the store (:func:`ltmstore.core.store.revised_store`) and swaps it in only
    when complete: a failure leaves the previous ``ltm`` untouched, and a killed run is resumed
    by the next ``overwrite`` run of the same parameters.

    Parameters
    ----------
    path : path-like
        The store (after ``ltm ingest``).
    client : distributed.Client, optional
        The Dask cluster that runs the tiles; without it one is started for the run
        (:func:`ltmstore.core.cluster.dask_client` with ``scheduler``) once the inputs are checked.
    scheduler : str, optional
        Address of an existing Dask scheduler (used when no ``client`` is given).
    lattice, delta_rs : optional
        ``(R, S)`` cells, or the cell size; neither: :func:`choose_lattice`.
    method : str
        A name from :data:`ltmstore.solve.METHODS`. A far-light store (a classic RTI capture)
        takes ``auto``, ``ptm``, ``hsh`` or ``rbf``, fitted at the exact light directions
        (:mod:`ltmstore.stages.reconstruct_far`).
    params : dict, optional
        Keyword arguments of the method.
    auto : bool
        Choose the method's regularisation per tile by held-out error
        (:mod:`ltmstore.solve.select`); parameters given in ``params`` stay fixed.
    color : bool, optional
        Also reconstruct Cb and Cr LTMs (``ltm_cb``, ``ltm_cr``: a colour LTM). Default: when
        ingest found that the chroma varies with the light (``stages.ingest.chroma``).
    tile : int, optional
        Pixel tile side: the unit of work and the ``ltm`` shard (default 32; 64 for a far-light
        store).
    overwrite : bool
        Recompute an existing complete ``ltm``.
    resume : bool
        When an earlier run of the same parameters and software was interrupted (stage
        ``reconstruct`` incomplete, its samples complete), solve only the tiles it did not
        finish (``tiles_solved`` counts them, ``tiles_resumed`` the ones kept).
    force : bool
        Run a ``lattice`` or ``delta_rs`` whose sampling ratio ``K/M`` is below
        :data:`MIN_RATIO` (refused otherwise, naming the lattice that reaches
        :data:`TARGET_RATIO`).
    light_major : bool
        Also write the light-major copy of each LTM (:mod:`ltmstore.stages.by_light`): as many
        bytes again, and what makes relighting interactive (a point light reads 4 cells' image
        planes); ``ltm compact`` can add it later. A far-light store has none.
    form : {"auto", "dense", "factored"}
        ``factored``: each tile's solver stores its LTFs as a basis and per-pixel weights at
        the rank its held-out error supports (:mod:`ltmstore.stages.factors`, as ``ltm
        compact --form factored`` does) in place of the dense ``ltm`` and its light-major copy:
        a store of a few percent of the bytes, for captures whose dense LTM is too large.
        ``auto``: dense while it fits in half the free disk
        (:func:`~ltmstore.stages.plan.choose_form`), else factored; an interrupted run keeps
        its form; a far-light or 6-D store is dense.
    keep_frames : bool
        Keep the decoded frames where ``auto`` stored the factors for lack of disk. Without it
        they are dropped once the ``ltm`` is complete, as ``ltm compact`` drops them (at 4K,
        11 of a store's 16 GB): the disk is short, and a near-light store relights from its
        ``ltm`` alone; reconstructing again then needs a new ``ltm ingest``.
    stage : {"all", "classic"}
        A far-light store's ``auto`` and ``physical`` run in two recorded stages: the classic
        fit (``reconstruct``: complete and relightable), then the surface refinement
        (:data:`~ltmstore.stages.reconstruct_far.REFINE`), built on a linked copy and swapped
        in when complete. ``classic`` runs the first only; a later run of the same
        parameters (without ``overwrite``) finishes the second, as it finishes one that was
        interrupted.

    Returns
    -------
    dict
        What was done: lattice, K/M, path density, tiles solved and resumed, timings;
        ``frames_dropped`` where the frames were dropped: the store's bytes before and after,
        and the seconds it took (``ltm compact``'s ``compact`` record holds the rest).
    """
    if lattice is not None and delta_rs is not None:
        raise LtmError("give either --lattice or --delta-rs, not both")
    if tile is not None and (int(tile) != tile or tile < 1):
        raise LtmError(f"--tile {tile!r} must be a positive whole number of pixels")
    if form not in (AUTO, *FORMS):
        raise LtmError(f"form {form!r} must be one of {', '.join((AUTO, *FORMS))}")
    path = os.path.abspath(path)  # Dask workers resolve a relative path in their own folder
    group = st.open_group(path, mode="r")
    st.require_stage(group, "ingest", path)
    if "frames" not in group:
        raise LtmError(f"store {str(path)!r} holds no frames (`ltm compact` dropped them); "
                       "ingest the acquisition again to reconstruct it")
    far = light_kind(group.attrs.get("acquisition", {})) == FAR
    if far:  # the far-light models load only here (SciPy)
        from ltmstore.stages.reconstruct_far import far_models

        far_models(method)
        if delta_rs is not None:
            raise LtmError("--delta-rs is a cell size on a plane; a far-light store takes "
                           "--lattice RxS (cells over the disk of directions)")
    planar = not far and "pose_p" not in group  # a near-light (y, x, r, s) ltm
    if form == "factored" and not planar:
        raise LtmError(f"store {str(path)!r}: the factored form holds a near-light ltm "
                       "(y, x, r, s); expected --form dense for a far-light or 6-D store")
    if not far and method != AUTO:
        get_method(method)
    elif not far and params:
        raise LtmError(f"params {params!r} need a named method; auto chooses the method and its "
                       "parameters per tile")
    if stage not in ("all", "classic"):
        raise LtmError(f"stage {stage!r} must be one of all, classic")
    if stage != "all" and not far:
        raise LtmError(f"--stage {stage} splits the reconstruction of a classic RTI capture "
                       f"(far lights); store {str(path)!r} holds near lights")
    st.check_writable(path)
    revise = bool(st.stages(group).get("reconstruct", {}).get("complete"))
    key = run_key(lattice=lattice, delta_rs=delta_rs, method=method, params=dict(params or {}),
                  auto=auto, color=False, tile=tile)  # a far-light run's
    pending = far and revise and not overwrite and _refinement_pending(group, key)
    if revise and not overwrite and not (pending and stage == "all"):
        raise LtmError(f"store {str(path)!r} already has an ltm; pass --overwrite to recompute "
                       f"it{_pending_note(group, key) if far else ''}")
    if far:
        color = False  # relit colour comes from the frames at the fitted weights
    elif color is None:
        color = not st.stages(group)["ingest"].get("chroma", {}).get("invariant", True)
    if color and FRAME_CHROMA not in group:
        chroma = st.stages(group)["ingest"].get("chroma", {})
        why = (f"ingest found its colour illumination invariant (variation "
               f"{chroma['variation']:.3f} <= {chroma['tolerance']}) and kept none; "
               "ltm ingest --keep-chroma keeps it" if chroma.get("frames_kept") is False
               else "ingest it again with this version")
        raise LtmError(f"store {str(path)!r} has no per-frame chroma for a colour LTM; {why}")
    form_choice = None
    estimate = partial(_dense_estimate, path, group, lattice=lattice, delta_rs=delta_rs,
                       channels=3 if color else 1, light_major=light_major, tile=tile)
    if form == AUTO:
        form_choice = _choose_form(group, planar=planar, estimate=estimate)
        form = form_choice["form"]
    elif form == "dense" and planar:
        _warn_if_it_overflows(estimate())
    _check_user_lattice(path, group, lattice=lattice, delta_rs=delta_rs, far=far,
                        copies=_ltm_copies(color, light_major, form), tile=tile)
    run = dict(lattice=lattice, delta_rs=delta_rs, method=method, params=dict(params or {}),
               auto=auto, color=color, tile=tile, progress=progress, resume=resume, force=force,
               light_major=light_major and form == "dense", form=form)
    try:
        with st.writing(path):
            if far:
                info = _far_stages(path, run, revise=revise, pending=pending, stage=stage)
            elif not revise:
                info = _on_cluster(path, client, scheduler, run)
            else:  # a good ltm exists: build the new one on a linked copy, swapped in when done
                with st.revised_store(path) as side:
                    info = _on_cluster(side, client, scheduler, run)
    except OSError as exc:  # a full disk, a store made read-only during the run
        st.settle_writes()  # no write of this process lands after the error
        kept = ("the previous ltm is untouched" if revise
                else _kept_note(path) if far else "its reconstruct stage stays incomplete")
        raise LtmError(f"cannot write store {str(path)!r}: {exc.strerror or exc}; {kept}") from exc
    if form_choice and form_choice["form"] == "factored" and not keep_frames:
        info["frames_dropped"] = _drop_frames(path)
    return {**info, **({"form_choice": form_choice} if form_choice else {})}


def _drop_frames(path: str) -> dict | None:
    """``ltm compact`` of a complete factored store: its frames dropped, atomically; where
    that fails, a warning (the ``ltm`` is complete all the same) and None."""
    from ltmstore.stages.compact import compact

    try:
        done = compact(path, progress=False)
    except LtmError as exc:
        warnings.warn(f"the ltm is complete; its frames were kept: {exc}", LtmWarning,
                      stacklevel=3)
        return None
    return {k: done[k] for k in ("bytes_before", "bytes_after", "seconds")}


def _choose_form(group: zarr.Group, *, planar: bool, estimate: Callable[[], dict]) -> dict:
    """``--form auto``: the form of an interrupted run of this store (so that it resumes),
    dense for a far-light or 6-D store, else the choice of ``estimate()``
    (:func:`_dense_estimate`)."""
    stage = st.stages(group).get("reconstruct", {})
    if not stage.get("complete") and stage.get("run", {}).get("form") in FORMS:
        return {"form": stage["run"]["form"], "resumed": True}
    return estimate() if planar else {"form": "dense"}


def _dense_estimate(path: str, group: zarr.Group, *, lattice, delta_rs, channels: int,
                    light_major: bool, tile: int | None) -> dict:
    """:func:`~ltmstore.stages.plan.choose_form` on the lattice the run will use (a near-light
    4-D store)."""
    r, s, valid = group["pose_r"][:], group["pose_s"][:], group["pose_valid"][:]
    lat = _pick_lattice(_plane(group), r, s, valid, shape=lattice, delta=delta_rs)[0]
    plan = plan_tiles(group["frames"].shape[1:], lat.shape, tile=tile or 32)
    return choose_form(plan, path, channels=channels, light_major=light_major)


def _warn_if_it_overflows(estimate: dict) -> None:
    """A ``--form dense`` asked for whose store is estimated at more than the free disk: one
    warning line before hours of work (it runs all the same: the estimate may be wrong)."""
    dense, free = estimate["dense_estimate_bytes"], estimate["free_bytes"]
    if dense > free:
        warnings.warn(f"the dense form of this store is estimated at {size_text(dense)}, more "
                      f"than the {size_text(free)} free on its disk: it will likely run out of "
                      "space; --form factored stores a few percent of that", LtmWarning,
                      stacklevel=3)


def _refinement_pending(group: zarr.Group, key: dict) -> bool:
    """Whether the store's far-light refinement was begun and not completed by a run of the
    parameters ``key`` (stage 1 alone, or a run killed during stage 2)."""
    entry = st.stages(group).get(st.REFINEMENT) or {}
    return bool(entry) and not entry.get("complete") and entry.get("run") == key


def _pending_note(group: zarr.Group, key: dict) -> str:
    """How to finish a far-light store's pending refinement (empty where none is)."""
    entry = st.stages(group).get(st.REFINEMENT) or {}
    if not entry or entry.get("complete"):
        return ""
    run = entry.get("run") or {}
    if run == key:
        return " (the classic fit; `--stage all`, the default, finishes its surface refinement)"
    return (f" (its surface refinement is pending for a run of other parameters: method "
            f"{run.get('method')!r}, lattice {run.get('lattice')!r}, tile {run.get('tile')!r}, "
            f"software {run.get('software')!r}; run those to finish it)")


def _kept_note(path: str) -> str:
    """What a failed far-light run left: its classic fit, or nothing complete."""
    try:
        done = st.stages(st.open_group(path)).get("reconstruct", {}).get("complete")
    except (LtmError, OSError, ValueError):
        done = False
    return ("its classic fit is complete, its surface refinement is not" if done
            else "its reconstruct stage stays incomplete")


def _far_stages(path: str, run: dict, *, revise: bool, pending: bool, stage: str) -> dict:
    """A far-light store's stages (:mod:`~ltmstore.stages.reconstruct_far`): the classic
    fit in place (on a linked copy where it replaces a complete ``ltm``), unless it is there
    and only its refinement is ``pending``; then, unless ``stage`` is ``classic``, the surface
    refinement on a linked copy swapped in when complete, so that a killed run leaves the
    classic store as it was, its refinement recorded as not complete."""
    from ltmstore.stages import reconstruct_far as far

    key = run_key(**{k: run[k] for k in ("lattice", "delta_rs", "method", "params", "auto",
                                         "color", "tile")})
    args = {k: run[k] for k in ("lattice", "method", "tile", "progress")}
    two = far.refines(run["method"]) and stage == "all"
    fit = None
    if not pending:
        if not revise:
            info, fit = far.reconstruct_far(st.open_group(path, mode="r+"), **args, key=key,
                                            refine_next=two)
        else:
            with st.revised_store(path) as side:
                info, fit = far.reconstruct_far(st.open_group(side, mode="r+"), **args,
                                                key=key, refine_next=two)
    if two:
        with st.revised_store(path, resumable=False) as side:
            info = far.refine_far(st.open_group(side, mode="r+"), fit=fit, **args, key=key)
    return info


def _on_cluster(path, client: Client | None, scheduler: str | None, run: dict) -> dict:
    from ltmstore.core.cluster import dask_client, is_small

    group = st.open_group(path, mode="r+")

    run = {**run, "tile": run["tile"] or 32}
    if client is not None:
        return _reconstruct(group, client, **run)
    work = group["frames"].size * 4  # the frames' bytes as resampling computes them (float32)
    with dask_client(scheduler, small=is_small(work)) as own:
        return _reconstruct(group, own, **run)


def run_key(*, lattice, delta_rs, method: str, params: dict, auto: bool, color: bool,
            tile: int, form: str = "dense") -> dict:
    """Everything that shapes the ``ltm`` (with the software): equal keys, equal results."""
    from ltmstore.core.provenance import software

    soft = software()
    return json.loads(json.dumps({
        "lattice": None if lattice is None else [int(n) for n in lattice],
        "delta_rs": delta_rs, "method": method, "params": params, "auto": bool(auto),
        "color": bool(color), "tile": None if tile is None else int(tile), "form": form,
        "software": soft["version"]}, sort_keys=True, default=str))


def _ltm_copies(color: bool, light_major: bool, form: str = "dense") -> int:
    """Dense LTM-sized float32 variables of a run: samples, ltm, and its light-major copy
    (the samples alone in the factored form), for luminance and, in colour, Cb and Cr."""
    return (3 if color else 1) * (1 if form == "factored" else 3 if light_major else 2)


def _check_user_lattice(path: str, group: zarr.Group, *, lattice, delta_rs, far: bool,
                        copies: int, tile: int | None) -> None:
    """Refuse a ``--lattice`` or ``--delta-rs`` that cannot fit in memory or on disk, before
    a cluster starts or anything is written (:func:`~ltmstore.stages.plan.check_fits`)."""
    if lattice is None and delta_rs is None:
        return
    what = (f"--lattice {'x'.join(map(str, lattice))}" if lattice is not None
            else f"--delta-rs {delta_rs!r}")
    if far:
        from ltmstore.stages.reconstruct_far import FAR_TILE

        lat, tile = Lattice.from_plane(DISK, lattice), tile or FAR_TILE
    elif "pose_p" in group:
        lat = lattice_6d(_plane(group), _view_plane(group, path), (), None, shape=lattice,
                         delta=delta_rs)[0]
    else:
        lat = _pick_lattice(_plane(group), None, None, None, shape=lattice, delta=delta_rs)[0]
    plan = plan_tiles(group["frames"].shape[1:], lat.shape, tile=tile or 32)
    check_fits(plan, path, what=what, ltm_copies=copies)


def _plane(group: zarr.Group) -> Plane:
    return Plane.from_json(group.attrs["acquisition"]["plane"])


def _view_plane(group: zarr.Group, path) -> dict:
    """The view plane of a 6D store (one with camera positions)."""
    view = group.attrs["acquisition"].get("view_plane")
    if view is None:
        raise LtmError(f"store {str(path)!r} holds camera positions (pose_p, pose_q) but no "
                       "view_plane; declare it in acquisition.json and ingest again")
    return view


def _pick_lattice(plane: Plane, r, s, valid, *, shape, delta) -> tuple[Lattice, str]:
    if shape is not None:
        return Lattice.from_plane(plane, shape), "user"
    if delta is not None:
        return Lattice.from_delta(plane, delta), "user"
    return choose_lattice(plane, r, s, valid), "automatic"


def _too_sparse(lattice: Lattice, binning: Binning, automatic: Lattice, ratio: float) -> str:
    """Why a lattice with a sampling ratio below :data:`MIN_RATIO` is refused."""
    def name(lat: Lattice) -> str:
        return "x".join(map(str, lat.shape))

    return (f"lattice {name(lattice)} gives K/M {binning.ratio:.4f} ({binning.k} of "
            f"{binning.m} cells observed), below {MIN_RATIO}: almost every cell would be "
            f"guessed; --lattice {name(automatic)} gives K/M {ratio:.2f} (the automatic "
            f"lattice, aiming at the paper's {TARGET_RATIO}); pass --force to run it anyway")


def _resumable(group: zarr.Group, key: dict, plan: TilePlan, names: list[str],
               ltm_names: list[str]) -> bool:
    """Whether an interrupted run of the same ``key`` left complete samples, the variables
    ``names`` and the tile marks of every LTM in ``ltm_names``."""
    entry = st.stages(group)
    rec, res = entry.get("reconstruct") or {}, entry.get("resample") or {}
    if rec.get("complete") or not res.get("complete") or rec.get("run") != key:
        return False
    return (all(n in group for n in names)
            and all(tiles_name(n) in group and group[tiles_name(n)].shape == plan.grid
                    for n in ltm_names)
            and group[SAMPLES].shape == (*plan.image, *plan.lattice))


def tiles_name(variable: str) -> str:
    """The per-tile completion marks of an LTM variable (removed when the stage completes)."""
    return f"{variable}_tiles_done"


def _reconstruct(group: zarr.Group, client: Client, *, lattice, delta_rs, method: str,
                 params: dict, auto: bool, color: bool, tile: int, progress: bool,
                 resume: bool, force: bool, light_major: bool, form: str) -> dict:
    plane = _plane(group)
    r, s, valid = group["pose_r"][:], group["pose_s"][:], group["pose_valid"][:]
    timings = {}
    start = time.perf_counter()
    positions = view_positions(group, r, s)  # (r, s), or (r, s, p, q) in 6D
    path = getattr(group.store, "root", ".")
    pick = (partial(_pick_lattice, plane, r, s, valid) if len(positions) == 2
            else partial(lattice_6d, plane, _view_plane(group, path), positions, valid))
    lat, chosen = pick(shape=lattice, delta=delta_rs)
    plan = plan_tiles(group["frames"].shape[1:], lat.shape, tile=tile)
    check_fits(plan, path, what=f"the {chosen} lattice {'x'.join(map(str, lat.shape))}",
               ltm_copies=_ltm_copies(color, light_major, form))
    binning = bin_positions(lat, positions, valid)
    if binning.k == 0:
        raise LtmError(f"no valid frame falls on the {lat.shape} lattice")
    if binning.ratio < MIN_RATIO and chosen == "user" and not force:
        automatic = pick(shape=None, delta=None)[0]
        raise LtmError(_too_sparse(lat, binning, automatic,
                                   bin_positions(automatic, positions, valid).ratio))
    key = run_key(lattice=lattice, delta_rs=delta_rs, method=method, params=params, auto=auto,
                  color=color, tile=tile, form=form)
    ltm_names = [LTM, *(CHROMA_LTM[c] for c in CHROMA_CHANNELS if color)]
    sample_names = [SAMPLES, *(CHROMA_SAMPLES[c] for c in CHROMA_CHANNELS if color)]
    sampling = {"lattice": lat.to_json(), "lattice_choice": chosen, "K": binning.k,
                "M": binning.m, "sampling_ratio": binning.ratio,
                "path_density": path_length(r, s, valid=valid) / plane.area}
    segment, sampling["revisited"] = _segments(group, binning)
    solve_args = dict(geometry=Geometry(lattice=lat, height=plane.height,
                                        sampled=_sampled(binning, r, s),
                                        led_axis=_cell_axes(group, binning), segment=segment),
                      plan=plan,
                      sampling=sampling, key=key, method=method, params=params, auto=auto,
                      color=color, progress=progress, light_major=light_major, form=form)
    place = partial(_place, group, plan, binning, r, s, solve_args["geometry"], method)
    outputs = (ltm_names if form == "dense"
               else [factors.staging_names(n)[i] for n in ltm_names for i in (0, 1)])
    if resume and _resumable(group, key, plan, [*sample_names, *outputs, EXPECTED_ERROR,
                                                UNSUPPORTED], ltm_names):
        timings = {"resample_s": 0.0}
        return _solve_stage(group, client, **solve_args, **place(timings), timings=timings,
                            resumed=True)

    st.begin_stage(group, "resample")
    st.begin_stage(group, "reconstruct", {"run": key})
    st.drop_stage_variables(group, "resample", "reconstruct")  # possibly on another lattice
    _write_lattice(group, binning)
    _write_samples(group, SAMPLES, group["frames"], binning, plan, client, progress=progress)
    for i, c in enumerate(CHROMA_CHANNELS if color else ()):
        _write_samples(group, CHROMA_SAMPLES[c], group[FRAME_CHROMA], binning, plan, client,
                       channel=i, progress=progress)
    st.complete_stage(group, "resample", {
        **sampling, "frames_used": int((binning.cell >= 0).sum())})
    timings["resample_s"] = time.perf_counter() - start
    placed = place(timings)

    for name in ltm_names:
        if form == "factored":
            factors.create_staging(group, name, plan.image, plan.lattice, plan.tile)
        else:
            st.create_variable(group, name, ("y", "x", *lat.dims), (*plan.image, *lat.shape),
                               chunks=plan.chunks, shards=plan.shards,
                               compressors=checksum.FAST_COMPRESSORS)
        st.create_variable(group, tiles_name(name), ("tile_y", "tile_x"), plan.grid,
                           chunks=(1, 1), dtype=str, fill_value="")
    st.create_variable(group, EXPECTED_ERROR, ("y", "x"), plan.image, chunks=plan.tile)
    st.create_variable(group, UNSUPPORTED, ("y", "x"), plan.image, chunks=plan.tile, dtype=bool,
                       fill_value=True)
    if placed["extent"] is not None:
        _create_surface_maps(group, plan)
    return _solve_stage(group, client, **solve_args, **placed, timings=timings, resumed=False)


def _sampled(binning: Binning, r: np.ndarray, s: np.ndarray) -> np.ndarray | None:
    """Each cell's samples' mean light position on a lattice of the plane (the surface
    model fits them there), None on a 6-D lattice."""
    return cell_means(binning, r, s) if len(binning.lattice.shape) == 2 else None


def _cell_axes(group: zarr.Group, binning: Binning) -> np.ndarray | None:
    """The LED's mean axis over each cell's frames, ``(M, 3)`` unit vectors (NaN where none),
    where the store has the poses' axis (``pose_axis_*``) and the lattice is the plane's; else
    None (the LED held level)."""
    if len(binning.lattice.shape) != 2 or any(name not in group for name in POSE_AXIS):
        return None
    mean = cell_means(binning, *(group[name][:] for name in POSE_AXIS))
    with np.errstate(invalid="ignore"):
        return mean / np.linalg.norm(mean, axis=1, keepdims=True)


def _segments(group: zarr.Group, binning: Binning) -> tuple[np.ndarray | None, float | None]:
    """The second of a handheld video (:data:`SEGMENT_S`) in which each cell took most of its
    frames (:func:`ltmstore.core.binning.segments`), None where the path was revisited beside
    fewer than :data:`MIN_REVISITED` of its cells; and that fraction (None for photographs or a
    6-D lattice)."""
    if (group.attrs.get("acquisition", {}).get("source") != "video"
            or len(binning.lattice.shape) != 2):
        return None, None
    segment = segments(binning, group["t"][:], SEGMENT_S)
    fraction = revisited(segment.reshape(binning.lattice.shape))
    return (segment if fraction >= MIN_REVISITED else None), fraction


def _place(group: zarr.Group, plan: TilePlan, binning: Binning, r: np.ndarray, s: np.ndarray,
           geometry: Geometry, method: str, timings: dict) -> dict:
    """The object extent of the surface model (declared or estimated,
    :func:`ltmstore.stages.placement.place_object`, levelled at ``geometry`` with the beam
    ingest estimated) and its record; none where the method or a 6-D lattice does not use
    it."""
    if method not in (AUTO, "physical") or len(binning.lattice.shape) != 2:
        return {"extent": None, "placement": None}
    from ltmstore.stages.placement import place_object

    start = time.perf_counter()
    beam = _ingest_beam(group)
    level = replace(geometry, led_exponent=float(beam["exponent"])
                    if beam.get("source") == "estimated" else 0.0)
    extent, record = place_object(group, plan, binning, r, s, geometry.height, method=method,
                                  geometry=level)
    timings["placement_s"] = time.perf_counter() - start
    return {"extent": extent, "placement": record}


def _solve_stage(group: zarr.Group, client: Client, *, geometry: Geometry, plan: TilePlan,
                 sampling: dict, key: dict, method: str, params: dict, auto: bool, color: bool,
                 progress: bool, timings: dict, resumed: bool, light_major: bool,
                 form: str, extent: dict | None, placement: dict | None) -> dict:
    """Solve every tile not yet marked done (all of them in a fresh run); complete the stage.
    ``extent`` places the pixels on the object plane for the surface model (None: without it);
    ``placement`` records where it came from."""
    start = time.perf_counter()
    geometry, beam = led_beam(group, plan, geometry, extent)
    timings["led_beam_s"] = time.perf_counter() - start
    start = time.perf_counter()

    def outputs(name: str) -> dict:  # where a tile of the LTM variable ``name`` goes
        written = ({FACTORS: tuple(group[n] for n in factors.staging_names(name))}
                   if form == "factored" else {LTM: group[name]})
        return {**written, TILES: group[tiles_name(name)]}

    out = {**outputs(LTM), EXPECTED_ERROR: group[EXPECTED_ERROR],
           UNSUPPORTED: group[UNSUPPORTED],
           **{name: group[name] for name in sf.SURFACE if name in group}}
    solve = partial(_solve_tiles, plan=plan, geometry=geometry, params=params, client=client,
                    progress=progress)
    records, solved = solve(group[SAMPLES], out, method=method, auto=auto, extent=extent)
    record_method_map(group, records, plan, method)
    all_records = {LTM: records}
    # The colour LTM: the same method, default parameters. Signed chroma is no reflectance:
    # `--method physical` interpolates it with rbf, and auto's chroma passes leave physical out.
    # Its factors leave out the fraction of its energy the luminance's left out in each tile.
    chroma_method = "rbf" if method == "physical" else method
    fractions = _tile_values(records, plan, "fraction") if form == "factored" else None
    for c in CHROMA_CHANNELS if color else ():
        done, n = solve(group[CHROMA_SAMPLES[c]], outputs(CHROMA_LTM[c]),
                        method=chroma_method, auto=False, extent=None, fractions=fractions)
        all_records[CHROMA_LTM[c]], solved = done, solved + n
    timings["solve_s"] = time.perf_counter() - start
    passes = 1 + len(CHROMA_CHANNELS) * bool(color)
    info = {**sampling, "method": method, "params": params, "auto": auto, "color": color,
            "run": key, "chosen_per_tile": summarise_choices(records),
            "methods_per_tile": summarise_methods(records), "plan": asdict(plan),
            "heldout_error": _mean_heldout(records), "tiles_total": plan.n_tiles * passes,
            "tiles_solved": solved, "tiles_resumed": plan.n_tiles * passes - solved,
            "resumed": resumed, "timings": timings, "form": form,
            **({"rank_rule": factored.RANK_RULE} if form == "factored" else {}),
            "seconds_per_pixel": sum(r["seconds"] for r in records) / int(np.prod(plan.image)),
            **({"placement": placement} if placement is not None else {}),
            **({"led_beam": beam} if beam is not None else {})}
    names = [LTM, *(CHROMA_LTM[c] for c in CHROMA_CHANNELS if color)]
    start = time.perf_counter()
    for name in names:
        if form == "factored":  # refuses a tile whose factors are missing
            ranks = _tile_values(all_records[name], plan, "rank").astype(int)
            factors.gather(group, name, plan.tile, plan.lattice_chunk, ranks)
            info.setdefault("ranks", {})[name] = {
                "min": int(ranks.min()), "mean": float(ranks.mean()), "max": int(ranks.max())}
        else:
            check_solved(group, name, plan, client)
    timings["gather_s" if form == "factored" else "check_s"] = time.perf_counter() - start
    start = time.perf_counter()
    for name in names if light_major else ():
        write_by_light(group, name, client=client)  # the light-major copy relight reads
    timings["by_light_s"] = time.perf_counter() - start
    for name in [LTM, *CHROMA_LTM.values()]:
        if tiles_name(name) in group:
            del group[tiles_name(name)]
    st.complete_stage(group, "reconstruct", info)
    return info


def check_solved(group: zarr.Group, name: str, plan: TilePlan, client: Client) -> None:
    """Refuse to complete the stage unless the samples hold data and every tile of the LTM
    ``name`` is in the store (a worker that wrote elsewhere, a lost shard). Each tile checked
    its solution finite wherever its samples are before writing it (:func:`_solve_tile`), so
    the chunks' count settles it; where one is missing, the samples and the LTM are read to
    name the first tile at fault.

    Raises
    ------
    LtmError
        Naming the first tile at fault.
    """
    import dask.array as da

    samples_name = SAMPLES if name == LTM else name.replace(LTM, SAMPLES, 1)
    ltm = group[name]
    if group[samples_name].nchunks_initialized > 0 and ltm.nchunks_initialized == ltm.nchunks:
        return
    samples = da.from_zarr(group[samples_name], chunks=plan.block)
    ltm = da.from_zarr(ltm, chunks=plan.block)
    lattice_axes = tuple(range(2, samples.ndim))
    observed = da.isfinite(samples)
    missing = (observed & ~da.isfinite(ltm)).any(axis=lattice_axes)
    n_observed, missing = client.compute([observed.sum(), missing], sync=True)
    where = f"store {str(getattr(group.store, 'root', group.store))!r}"
    if n_observed == 0:
        raise LtmError(f"{where}: {samples_name} holds no finite sample (did the Dask workers "
                       "see the store?); the reconstruct stage stays incomplete")
    if missing.any():
        y, x = np.argwhere(missing)[0]
        raise LtmError(f"{where}: {name} is not finite at {int(missing.sum())} observed pixels "
                       f"(first in tile {y // plan.tile[0]}, {x // plan.tile[1]}); the "
                       "reconstruct stage stays incomplete")


def record_method_map(group: zarr.Group, records: list[dict], plan: TilePlan,
                      method: str) -> None:
    """``method_map (tile_y, tile_x)``: the method each tile used (index into attr
    ``methods``)."""
    names = list(AUTO_LABELS) if method == AUTO else [method]
    chosen = np.full(plan.grid, -1, dtype=np.int16)
    for rec in records:
        chosen[tuple(rec["tile"])] = names.index(rec.get("method", method))
    write_method_map(group, plan, chosen, names, "held-out error")


def _mean_heldout(records: list[dict]) -> float | None:
    """Mean over tiles of the held-out relative error of the chosen parameters (of the chosen
    method, for a tile whose method had no parameters to choose)."""
    errors = []
    for rec in records:
        chosen = rec["params"]
        found = [error for value, error in (rec.get("heldout") or {}).items()
                 if any(str(v) == str(value) for v in chosen.values())]
        errors += found or ([rec["method_error"]] if rec.get("method_error") is not None else [])
    return float(np.mean(errors)) if errors else None


def _tile_values(records: list[dict], plan: TilePlan, key: str) -> np.ndarray:
    """``record[key]`` of every tile, on the tile grid."""
    values = np.zeros(plan.grid)
    for rec in records:
        values[tuple(rec["tile"])] = rec[key]
    return values


def _solve_tiles(samples: zarr.Array, out: dict[str, zarr.Array], *, plan: TilePlan,
                 geometry: Geometry, method: str, params: dict, auto: bool, client: Client,
                 progress: bool, extent: dict | None,
                 fractions: np.ndarray | None = None) -> tuple[list[dict], int]:
    """Solve every pixel tile not yet marked done in ``out[TILES]``, a few per Dask task
    (:func:`tile_groups`).

    Returns every tile's record (earlier runs' from their marks) and how many were solved now.
    """
    marks = _read_marks(out[TILES])
    todo = marks == ""
    chosen = None
    if method == AUTO and todo.any():  # once for the image, not per tile
        chosen = choose_for_image(samples, plan, geometry, extent)
    groups = tile_groups(todo)
    futures = client.map(_solve_tiles_task, groups, source=samples, plan=plan, out=out,
                         method=method, params=params, geometry=geometry, auto=auto,
                         extent=extent, chosen=chosen, fractions=fractions, pure=False)
    solved = _gather(futures, desc="reconstruct tiles", progress=progress,
                     total=int(todo.sum()), size=len)
    earlier = [json.loads(str(m)) for m in marks[~todo]]
    return earlier + [record for records in solved for record in records], int(todo.sum())


# A solve task takes up to GROUP_SIDE x GROUP_SIDE neighbouring tiles (a 32 x 32 px tile of
# the 4K capture solves in about half a second, its task's overhead on a cluster's scheduler
# is a few milliseconds), once the image has GROUP_MIN_TILES tiles to share among the workers.
GROUP_SIDE, GROUP_MIN_TILES = 2, 64


def tile_groups(todo: np.ndarray) -> list[list[tuple[int, int]]]:
    """The tiles to solve (``todo`` True on the tile grid) in the groups of one task each:
    squares of :data:`GROUP_SIDE` tiles a side, single tiles on a grid of fewer than
    :data:`GROUP_MIN_TILES`."""
    side = GROUP_SIDE if todo.size >= GROUP_MIN_TILES else 1
    groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for ty, tx in np.argwhere(todo):
        groups.setdefault((ty // side, tx // side), []).append((int(ty), int(tx)))
    return list(groups.values())


def _read_marks(marks: zarr.Array) -> np.ndarray:
    """The tile marks; a mark a killed process left unreadable counts as not done."""
    try:
        return np.asarray(marks[...], dtype=object)
    except Exception:  # noqa: BLE001 - a torn chunk: read the marks one by one
        out = np.full(marks.shape, "", dtype=object)
        for index in np.ndindex(marks.shape):
            try:
                out[index] = str(marks[index])
            except Exception:  # noqa: BLE001
                pass
        return out


def summarise_methods(records: list[dict]) -> dict:
    """How many tiles used each method (``auto`` chooses per tile)."""
    labels = [str(rec.get("method")) for rec in records]
    return {label: labels.count(label) for label in sorted(set(labels))}


def summarise_choices(records: list[dict]) -> dict:
    """How many tiles chose each parameter setting."""
    counts: dict[str, int] = {}
    for rec in records:
        key = json.dumps(rec["params"], sort_keys=True)
        counts[key] = counts.get(key, 0) + 1
    return counts
