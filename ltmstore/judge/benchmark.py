"""``ltm bench``: every method, speed against accuracy, over path density and lattice size.

Cases are simulated at the samples level with real rendering: frames rendered at the true
(continuous) light positions along a handheld trajectory, sensor noise, binned at the tracker's
positions onto the lattice (box kernel), and scored against the ground-truth LTM at the cell
centres (SNR_Y on a fixed random subset of pixels, the same for every method). Time per pixel is
the median over repeats on one thread; peak memory is what ``tracemalloc`` sees during a
separate solve of a quarter of the pixels, scaled to the whole batch.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
import tracemalloc
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import dask.array as da
import numpy as np
from threadpoolctl import threadpool_limits
from zarr.storage import LocalStore

from ltmstore.core.dims import LUMA, Lattice
from ltmstore.core.provenance import version
from ltmstore.core.store import CountingStore, open_store
from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import METHODS, Geometry, get_method
from ltmstore.solve.select import choose_params
from ltmstore.stages.relight import relight
from ltmstore.stages.resample import bin_frames, bin_positions
from ltmstore.synthetic.render import GGX, Shading, iter_frames, render_ltm
from ltmstore.synthetic.simulate import EXPOSURE_PEAK, plan_simulation

SCENES = ("canvas", "icon", "relief")
DENSITIES = (8.0, 15.0, 27.0, 45.0)
LATTICES = (16, 24, 32)
DEFAULT_LATTICE = 32
# Settings shown as separate points on the speed-accuracy chart.
SETTINGS = {"cs": [{"n_iter": 10}, {}, {"n_iter": 100}, {"lam_min": 3e-3}, {"lam_min": 3e-4},
                   {"auto": True}], "kernel": [{"order": 0}, {}],
            "hsh": [{"order": 2}, {}], "rbf": [{}], "lars": [{}]}
SLOW = ("lars", "svt")  # per-pixel LARS; SVT's iterated SVDs
NOISE = 0.003  # sensor noise, linear units (about 0.3 % of the peak)


@dataclass(frozen=True, eq=False)
class Case:
    """Binned samples of a simulated capture and the truth on the same lattice."""

    scene: str
    path_density: float
    samples: np.ndarray  # (n, R, S)
    truth: np.ndarray  # (n, R, S)
    geometry: Geometry

    @property
    def ratio(self) -> float:
        return float(np.isfinite(self.samples).any(axis=0).mean())


def simulate_frames(scene: str, path_density: float, *, size: int, seed: int,
                    shading: Shading = GGX):
    """Luminance frames at the true light positions, the recorded positions, and the plan."""
    plan = plan_simulation(scene=scene, path_density=path_density, seed=seed, size=size)
    lights = plan.frame_lights()
    frames = np.stack([f @ LUMA.astype(np.float32)
                       for f in iter_frames(plan.scene, lights, shading=shading)])
    r, s, z = plan.tracker.at(plan.frame_times)
    valid = np.abs(z - plan.plane.height) <= 0.05 * plan.plane.height
    return frames, (r, s, valid), plan


def make_cases(scene: str, path_density: float, lattices, *, size: int, seed: int,
               shading: Shading = GGX) -> list[Case]:
    """One :class:`Case` per lattice side in ``lattices`` for one simulated trajectory, rendered
    with ``shading`` (:data:`~ltmstore.synthetic.render.MISMATCHED`: physics no fitted model
    assumes)."""
    frames, (r, s, valid), plan = simulate_frames(scene, path_density, size=size, seed=seed,
                                                  shading=shading)
    rng = np.random.default_rng(seed)
    cases = []
    for n in lattices:
        lattice = Lattice.from_plane(plan.plane, (n, n))
        truth = render_ltm(plan.scene, lattice, plan.plane.height,
                           shading=shading) @ LUMA.astype(np.float32)
        exposure = EXPOSURE_PEAK / float(truth.max())
        noisy = frames * exposure + rng.normal(0, NOISE, frames.shape).astype(np.float32)
        binned = bin_frames(da.from_array(noisy), bin_positions(lattice, (r, s), valid))
        cases.append(Case(scene=scene, path_density=path_density,
                          samples=np.asarray(binned.compute()).reshape(-1, n, n),
                          truth=(truth * exposure).reshape(-1, n, n),
                          geometry=Geometry(lattice=lattice, height=plan.plane.height,
                                            pixels=_pixels(plan.scene))))
    return cases


def _pixels(scene) -> np.ndarray:
    """Object-plane ``(X, Y)`` of every pixel of ``scene``, ``(n, 2)`` in C order of ``(y, x)``."""
    x, y = scene.pixel_centres()
    return np.column_stack([x.ravel(), y.ravel()])


def measure(case: Case, method: str, params: dict, rows: np.ndarray, *, repeats: int) -> dict:
    """SNR_Y, median time per pixel and peak memory of one method on one case."""
    batch, geometry = case.samples[rows], case.geometry.take(rows)
    solve = partial(_auto, method=method) if params.get("auto") else get_method(method)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        estimate = solve(batch, geometry, **params)
        times.append(time.perf_counter() - start)
    tracemalloc.start()  # a separate run: tracing slows allocation-heavy code
    quarter = np.arange(max(1, len(batch) // 4))
    solve(batch[quarter], geometry.take(quarter), **params)
    peak = tracemalloc.get_traced_memory()[1] * len(batch) / max(1, len(batch) // 4)
    tracemalloc.stop()
    return {"scene": case.scene, "path_density": case.path_density,
            "lattice": case.geometry.shape[0], "sampling_ratio": case.ratio, "method": method,
            "params": params, "pixels": len(rows),
            "snr_db": snr_db(case.truth[rows], estimate),
            "ms_per_pixel": 1e3 * statistics.median(times) / len(rows),
            "peak_mib": peak / 2**20, "repeats": repeats}


def _auto(batch: np.ndarray, geometry: Geometry, *, method: str, auto: bool) -> np.ndarray:
    """Choose the regularisation by held-out error (as ``ltm reconstruct`` does), then solve."""
    choice = choose_params(batch, geometry, method, params={})
    return get_method(method)(batch, geometry, **choice.params)


def run(*, scenes=SCENES, densities=DENSITIES, lattices=LATTICES, size: int = 32,
        pixels: int = 128, slow_pixels: int = 32, repeats: int = 3, seed: int = 0,
        progress=print) -> list[dict]:
    """The whole sweep; one record per (scene, density, lattice, method, setting).

    Every method runs on the default lattice; the other lattices run ``cs`` only (the paper's
    Fig. 9). The slow methods (:data:`SLOW`) run on ``slow_pixels`` pixels, once.
    """
    with threadpool_limits(1):
        return _sweep(scenes, densities, lattices, size=size, pixels=pixels,
                      slow_pixels=slow_pixels, repeats=repeats, seed=seed, progress=progress)


def _sweep(scenes, densities, lattices, *, size, pixels, slow_pixels, repeats, seed,
           progress) -> list[dict]:
    records = []
    for scene in scenes:
        for density in densities:
            for case in make_cases(scene, density, lattices, size=size, seed=seed):
                n_px = len(case.samples)
                on_default = case.geometry.shape[0] == DEFAULT_LATTICE
                for method in sorted(METHODS) if on_default else ["cs"]:
                    slow = method in SLOW
                    rows = np.random.default_rng(seed).choice(
                        n_px, size=min(slow_pixels if slow else pixels, n_px), replace=False)
                    for params in SETTINGS.get(method, [{}]) if on_default else [{}]:
                        rec = measure(case, method, params, rows, repeats=1 if slow else repeats)
                        records.append(rec)
                        progress(json.dumps(rec))
    return records


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points not beaten in both time (lower) and SNR (higher), by time."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], -np.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def _label(rec: dict) -> str:
    extra = ",".join(f"{k}={v}" for k, v in rec["params"].items())
    return rec["method"] + (f"({extra})" if extra else "")


def summarise(records: list[dict], *, density: float = 27.0) -> list[dict]:
    """Per method and setting, at the default lattice and ``density``: mean SNR over scenes and
    median time per pixel (the points of the speed-accuracy chart)."""
    groups: dict[str, list[dict]] = {}
    for rec in records:
        if rec["lattice"] == DEFAULT_LATTICE and rec["path_density"] == density:
            groups.setdefault(_label(rec), []).append(rec)
    return sorted(({"label": k, "snr_db": float(np.mean([r["snr_db"] for r in v])),
                    "ms_per_pixel": float(np.median([r["ms_per_pixel"] for r in v])),
                    "peak_mib": float(np.max([r["peak_mib"] for r in v])),
                    "snr_db_by_scene": {r["scene"]: r["snr_db"] for r in v}}
                   for k, v in groups.items()), key=lambda d: -d["snr_db"])


def charts(records: list[dict], out: Path) -> dict[str, str]:
    """Speed against accuracy (Pareto front marked), SNR against path density (the paper's
    Fig. 10) and SNR over path density x lattice for ``cs`` (its Fig. 9)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    points = summarise(records)
    fig, ax = plt.subplots(figsize=(7, 5))
    xy = [(p["ms_per_pixel"], p["snr_db"]) for p in points]
    front = pareto_front(xy)
    for i, p in enumerate(points):
        ax.scatter(*xy[i], s=50, c="tab:red" if i in front else "tab:blue")
        ax.annotate(p["label"], xy[i], fontsize=7, xytext=(5, 9 * (i % 3) - 9),
                    textcoords="offset points")  # staggered: close points stay legible
    fx, fy = zip(*sorted(xy[i] for i in front), strict=True)
    ax.step(fx, fy, where="post", c="tab:red", lw=1, label="Pareto front")
    ax.set_xscale("log")
    ax.set(xlabel="time per pixel, ms (median, one thread)",
           ylabel="SNR_Y, dB (mean over canvas, icon, relief)",
           title=f"Speed against accuracy: {DEFAULT_LATTICE}x{DEFAULT_LATTICE} lattice, "
                 "path density 27/m")
    ax.legend()
    fig.tight_layout()
    paths["speed_accuracy"] = out / "speed_accuracy.png"
    fig.savefig(paths["speed_accuracy"], dpi=120)

    fig, axes = plt.subplots(1, len(SCENES), figsize=(14, 4), sharey=True)
    for ax, scene in zip(axes, SCENES, strict=True):
        for method in sorted(METHODS):
            pts = sorted((r["path_density"], r["snr_db"]) for r in records
                         if r["scene"] == scene and r["method"] == method and not r["params"]
                         and r["lattice"] == DEFAULT_LATTICE)
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=method)
        ax.set(title=scene, xlabel="path density (1/m)")
    axes[0].set_ylabel("SNR_Y (dB)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    paths["snr_vs_density"] = out / "snr_vs_density.png"
    fig.savefig(paths["snr_vs_density"], dpi=120)

    fig, axes = plt.subplots(1, len(SCENES), figsize=(14, 4))
    dens = sorted({r["path_density"] for r in records})
    lats = sorted({r["lattice"] for r in records})
    for ax, scene in zip(axes, SCENES, strict=True):
        grid = np.full((len(lats), len(dens)), np.nan)
        for r in records:
            if r["scene"] == scene and r["method"] == "cs" and not r["params"]:
                grid[lats.index(r["lattice"]), dens.index(r["path_density"])] = r["snr_db"]
        im = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, f"{v:.1f}", ha="center", va="center", fontsize=8, color="w")
        ax.set_xticks(range(len(dens)), [f"{d:g}" for d in dens])
        ax.set_yticks(range(len(lats)), [f"{400 / n:.1f}" for n in lats])
        ax.set(title=f"cs, {scene}", xlabel="path density (1/m)", ylabel="delta_rs (mm)")
        fig.colorbar(im, ax=ax, label="SNR_Y (dB)")
    fig.tight_layout()
    paths["snr_density_delta"] = out / "snr_density_delta.png"
    fig.savefig(paths["snr_density_delta"], dpi=120)
    plt.close("all")
    return {k: str(v) for k, v in paths.items()}


def random_lights(plane: dict, n: int, *, seed: int = 0) -> np.ndarray:
    """``n`` point lights drawn uniformly over a plane rectangle (``acquisition["plane"]``)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(*plane["r"], n), rng.uniform(*plane["s"], n)])


def relight_cost(store: Path, lights: np.ndarray) -> dict:
    """Median time and bytes read (counted at the Zarr store) of relighting one point light,
    each light on a freshly opened store so that nothing is cached."""
    seconds, nbytes = [], []
    for light in lights:
        counting = CountingStore(LocalStore(str(store), read_only=True))
        start = time.perf_counter()
        relight(open_store(counting), [light], color=False).compute()
        seconds.append(time.perf_counter() - start)
        nbytes.append(counting.bytes_read)
    return {"seconds_median": statistics.median(seconds),
            "bytes_read_median": statistics.median(nbytes), "repeats": len(lights)}


def warm_relight_cost(store: Path, lights: np.ndarray) -> dict:
    """Median time of relighting one point light on a store opened once, as a notebook relights
    light after light: the first light a warm-up, left out."""
    ds = open_store(store)
    relight(ds, [lights[0]], color=False).compute()
    seconds = []
    for light in lights[1:]:
        start = time.perf_counter()
        relight(ds, [light], color=False).compute()
        seconds.append(time.perf_counter() - start)
    return {"seconds_median": statistics.median(seconds), "seconds": seconds,
            "repeats": len(seconds)}


def write(records: list[dict], out: Path, *, command: str) -> dict:
    """``bench.json`` (records, summary, machine) and the charts, under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    paths = charts(records, out)
    result = {"command": command, "ltmstore": version(),
              "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
              "summary": summarise(records), "records": records, "charts": paths}
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n")
    return result
