"""Relight latency: one point light and one area light on a 0.25 MP store, warm, with bytes read.

Run: ``python bench/relight_latency.py`` (builds the store once under ``--work``: a simulated
500 x 500 px canvas on a 50 x 50 lattice over a 40 cm plane, the Toys size of the scale bench;
simulate + ingest + reconstruct take 10-20 minutes on 2 cores) or ``--store PATH`` for an
existing reconstructed near-light store. Writes ``relight_latency.json`` and
``relight_latency.png`` into ``--out``.

Each layout is opened once (through a byte-counting Zarr store); after one warm-up call, 10
different lights are relit one at a time (``relight(...).compute()``, colour), and the median
seconds and bytes read per call are reported (3 lights for the slow pixel-major baseline):

* ``pixel-major``: the ``ltm`` alone, as before the light-major copy (``ltm_by_light`` hidden);
* ``light-major``: the store as reconstructed now (relight reads ``ltm_by_light``);
* ``light-major float16``: after ``ltm compact --precision float16`` (on a copy).

The point light is a random position inside the plane; the area light a uniform disk of
radius 5 cm (:func:`ltmstore.stages.relight.disk_light`, about 120 cells of 8 mm); the
environment a weight on every cell (reported, not a target).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from zarr.storage import LocalStore

from ltmstore import __version__
from ltmstore.core.dims import Plane
from ltmstore.core.store import CountingStore, open_store
from ltmstore.stages.by_light import by_light_name
from ltmstore.stages.compact import compact, store_bytes
from ltmstore.stages.relight import disk_light, relight

PLANE = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)
SIZE, LATTICE, DENSITY = 500, (50, 50), 53.0
REPEATS = 10
AREA_RADIUS = 0.05
TARGETS = {"point": 0.1, "area": 1.0}


def build(work: Path) -> Path:
    """The bench store: simulate, ingest, reconstruct (luminance LTM), once."""
    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct
    from ltmstore.synthetic.simulate import simulate_acquisition

    store = work / "store.zarr"
    if store.exists():
        return store
    simulate_acquisition(work / "acq", scene="canvas", size=SIZE, seed=0, lattice=LATTICE,
                         plane=PLANE, path_density=DENSITY, truth=False, overwrite=True)
    ingest(work / "acq", store)
    reconstruct(store, lattice=LATTICE, color=False)
    return store


def folder_bytes(store: Path, name: str) -> int:
    folder = store / name
    return store_bytes(folder) if folder.is_dir() else 0


def time_calls(ds: xr.Dataset, counting: CountingStore, queries: list) -> dict:
    """Median seconds and bytes read of ``relight(ds, q).compute()`` over ``queries`` (the first
    call, a warm-up, left out)."""
    relight(ds, queries[0]).compute()
    seconds, nbytes = [], []
    for query in queries[1:]:
        counting.bytes_read = 0
        start = time.perf_counter()
        relight(ds, query).compute()
        seconds.append(time.perf_counter() - start)
        nbytes.append(counting.bytes_read)
    return {"seconds_median": statistics.median(seconds), "seconds": seconds,
            "bytes_read_median": statistics.median(nbytes), "repeats": len(seconds)}


def measure(store: Path, *, light_major: bool, rng: np.random.Generator) -> dict:
    """Point, area (and, light-major, environment) lights; the pixel-major baseline is slow
    (its area light reads most of the LTM): 3 repeats there."""
    counting = CountingStore(LocalStore(str(store), read_only=True))
    ds = open_store(counting)
    if not light_major:
        ds = ds.drop_vars([v for v in ds.data_vars if v.endswith("_by_light")])
    ltm = ds["ltm"]
    repeats = REPEATS if light_major else 3
    lo, hi = np.array([PLANE.r[0], PLANE.s[0]]), np.array([PLANE.r[1], PLANE.s[1]])
    points = lo + 0.1 + (hi - lo - 0.2) * rng.random((repeats + 1, 2))
    areas = [disk_light(ltm, p, AREA_RADIUS) for p in points]
    row = {"point": time_calls(ds, counting, [[tuple(p)] for p in points]),
           "area": {**time_calls(ds, counting, areas),
                    "cells": int(np.median([(a.values > 0).sum() for a in areas]))}}
    if light_major:
        cells = (ltm.sizes["r"], ltm.sizes["s"])  # the store's lattice, not the built one's
        env = [xr.DataArray(rng.random(cells), dims=("r", "s")) for _ in range(3)]
        row["environment"] = time_calls(ds, counting, env)
    return row


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layouts = list(result["layouts"])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, kind in zip(axes, ("point", "area"), strict=True):
        values = [result["layouts"][k][kind]["seconds_median"] * 1e3 for k in layouts]
        mb = [result["layouts"][k][kind]["bytes_read_median"] / 1e6 for k in layouts]
        bars = ax.bar(layouts, values, color=["#999", "#3a7", "#37a"][: len(layouts)])
        for bar, m in zip(bars, mb, strict=True):
            ax.annotate(f"{m:.1f} MB read", (bar.get_x() + bar.get_width() / 2,
                                             bar.get_height()), ha="center", va="bottom",
                        fontsize=8)
        ax.axhline(TARGETS[kind] * 1e3, color="r", ls="--", label="target")
        ax.set_ylabel("ms (median, warm; log scale)")
        ax.set_yscale("log")
        ax.set_title(f"one {kind} light, {SIZE} x {SIZE} px, {LATTICE[0]} x {LATTICE[1]} cells")
        ax.tick_params(axis="x", labelsize=8)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--store", help="an existing reconstructed near-light store")
    parser.add_argument("--work", default="/tmp/ltm-relight-bench", help="scratch folder")
    parser.add_argument("--out", default="bench/results")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    store = Path(args.store) if args.store else build(work)
    if by_light_name("ltm") not in os.listdir(store):  # a store reconstructed before the copy
        shutil.rmtree(work / "full.zarr", ignore_errors=True)
        shutil.copytree(store, work / "full.zarr", copy_function=os.link)
        compact(work / "full.zarr", keep_frames=True)
        store = work / "full.zarr"
    half = work / "float16.zarr"
    shutil.rmtree(half, ignore_errors=True)
    shutil.copytree(store, half, copy_function=os.link)  # compact replaces, never edits
    lossy = compact(half, precision="float16")
    ds = open_store(store)
    result = {
        "command": "python bench/relight_latency.py" + (f" --store {args.store}"
                                                         if args.store else ""),
        "ltmstore": __version__,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load_average_1min_at_start": os.getloadavg()[0]},
        "store": {"pixels": int(ds.sizes["y"] * ds.sizes["x"]),
                  "image": [ds.sizes["y"], ds.sizes["x"]],
                  "lattice": [ds.sizes["r"], ds.sizes["s"]],
                  "ltm_float32_bytes": int(ds["ltm"].nbytes),
                  "bytes_total": store_bytes(store),
                  "bytes": {name: folder_bytes(store, name) for name in
                            ("ltm", "ltm_by_light", "samples", "frames", "frame_chroma")},
                  "float16_compacted_bytes_total": store_bytes(half),
                  "float16_ltm_bytes": folder_bytes(half, "ltm"),
                  "float16_ltm_by_light_bytes": folder_bytes(half, "ltm_by_light"),
                  "float16_snr_db": lossy["snr_db"]},
        "area_light": {"kind": "uniform disk", "radius_m": AREA_RADIUS},
        "targets_s": TARGETS,
        "layouts": {},
    }
    for label, path, fast in (("pixel-major", store, False), ("light-major", store, True),
                              ("light-major float16", half, True)):
        result["layouts"][label] = measure(path, light_major=fast,
                                           rng=np.random.default_rng(0))
        row = result["layouts"][label]
        print(f"{label:>20s}  point {row['point']['seconds_median'] * 1e3:7.1f} ms "
              f"{row['point']['bytes_read_median'] / 1e6:6.1f} MB   area "
              f"{row['area']['seconds_median'] * 1e3:7.1f} ms "
              f"{row['area']['bytes_read_median'] / 1e6:6.1f} MB   environment "
              f"{row.get('environment', {}).get('seconds_median', float('nan')):.2f} s",
              flush=True)
    result["machine"]["load_average_1min_at_end"] = os.getloadavg()[0]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "relight_latency.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(result, out / "relight_latency.png")
    print(f"wrote {out}/relight_latency.json and relight_latency.png")


if __name__ == "__main__":
    main()
