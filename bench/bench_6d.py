"""6D scale benchmark: the paper's section IV-F configuration, reconstructed out of core.

128 x 128 pixels x 25 x 25 lights x 16 x 16 views (a 10.7 GB float32 LTM) at an overall sampling
ratio K/M about 0.165, on the ``relief`` scene (raised features: parallax and cast shadows), both
devices scribbling. Stages (each can be skipped when its output exists, ``--reuse``):

1. ``simulate``: the acquisition folder (camera B's frames, poses with ``p, q``), no truth store;
2. ``ingest``: registration of every frame onto the object grid;
3. ``reconstruct``: binning onto ``(r, s, p, q)`` and the 4D-DCT compressive-sensing solve, one
   Dask task per pixel tile, on a 2-worker LocalCluster; peak memory of the whole process tree;
4. ``evaluate``: SNR_Y on a seeded random subset of the lattice cells (all pixels of each),
   rendered on the fly (rendering the whole 10.7 GB truth would take longer than the
   reconstruction), the bytes one (light, view) query reads, and a GIF where the light and the
   viewpoint both move.

Run: ``nice python bench/bench_6d.py`` (``--config small`` for a quick check). Writes
``bench/results/scale_6d[_small].json`` and ``.gif``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).parent))
from scale_bench import PeakMemory  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.core.dims import LUMA, Lattice  # noqa: E402
from ltmstore.core.store import CountingStore, open_group, open_store  # noqa: E402
from ltmstore.stages.ingest import ingest  # noqa: E402
from ltmstore.stages.reconstruct import reconstruct  # noqa: E402
from ltmstore.synthetic.render import PinholeCamera, _Renderer  # noqa: E402
from ltmstore.synthetic.scenes import make_scene  # noqa: E402
from ltmstore.synthetic.simulate import VIEW_PLANE, simulate_acquisition  # noqa: E402

CONFIGS = {
    # The paper's 6D experiment: 25 x 25 lights x 16 x 16 views, K/M 0.1656.
    "paper": {"size": 128, "lattice": (25, 25, 16, 16), "path_density": 3300.0, "speed": 0.5,
              "view_speed": 0.15, "tile": 8, "cells": 96},
    "small": {"size": 32, "lattice": (10, 10, 6, 6), "path_density": 140.0, "speed": 0.5,
              "view_speed": 0.15, "tile": 8, "cells": 96},
}
PAPER_SNR_DB = 20.8  # section IV-F, ray-traced scene, K/M 0.1656


def truth_at_cells(acq: Path, cells: np.ndarray, lattice: Lattice) -> np.ndarray:
    """Ground-truth luminance images ``(n, H, W)`` at lattice cells ``(n, 4)``, in frame units."""
    meta = json.loads((acq / "acquisition.json").read_text())
    sim = meta["simulation"]
    scene = make_scene(sim["scene"], size=sim["size"], seed=sim["seed"])
    height, distance = meta["plane"]["height"], meta["view_plane"]["distance"]
    centres = [lattice.centres(i) for i in range(4)]
    renderer = _Renderer(scene)
    out = np.empty((len(cells), *scene.shape), dtype=np.float32)
    for n, (i, j, k, m) in enumerate(cells):
        renderer.set_camera(PinholeCamera(centres[2][k], centres[3][m], distance, 1.0))
        rgb = renderer.rectified(np.array([centres[0][i], centres[1][j], height]))
        out[n] = rgb @ LUMA.astype(np.float32) * np.float32(sim["exposure"])
    return out


def sampled_snr(store: Path, acq: Path, n_cells: int, seed: int = 0) -> dict:
    """SNR_Y over ``n_cells`` seeded random lattice cells (every pixel of each)."""
    group = open_group(store)
    ltm = group["ltm"]
    lattice = Lattice(**{k: tuple(map(tuple, v)) if k == "bounds" else tuple(v)
                         for k, v in group.attrs["stages"]["resample"]["lattice"].items()
                         if k in ("bounds", "shape", "dims")})
    rng = np.random.default_rng(seed)
    flat = rng.choice(lattice.size, size=n_cells, replace=False)
    cells = np.column_stack(np.unravel_index(flat, lattice.shape))
    truth = truth_at_cells(acq, cells, lattice)
    est = np.stack([ltm[(slice(None), slice(None), *map(int, c))] for c in cells])
    num, den = float((truth.astype(np.float64) ** 2).sum()), float(
        ((truth - est).astype(np.float64) ** 2).sum())
    per_cell = 10 * np.log10((truth.astype(np.float64) ** 2).sum((1, 2))
                             / np.maximum(((truth - est) ** 2).sum((1, 2)), 1e-30))
    return {"snr_y_db": 10 * np.log10(num / den), "cells": int(n_cells), "seed": seed,
            "per_cell_snr_db_median": float(np.median(per_cell)),
            "per_cell_snr_db_p10_p90": [float(np.percentile(per_cell, 10)),
                                        float(np.percentile(per_cell, 90))]}


def query_cost(store: Path, light, view) -> dict:
    """Bytes and reads of one (light, view) point query, against the whole ``ltm``."""
    from ltmstore.stages.relight import relight

    counting = CountingStore(__import__("zarr").storage.LocalStore(str(store), read_only=True))
    ds = open_store(counting)
    start = time.perf_counter()
    relight(ds, [light], view=view, color=False).compute()
    seconds = time.perf_counter() - start
    total = sum(f.stat().st_size for f in (store / "ltm").rglob("*") if f.is_file())
    return {"seconds": seconds, "bytes_read": counting.bytes_read, "reads": counting.reads,
            "ltm_bytes_on_disk": total, "fraction": counting.bytes_read / max(total, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", choices=sorted(CONFIGS), default="paper")
    parser.add_argument("--work", default="/tmp/ltm-6d")
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--reuse", action="store_true", help="skip stages whose output exists")
    parser.add_argument("--stages", default="simulate,ingest,reconstruct,evaluate")
    parser.add_argument("--n-iter", type=int, default=None, help="cs iterations (default: cs's)")
    parser.add_argument("--cells", type=int, default=None,
                        help="lattice cells rendered for the sampled SNR_Y (default: config's)")
    args = parser.parse_args()
    cfg = CONFIGS[args.config]
    stages = args.stages.split(",")
    work = Path(args.work) / args.config
    work.mkdir(parents=True, exist_ok=True)
    acq, store = work / "acq", work / "store.zarr"
    suffix = "" if args.config == "paper" else f"_{args.config}"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result_path = out / f"scale_6d{suffix}.json"
    result = json.loads(result_path.read_text()) if result_path.exists() else {}
    result.update({"config": args.config, **{k: list(v) if isinstance(v, tuple) else v
                                             for k, v in cfg.items()},
                   "command": "nice python bench/bench_6d.py " + " ".join(sys.argv[1:]),
                   "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                               "memory_gib": psutil.virtual_memory().total / 2**30},
                   "ltmstore": __version__, "paper_snr_y_db": PAPER_SNR_DB})
    times = result.setdefault("timings", {})

    def save() -> None:
        result_path.write_text(json.dumps(result, indent=2, default=str) + "\n")

    if "simulate" in stages and not (args.reuse and (acq / "acquisition.json").exists()):
        start = time.perf_counter()
        sim = simulate_acquisition(acq, scene="relief", size=cfg["size"], seed=0,
                                   lattice=cfg["lattice"], path_density=cfg["path_density"],
                                   view=True, speed=cfg["speed"], view_speed=cfg["view_speed"],
                                   truth=False, overwrite=True, progress=True)
        times["simulate_s"] = time.perf_counter() - start
        result["simulation"] = {k: sim[k] for k in ("frames", "sampling_ratio", "exposure",
                                                     "path_density", "duration_s")}
        save()
    if "ingest" in stages and not (args.reuse and (store / "zarr.json").exists()):
        start = time.perf_counter()
        with PeakMemory() as memory:
            rec = ingest(acq, store, overwrite=True, progress=True, chunk_frames=256)
        times["ingest_s"] = time.perf_counter() - start
        result["ingest"] = {"n_frames": rec["n_frames"], "n_valid": rec["n_valid"],
                            "peak_memory_gib": memory.peak / 2**30}
        save()
    if "reconstruct" in stages:
        params = {} if args.n_iter is None else {"n_iter": args.n_iter}
        start = time.perf_counter()
        with PeakMemory() as memory:
            info = reconstruct(store, lattice=cfg["lattice"], color=False, auto=False,
                               resume=False, params=params, tile=cfg["tile"], overwrite=True,
                               progress=True)
        times["reconstruct_s"] = time.perf_counter() - start
        result["reconstruct"] = {
            "K": info["K"], "M": info["M"], "sampling_ratio": info["sampling_ratio"],
            "pixel_sampling_ratio": info.get("pixel_sampling_ratio"),
            "timings": info["timings"], "params": params, "auto": False,
            "plan": info["plan"], "seconds_per_pixel_solve": info["seconds_per_pixel"],
            "peak_memory_gib": memory.peak / 2**30, "workers": 2}
        result["ltm_gb_float32"] = 4 * cfg["size"] ** 2 * int(np.prod(cfg["lattice"])) / 1e9
        save()
    if "evaluate" in stages:
        start = time.perf_counter()
        result["accuracy"] = sampled_snr(store, acq, args.cells or cfg["cells"])
        result["accuracy"]["note"] = (
            "SNR_Y = 20 log10(||T|| / ||T - T_hat||) over a seeded random subset of lattice "
            "cells (all pixels of each); the truth is rendered at those cells only")
        times["evaluate_s"] = time.perf_counter() - start
        centre = (0.0, 0.0)
        result["query"] = query_cost(store, centre, (VIEW_PLANE.r[1] / 2, 0.0))
        n = 36
        angle = np.linspace(0, 2 * np.pi, n, endpoint=False)
        lights = np.column_stack([0.15 * np.cos(angle), 0.15 * np.sin(angle)])
        views = np.column_stack([0.08 * np.cos(-2 * angle), 0.08 * np.sin(-2 * angle)])
        from ltmstore.stages.relight import write_gif

        gif = out / f"scale_6d{suffix}.gif"
        write_gif(store, gif, lights, views)
        result["gif"] = str(gif)
        save()
    print(json.dumps(result, indent=2, default=str))


if __name__ == "__main__":
    main()
