"""Issue-3 benchmark: the fast CS default against per-pixel LARS, and relighting query cost.

Run: ``python bench/pipeline_bench.py [--out bench/results]``. Writes ``pipeline.json`` and
``cs_vs_lars.png``. Machine, versions and commands go into the JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from functools import partial
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from zarr.storage import LocalStore  # noqa: E402

from ltmstore import __version__, relight  # noqa: E402
from ltmstore.core.store import CountingStore, open_store  # noqa: E402
from ltmstore.judge.benchmark import random_lights, relight_cost  # noqa: E402
from ltmstore.judge.evaluate import snr_db  # noqa: E402
from ltmstore.solve import Geometry, get_method  # noqa: E402
from ltmstore.stages.ingest import ingest  # noqa: E402
from ltmstore.stages.reconstruct import reconstruct  # noqa: E402
from ltmstore.synthetic.simulate import simulate_acquisition  # noqa: E402

SCENES = ("canvas", "icon", "relief")


def timed(fn, repeats: int):
    """Median wall time of ``repeats`` calls and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def cs_vs_lars(work: Path, *, size: int, crop: int, repeats: int) -> list[dict]:
    rows = []
    for scene in SCENES:
        acq = work / scene
        simulate_acquisition(acq, scene=scene, size=size, seed=0, progress=False)
        store = acq.with_name(acq.name + ".zarr")  # beside the folder, never inside it
        ingest(acq, store, progress=False)
        info = reconstruct(store, lattice=(32, 32), progress=False)
        ds, truth = open_store(store), open_store(acq / "truth.zarr")["ltm"]
        window = {"y": slice(size // 2 - crop // 2, size // 2 + crop // 2),
                  "x": slice(size // 2 - crop // 2, size // 2 + crop // 2)}
        samples = ds["samples"].isel(window).values
        batch = samples.reshape(-1, *samples.shape[2:])
        ref = truth.isel(window).values
        row = {"scene": scene, "size": size, "lattice": [32, 32],
               "sampling_ratio": info["sampling_ratio"], "crop_pixels": len(batch),
               "snr_full_cs_db": snr_db(truth, ds["ltm"]),
               "solve_s_full_cs": info["timings"]["solve_s"]}
        geometry = Geometry.from_shape((32, 32))
        for name, reps in (("cs", repeats), ("lars", 1)):
            seconds, est = timed(partial(get_method(name), batch, geometry), reps)
            row[f"snr_crop_{name}_db"] = snr_db(ref, est.reshape(ref.shape))
            row[f"ms_per_pixel_{name}"] = 1e3 * seconds / len(batch)
        row["speedup"] = row["ms_per_pixel_lars"] / row["ms_per_pixel_cs"]
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def relight_queries(store: Path, *, repeats: int) -> dict:
    ds = open_store(store)
    total = int(ds["ltm"].nbytes)
    plane = ds.attrs["acquisition"]["plane"]
    point = relight_cost(store, random_lights(plane, repeats))
    counting = CountingStore(LocalStore(str(store), read_only=True))
    dsc = open_store(counting)
    area = dsc["ltm"].isel(y=0, x=0, drop=True) * 0 + 1.0 / dsc["ltm"][0, 0].size
    start = time.perf_counter()
    relight(dsc, area.compute(), color=False).compute()
    area_s = time.perf_counter() - start
    return {"ltm_bytes_on_disk_uncompressed": total, "shape": list(ds["ltm"].shape),
            "inner_chunks": list(ds["ltm"].encoding.get("preferred_chunks", {}).values()),
            "point_light_bytes_read_median": point["bytes_read_median"],
            "point_light_fraction_read": point["bytes_read_median"] / total,
            "point_light_seconds_median": point["seconds_median"],
            "area_light_bytes_read": counting.bytes_read, "area_light_seconds": area_s,
            "repeats": repeats}


def chart(rows: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for row, colour in zip(rows, ("tab:blue", "tab:orange", "tab:green"), strict=False):
        for name, marker in (("cs", "o"), ("lars", "s")):
            ax.scatter(row[f"ms_per_pixel_{name}"], row[f"snr_crop_{name}_db"], c=colour,
                       marker=marker, s=60, label=f"{row['scene']} {name}")
    ax.set_xscale("log")
    ax.set_xlabel("time per pixel (ms, median, 1 core)")
    ax.set_ylabel("SNR_Y on the crop (dB)")
    ax.set_title("fast CS (circles) against per-pixel LARS (squares), 32x32 lattice")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--crop", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        rows = cs_vs_lars(work, size=args.size, crop=args.crop, repeats=args.repeats)
        big = work / "relight"
        simulate_acquisition(big, scene="canvas", size=128, seed=0, progress=False)
        big_store = big.with_name(big.name + ".zarr")
        ingest(big, big_store, progress=False)
        reconstruct(big_store, lattice=(32, 32), progress=False)
        queries = relight_queries(big_store, repeats=args.repeats)
    result = {"machine": {"platform": platform.platform(), "python": platform.python_version(),
                          "cpus": __import__("os").cpu_count()},
              "ltmstore": __version__, "command": "python bench/pipeline_bench.py",
              "cs_vs_lars": rows, "relight": queries}
    (out / "pipeline.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, out / "cs_vs_lars.png")
    print(json.dumps(queries, indent=2))


if __name__ == "__main__":
    main()
