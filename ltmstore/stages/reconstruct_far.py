"""Reconstruct a far-light store: classic RTI models fitted at the exact light directions.

Every model of :mod:`ltmstore.solve.lightfit` is linear in the observations, with weights that
depend only on the light directions, so one weight matrix per model serves every pixel. Per pixel
tile, the model with the lowest leave-one-light-out error on the tile's own photographs is chosen
(``method="auto"``: PTM, HSH of order 2 and 3, Gaussian RBF at several widths and smoothings, HSH
order 3 plus an RBF of its residual; the smaller model wins a tie), and recorded in
``method_map (tile_y, tile_x)``. No truth and no held-out photograph is used. With ``auto``,
held-out lights of the capture itself (every 4th in turn, on a sample of pixels) then score every
classic model and the surface model (:func:`_surface`): the image's classic model is the one
they prefer where it beats the leave-one-out choice by
:data:`~ltmstore.stages.surface.CLASSIC_MARGIN` (leave-one-out on a dome's rings favours the
models that interpolate along them), and the surface is fitted only where it lowers that
model's held-out error by :data:`~ltmstore.stages.surface.MARGIN`; where it is skipped, the
stage record's ``timings.surface_skipped_s`` says how long its fit would have taken.

``auto`` and ``physical`` run in two recorded stages. Stage 1 (:func:`reconstruct_far`, the
``reconstruct`` record) is the leave-one-out choice per tile among the classic models: ``ltm``,
``method_map`` and ``expected_error`` written, the store complete and relightable in about the
time of ``--method rbf``. Its last write begins the record of stage 2, :data:`REFINE`, which
stays incomplete (``ltm info``: not complete, ``reconstruct_surface`` not complete) until stage 2
(:func:`refine_far`: the held-out choice, the surface fit, the tiles written again where the
choice changed) completes the ``reconstruct`` record again and then its own, on a linked copy of
the store swapped in only then (:mod:`ltmstore.stages.reconstruct`): a killed stage 2 leaves
the stage-1 store as it was, and the next ``ltm reconstruct`` of the same parameters runs stage 2
again from its start (what stage 1 chose is recomputed from the store: the same choice). Both
stages in one run write the same arrays as one stage did.

Like the RTI world's fitters, the models are fitted to the sRGB-encoded values of the
photographs (the measure is on 8-bit sRGB images; on the coin this is 3-4 dB better than a fit in
linear light) and decoded back to linear light.

The outputs: ``ltm (y, x, r, s)``, linear luminance on a lattice of ``r = lx, s = ly`` over the unit
disk (cells outside the disk hold the value at the horizon along their azimuth), for plain
xarray readers and exporters; ``expected_error (y, x)`` (leave-one-out RMS over the pixel's
observed range, in sRGB-encoded units); ``method_map``. Relighting
(:mod:`ltmstore.stages.relight`) evaluates the chosen model at any direction from the frames
themselves, so the lattice costs nothing in accuracy.

A small capture needs no process cluster: tiles run on a thread pool (NumPy and Zarr release the
GIL), started in well under a second, with one BLAS thread each (BLAS threads on top of the pool
oversubscribe the cores: on a busy 2-core machine a 200 x 200 solve then took 2 s instead of
3 ms). The choice costs one Gram matrix per tile (:func:`_loo_mse`), and each tile encodes its own
pixels to sRGB, so the photographs' luminance is read once, kept in float16 as stored, and never
copied whole. The surface reads their colour band by band of rows (twice: for its sample, then to
fit), so memory does not grow with the image's colour: a 12 MP, 47-light capture reconstructs
in 3.95 GiB at its peak, against 19.2 GiB with the whole image in float32 (``bench/rti_scale.py``).
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
import zarr
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from ltmstore.core import checksum
from ltmstore.core import store as st
from ltmstore.core.dims import EXPECTED_ERROR, FRAMES, LTM, LUMA, UNSUPPORTED, Lattice
from ltmstore.core.errors import LtmError
from ltmstore.core.lights import DISK, FAR, coordinate_attrs, disk_to_direction
from ltmstore.core.transfer import half_to_srgb, linear_to_srgb, srgb_to_linear
from ltmstore.solve import Geometry, physical, shadows
from ltmstore.solve.lightfit import Model, candidates, loo_operator, pick, rbf_models
from ltmstore.stages import surface as sf
from ltmstore.stages.plan import TilePlan, plan_tiles, write_method_map

FAR_LATTICE = (8, 8)
FAR_TILE = 64
CHOICE_PIXELS = 1024  # pixels of a tile whose leave-one-out error chooses its model
# The least number of ltm shards, each written in one Zarr call (work for both threads of a
# small capture's slow surface tiles); above it, 4 x 4 or 2 x 2 tiles a shard: at 1 MP a
# shard a tile took 1.2 s to write, 16 tiles a shard 0.3 s (Zarr's cost of a file)
MIN_SHARDS = 16
# A tile leaves the image's model only when its own lowers the tile's MSE by more than this
# fraction of the image's mean MSE (see choose_tiles).
LEAVE_GLOBAL = 1.0
FAR_METHODS = ("auto", "ptm", "hsh", "rbf", "physical")
# The record of stage 2, the surface refinement (refine_far); stage 1 is ``reconstruct``.
REFINE = st.REFINEMENT


def far_models(method: str) -> tuple[Model, ...]:
    """The candidate models of ``method`` on a far-light store."""
    families = {"auto": candidates(), "ptm": (Model("ptm"),),
                "hsh": (Model("hsh2"), Model("hsh3")), "rbf": tuple(rbf_models()),
                "physical": candidates()}  # the classic models still choose per tile first
    if method not in families:
        raise LtmError(f"method {method!r} does not fit far lights (a classic RTI capture); "
                       f"expected one of {', '.join(FAR_METHODS)}")
    return families[method]


def train_directions(group) -> np.ndarray:
    """Unit directions ``(n, 3)`` of the store's valid lights."""
    valid = np.asarray(group["pose_valid"][:], dtype=bool)
    return np.column_stack([np.asarray(group[k][:])[valid]
                            for k in ("pose_r", "pose_s", "pose_z")])


def refines(method: str) -> bool:
    """Whether ``method`` has a second stage, the surface refinement (:data:`REFINE`)."""
    return method in ("auto", "physical")


def reconstruct_far(group: zarr.Group, *, lattice: tuple[int, int] | None, method: str,
                    tile: int | None, progress: bool, key: dict,
                    refine_next: bool = False) -> tuple[dict, FarFit]:
    """Stage 1: fit, choose per tile and write ``ltm``, ``method_map`` and ``expected_error``.

    The store is then complete and relightable from the classic models. Where ``method`` has a
    refinement (:func:`refines`), its record :data:`REFINE` is begun (not complete) before the
    ``reconstruct`` record completes: the store never looks refined, and :func:`refine_far`
    (next in this run where ``refine_next``: the progress bar says stage 1/2; or in a later
    run) finishes it.

    Returns the ``reconstruct`` stage record and the fit, which :func:`refine_far` reuses.
    """
    with threadpool_limits(1, user_api="blas"):  # threads over tiles: one BLAS thread each
        fit = FarFit.prepare(group, lattice=lattice, method=method, tile=tile)
        return fit.classic(group, progress=progress, key=key, staged=refine_next), fit


def refine_far(group: zarr.Group, *, fit: FarFit | None, lattice: tuple[int, int] | None,
               method: str, tile: int | None, progress: bool, key: dict) -> dict:
    """Stage 2 (:data:`REFINE`): the surface model and the held-out re-choice of the classic
    model, on a store whose stage 1 (:func:`reconstruct_far`) is complete.

    Writes the surface's maps (and exposures) where it pays, then, where the choice changed,
    every tile of ``ltm``, ``expected_error`` and ``method_map``; completes the ``reconstruct``
    record with what the refinement chose and, last, the :data:`REFINE` record. ``fit``: stage
    1's of this process (None: prepared again from the store, the same choice).

    Returns the completed ``reconstruct`` record.
    """
    # the surface's kernels load beside the reading of the frames' colour (not during stage 1:
    # on a busy 2-core machine they delayed the relightable store by 1-1.5 s, a third of it)
    threading.Thread(target=_load_kernels, name="numba-warm-up", daemon=True).start()
    with threadpool_limits(1, user_api="blas"):
        again = fit is None  # a later run's (stage 1 alone, or a killed stage 2)
        if again:
            fit = FarFit.prepare(group, lattice=lattice, method=method, tile=tile)
        return fit.refine(group, progress=progress, key=key, again=again)


def _forget_stage(group: zarr.Group, stage: str) -> None:
    """Remove the record of ``stage`` (an earlier run's refinement, before stage 1 runs)."""
    records = st.stages(group)
    if records.pop(stage, None) is not None:
        group.attrs[st.STAGES_ATTR] = records


@dataclass
class FarFit:
    """What both stages of a far-light reconstruction share: the candidate models and their
    operators, the valid frames (linear luminance, float16 as stored), the tile plan, and
    once computed, each tile's leave-one-out MSE of every model."""

    method: str
    models: tuple[Model, ...]
    valid: np.ndarray
    train: np.ndarray
    lat: Lattice
    cells: np.ndarray
    loo: np.ndarray
    usable: np.ndarray
    to_lattice: list[np.ndarray]
    frames: np.ndarray
    plan: TilePlan
    timings: dict = field(default_factory=dict)
    mse: np.ndarray | None = None

    @classmethod
    def prepare(cls, group: zarr.Group, *, lattice: tuple[int, int] | None, method: str,
                tile: int | None) -> FarFit:
        """Models, operators and frames of the store's valid lights."""
        start = time.perf_counter()
        models = far_models(method)
        valid = np.asarray(group["pose_valid"][:], dtype=bool)
        train = train_directions(group)
        lat = Lattice.from_plane(DISK, lattice or FAR_LATTICE)
        cells = disk_to_direction(*Geometry(lattice=lat).positions().T)
        operators = [loo_operator(m.hat(train)) for m in models]
        usable = np.array([a is not None for a in operators])
        loo = np.array([np.zeros((len(train),) * 2) if a is None else a for a in operators])
        to_lattice = [m.weights(train, cells).astype(np.float32) for m in models]
        # linear, kept in float16 as stored: each tile converts and encodes its own pixels
        stored = group[FRAMES]  # the valid frames only: no second copy of all of them
        frames = stored[:] if valid.all() else stored.oindex[np.flatnonzero(valid)]
        plan = plan_tiles(frames.shape[1:], lat.shape, tile=tile or FAR_TILE,
                          chunk_bytes=2**20).with_shards(MIN_SHARDS)
        return cls(method, models, valid, train, lat, cells, loo, usable, to_lattice, frames,
                   plan, {"prepare_s": time.perf_counter() - start})

    def pixels(self, index: tuple[int, int], gain: np.ndarray | None = None,
               choice: bool = False) -> tuple[slice, slice, np.ndarray]:
        """The tile's rows, columns and sRGB-encoded values ``(lights, pixels)`` (the frames
        divided by their exposures ``gain``); for the ``choice``, every k-th pixel only
        (:data:`CHOICE_PIXELS` of them)."""
        rows, cols = self.plan.tile_region(index)
        values = self.frames[:, rows, cols].reshape(len(self.frames), -1)
        if choice:
            values = values[:, :: max(1, values.shape[1] // CHOICE_PIXELS)]
        if gain is None:  # float16 as stored: encoded by a table
            return rows, cols, half_to_srgb(values)
        return rows, cols, linear_to_srgb(values / gain[:, None])

    def choose(self, pool: ThreadPoolExecutor) -> np.ndarray:
        """Each tile's leave-one-out MSE of every model (kept as :attr:`mse`) and its model
        (:func:`choose_tiles`) on the tile grid."""
        if self.mse is None:
            tiles = list(np.ndindex(self.plan.grid))
            self.mse = np.array(list(pool.map(
                lambda i: _loo_mse(self.pixels(i, choice=True)[2], self.loo, self.usable),
                tiles)))
        return choose_tiles(self.mse, self.models, len(self.train)).reshape(self.plan.grid)

    def write_tiles(self, group: zarr.Group, pool: ThreadPoolExecutor, chosen: np.ndarray, *,
                    desc: str, progress: bool, surface: tuple | None = None) -> None:
        """Every tile of ``ltm``, ``expected_error`` and ``unsupported`` from its model in
        ``chosen`` (an index of :attr:`models`; ``len(models)``: the surface blend, of
        ``surface = (theta, blend, gain, height)``, ``height`` the one casting its shadows)."""
        lat, loo32 = self.lat, self.loo.astype(np.float32)  # per pixel: float32 as the values
        ltm = group[LTM]
        # the per-pixel maps are written once, whole, after the tiles: a write per tile of
        # each cost as much as the tile's LTM (Zarr's overhead of a call, about 1.4 ms)
        error = np.empty(self.plan.image, np.float32)
        theta, blend, gain, height = surface if surface is not None else (None,) * 4
        at_cells = None if blend is None else sf.BlendAt.of(blend, self.train, self.cells)

        def fit(index: tuple[int, int], out: np.ndarray) -> None:  # its LTM; its error noted
            rows, cols, values = self.pixels(index, gain)
            shape = (rows.stop - rows.start, cols.stop - cols.start)
            best = int(chosen[index])
            if best < len(self.models):
                fitted, residual = self.to_lattice[best] @ values, loo32[best] @ values
            else:  # the surface model plus its smoothed residual (and classic model)
                tile_theta = theta[rows, cols].reshape(-1, 3, 6)
                visible = None
                if blend.shadows:
                    visible = tuple(shadows.visible(
                        d, shadows.region_horizons(height, rows, cols, d), blend.shadows)
                        for d in (self.train, self.cells))
                fitted, residual = at_cells.image_and_residual(tile_theta, values, visible)
            rms = np.sqrt(np.mean(residual**2, axis=0))
            spread = np.ptp(values, axis=0)
            error[rows, cols] = (rms / np.where(spread > 0, spread, np.inf)).reshape(shape)
            fitted = np.clip(fitted, 0, None)  # (cells, pixels): into out's (y, x, r, s)
            out[...] = srgb_to_linear(fitted).reshape(*lat.shape, *shape).transpose(2, 3, 0, 1)

        def write(shard: tuple[tuple[slice, slice], list[tuple[int, int]]]) -> int:
            (rows, cols), tiles = shard  # the shard's tiles, one Zarr write
            block = np.empty((rows.stop - rows.start, cols.stop - cols.start, *lat.shape),
                             np.float32)
            for index in tiles:
                r, c = self.plan.tile_region(index)
                fit(index, block[r.start - rows.start:r.stop - rows.start,
                                 c.start - cols.start:c.stop - cols.start])
            ltm[rows, cols] = block
            return len(tiles)

        with tqdm(total=self.plan.n_tiles, desc=desc, disable=not progress) as bar:
            for done in pool.map(write, self.plan.shard_blocks()):
                bar.update(done)
        group[EXPECTED_ERROR][...] = error
        group[UNSUPPORTED][...] = np.zeros(self.plan.image, bool)

    def classic(self, group: zarr.Group, *, progress: bool, key: dict, staged: bool) -> dict:
        """Stage 1 (:func:`reconstruct_far`); ``staged``: the refinement follows in this run
        (the progress bar names the stage)."""
        plan, lat, timings = self.plan, self.lat, dict(self.timings)
        st.begin_stage(group, "resample")
        st.complete_stage(group, "resample", {"lattice": lat.to_json(), "light_kind": FAR})
        st.begin_stage(group, "reconstruct", {"run": key})
        _forget_stage(group, REFINE)  # an earlier run's
        st.drop_stage_variables(group, "reconstruct")  # an earlier run's, e.g. surface maps
        for name, values in lat.coords().items():
            st.write_coord(group, name, values, **coordinate_attrs(FAR)[name])
        st.create_variable(group, LTM, ("y", "x", *lat.dims), (*plan.image, *lat.shape),
                           chunks=plan.chunks, shards=plan.shards,
                           compressors=checksum.FAST_COMPRESSORS)
        maps = {"chunks": plan.tile, "shards": plan.shards[:2]}  # a file per shard of ltm
        st.create_variable(group, EXPECTED_ERROR, ("y", "x"), plan.image, **maps)
        st.create_variable(group, UNSUPPORTED, ("y", "x"), plan.image, **maps, dtype=bool,
                           fill_value=False)
        solve_start = time.perf_counter()
        two = refines(self.method)
        with _pool() as pool:
            chosen = self.choose(pool)
            timings["fit_s"] = time.perf_counter() - solve_start  # the models are chosen
            desc = (f"reconstruct {'1/2 ' if staged else ''}classic: tiles" if two
                    else "reconstruct tiles")
            self.write_tiles(group, pool, chosen, desc=desc, progress=progress)
        timings["solve_s"] = timings["classic_s"] = time.perf_counter() - solve_start
        names = [m.name for m in self.models]
        write_method_map(group, plan, chosen, names, "leave-one-light-out error")
        timings["resample_s"] = 0.0
        info = {"lattice": lat.to_json(), "light_kind": FAR, "method": self.method,
                "params": {}, "auto": self.method == "auto", "color": False, "run": key,
                "K": int(self.valid.sum()), "M": lat.size,
                "sampling_ratio": float(self.valid.sum()) / lat.size, "path_density": None,
                **_chosen(chosen, names), "plan": asdict(plan), "tiles_total": plan.n_tiles,
                "tiles_solved": plan.n_tiles, "tiles_resumed": 0, "resumed": False,
                "timings": timings, "exposure_fitted": False, "surface_skipped": False,
                "refinement": "pending" if two else "none",
                "seconds_per_pixel": timings["solve_s"] / int(np.prod(plan.image))}
        if two:  # begun before stage 1 completes: the store never looks refined
            st.begin_stage(group, REFINE, {"run": key})
        st.complete_stage(group, "reconstruct", info)
        return info

    def refine(self, group: zarr.Group, *, progress: bool, key: dict, again: bool) -> dict:
        """Stage 2 (:func:`refine_far`); ``again``: in another run than stage 1 (its fit
        prepared again, in ``refine_prepare_s``)."""
        start = time.perf_counter()
        record = st.stages(group)["reconstruct"]
        st.begin_stage(group, REFINE, {"run": key})
        timings = {"refine_prepare_s": self.timings["prepare_s"]} if again else {}
        models, n_lights = self.models, len(self.train)
        with _pool() as pool:
            first = self.choose(pool)
            loo_choice = models[pick(self.mse.mean(axis=0), models, n_lights)]
            classic, surface = _surface(group, self.valid, self.train, loo_choice, models,
                                        self.method, timings, self.frames, progress)
            chosen = first
            if classic != loo_choice:  # held-out lights prefer another classic model
                chosen = choose_tiles(self.mse, models, n_lights,
                                      common=models.index(classic)).reshape(self.plan.grid)
            names = [m.name for m in models]
            if surface is not None:
                chosen = np.full_like(first, len(names))
                names.append(surface[1].name)
            if surface is not None or not np.array_equal(chosen, first):
                self.write_tiles(group, pool, chosen, desc="reconstruct 2/2 surface: tiles",
                                 progress=progress, surface=surface)
                write_method_map(group, self.plan, chosen, names,
                                 "leave-one-light-out error")
        timings["refine_s"] = time.perf_counter() - start
        gain = np.ones(1) if surface is None else surface[2]
        info = {**record, **_chosen(chosen, names), "refinement": "done",
                "exposure_fitted": bool((gain != 1).any()),
                "surface_skipped": "surface_skipped_s" in timings,
                "timings": {**record["timings"], **timings,
                            "solve_s": record["timings"]["solve_s"] + timings["refine_s"]}}
        info["seconds_per_pixel"] = info["timings"]["solve_s"] / int(np.prod(self.plan.image))
        # the reconstruct record again, with what it wrote (on a copy swapped in when complete)
        st.complete_stage(group, "reconstruct", info)
        st.complete_stage(group, REFINE, {"run": key, "timings": timings,
                                          "separate_run": again})  # last
        return st.stages(group)["reconstruct"]


def _chosen(chosen: np.ndarray, names: list[str]) -> dict:
    """``chosen_per_tile`` and ``methods_per_tile``: how many tiles took each model."""
    counts = {names[i]: int(c) for i, c in zip(*np.unique(chosen, return_counts=True),
                                                strict=True)}
    return {"chosen_per_tile": counts, "methods_per_tile": dict(counts)}


def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1))


def _surface(group: zarr.Group, valid: np.ndarray, train: np.ndarray, classic: Model,
             models: tuple[Model, ...], method: str, timings: dict, luma: np.ndarray,
             progress: bool
             ) -> tuple[Model, tuple[np.ndarray, sf.Blend, np.ndarray, np.ndarray | None] | None]:
    """The image's classic model and the surface model (:mod:`ltmstore.stages.surface`).

    With ``method="physical"`` the surface is fitted to the whole image and mixed with nothing.
    With ``auto``, held-out lights of a sample of the pixels score ``classic`` (the image's
    leave-one-out choice, the surface's partner in a blend), every other model of ``models``
    and the surface variants (:func:`~ltmstore.stages.surface.cross_validated`, the lobe's
    distribution chosen first, :func:`~ltmstore.stages.surface.choose_lobe`): the best
    classic model is the image's, and the surface is fitted only where it lowers that model's
    held-out error by :data:`~ltmstore.stages.surface.MARGIN`; where it does not, the fit of
    every pixel is skipped and the time it would have taken (estimated from the choice's own
    fits) is recorded as ``surface_skipped_s``.

    Returns the classic model and, where the surface is fitted, its parameters ``(y, x, 3,
    6)``, its :class:`~ltmstore.stages.surface.Blend`, the valid frames' exposures (ones
    unless chosen) and the height casting its shadows (None where the held-out choice,
    :func:`~ltmstore.stages.surface.choose_shadows`, leaves them out); its maps (and the
    height, :data:`~ltmstore.stages.surface.SHADOW_HEIGHT`) are written to the store. The
    frames' RGB is read band by band of rows (:func:`~ltmstore.stages.surface.row_bands`),
    never whole: once for the sample, once for the fit.
    """
    start = time.perf_counter()
    n_pixels = luma.shape[1] * luma.shape[2]
    sample = np.sort(np.random.default_rng(0).permutation(n_pixels)[:sf.CHOICE_PIXELS])
    chosen = sf.sample_rgb(group, valid, luma, sample)  # luma: the valid frames, already read
    exposure, weight, lobe = False, 1.0, "ggx"
    if method == "auto":
        with tqdm(total=2, desc="reconstruct 2/2 surface: choice", unit="step",
                  disable=not progress) as bar:  # the lobe, then the held-out scores
            lobe, timings["surface_lobe_loo_mse"] = sf.choose_lobe(chosen, train)
            bar.update()
            timings["surface_lobe"] = lobe
            scores = sf.cross_validated(chosen, train, classic, classics=models, lobe=lobe)
            bar.update()
        timings["surface_choice_s"] = time.perf_counter() - start
        best = sf.best_classic(scores, classic, models, len(train))
        key = None if best == classic else best.name
        timings["surface_heldout_mse"] = {
            classic.name: scores[None], best.name: scores[key],
            **{f"exposure={k[0]},weight={k[1]:g}": v for k, v in scores.items()
               if isinstance(k, tuple)}}
        surface = sf.choose_surface(scores, key)
        if surface is None:
            # the choice fitted a surface of each lobe to the sample, and 2 FOLDS more (3/4 of
            # the lights each)
            fits = 2 * sf.FOLDS + len(physical.LOBES)
            per_pixel = timings["surface_choice_s"] / (fits * len(sample))
            timings["surface_skipped_s"] = per_pixel * n_pixels
            return best, None
        exposure, weight = surface
    gain = np.ones(len(train), dtype=np.float32)
    if exposure:
        gain[:] = sf.exposures(chosen, train, lobe=lobe)
        chosen /= gain[:, None, None]
        _write_exposure(group, valid, gain)
    theta = _fit_bands(group, valid, luma, train, gain, lobe, progress)
    sf.write_surface(group, theta, lobe)
    encoded = linear_to_srgb((chosen @ LUMA).astype(np.float32))
    at_sample = theta.reshape(-1, 3, 6)[sample]
    height, softness, visible = _shadows(group, theta, encoded, at_sample, train, sample, lobe,
                                         timings)
    smoother = sf.choose_smoother(encoded, at_sample, train, lobe, visible)
    timings["surface_s"] = time.perf_counter() - start
    return classic, (theta, sf.Blend(smoother, classic, weight, lobe, softness), gain, height)


def _shadows(group: zarr.Group, theta: np.ndarray, encoded: np.ndarray, at_sample: np.ndarray,
             train: np.ndarray, sample: np.ndarray, lobe: str, timings: dict
             ) -> tuple[np.ndarray | None, float, np.ndarray | None]:
    """The surface's cast shadows where they lower its held-out error
    (:func:`~ltmstore.stages.surface.choose_shadows`, on the sampled pixels): the height
    casting them (written to the store), their softness and their visibility at the sampled
    pixels ``(p, t)``; ``(None, 0, None)`` where they are left out."""
    from ltmstore.solve.height import integrate  # SciPy's FFT: stage 2 only (0.1-0.2 s)

    start = time.perf_counter()
    normal = physical.unit_normal(theta[..., 0, 0].ravel(), theta[..., 0, 1].ravel())
    height = integrate(normal.reshape(*theta.shape[:2], 3)).astype(np.float32)
    horizon = shadows.horizons(height, *np.unravel_index(sample, height.shape), train)
    chosen, timings["shadow_scores"] = sf.choose_shadows(encoded, at_sample, train, horizon,
                                                         lobe)
    timings["shadow_choice_s"] = time.perf_counter() - start
    if chosen is None:
        return None, 0.0, None
    scale, softness = chosen
    height *= scale
    arr = st.create_variable(group, sf.SHADOW_HEIGHT, ("y", "x"), height.shape,
                             chunks=tuple(min(n, sf.MAP_CHUNK) for n in height.shape),
                             attrs={"units": "pixels", "scale": scale, "softness": softness})
    arr[...] = height
    return height, softness, shadows.visible(train, scale * horizon, softness)


def _fit_bands(group: zarr.Group, valid: np.ndarray, luma: np.ndarray, train: np.ndarray,
               gain: np.ndarray, lobe: str, progress: bool) -> np.ndarray:
    """The surface's parameters ``(y, x, 3, 6)`` of every pixel, fitted band by band of rows
    to the valid frames divided by their exposures ``gain``."""
    theta = np.empty((*luma.shape[1:], 3, 6))
    bands = sf.row_bands(luma.shape)
    for rows in tqdm(bands, desc="reconstruct 2/2 surface: fit", unit="band",
                     disable=not progress):
        rgb = sf.frames_rgb(group, valid, luma, rows)
        rgb /= gain[:, None, None, None]
        theta[rows] = sf.fit_image(rgb, train, lobe, workers=min(2, os.cpu_count() or 1))
        del rgb  # before the next band is read
    return theta


def _load_kernels() -> None:
    """Numba and the surface fit's compiled kernels (about 1-1.5 s of one core, mostly holding
    the GIL), loaded while stage 2 copies the store and reads the frames' colour."""
    from ltmstore.solve.physical_far import warm_up

    warm_up()


def _write_exposure(group: zarr.Group, valid: np.ndarray, gain: np.ndarray) -> None:
    """``exposure (t)``: the valid frames' exposures (:func:`~ltmstore.stages.surface.exposures`),
    1 for the others; relighting divides the frames by it."""
    values = np.ones(len(valid), dtype=np.float32)
    values[valid] = gain
    arr = st.create_variable(group, sf.EXPOSURE, ("t",), values.shape, chunks=values.shape)
    arr[...] = values


def _loo_mse(values: np.ndarray, loo: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Leave-one-out MSE of every model ``(models,)`` on the pixels ``values (n, p)``; ``loo``
    stacks the models' :func:`~ltmstore.solve.lightfit.loo_operator` ``(models, n, n)``.

    The mean of the squared residuals ``A V`` is ``trace(A G A^T) / (n p)`` with the Gram matrix
    ``G = V V^T`` of the pixels: one ``(n, n)`` product per tile, then ``n^3`` per model instead
    of ``n^2 p`` (float64: the residuals are small differences of large values).
    """
    values = values.astype(np.float64)
    gram = values @ values.T
    mse = np.einsum("mij,mij->m", loo @ gram, loo) / values.size
    return np.where(usable, mse, np.inf)


def choose_tiles(mse: np.ndarray, models: tuple[Model, ...], n_lights: int, *,
                 common: int | None = None) -> np.ndarray:
    """The model of each tile from its leave-one-out MSE ``(tiles, models)``.

    The whole image's choice (``common``, an index of ``models``; by default the lowest mean
    MSE over tiles, the smaller model winning a tie) holds for
    every tile unless the tile's own best lowers the tile's MSE by more than
    :data:`LEAVE_GLOBAL` times the image's mean MSE: a tile's leave-one-out estimate is noisy,
    and lights left out of a dome are not the lights between its rings. Following each tile's
    own choice (or a 10 % relative gain) cost up to 0.8 dB on held-out photographs (SynthRTI
    multi-obj1-material1, coin); this rule lets a tile go its own way only where it matters to
    the image, such as a specular object on a matte ground.
    """
    if common is None:
        common = pick(mse.mean(axis=0), models, n_lights)
    own = np.array([pick(row, models, n_lights) for row in mse])
    gain = mse[:, common] - mse[np.arange(len(mse)), own]
    return np.where(gain > LEAVE_GLOBAL * mse[:, common].mean(), own, common).astype(np.int16)
