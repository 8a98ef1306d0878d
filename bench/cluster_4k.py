"""The 4K reconstruct on a Dask cluster started as a user starts one (issue 25, point 5).

Run: ``python bench/cluster_4k.py --work W`` where ``W`` is the ``--work`` folder of a
``bench/scale_4k.py`` run (its ``4k/acq`` capture; about 50 minutes here with 2 workers).
``--store S`` names an ingested store to use (made by ``ltm ingest W/4k/acq S
--exposure-locked`` when missing, timed; its frames are kept so that it can be run again).

``dask scheduler`` and ``--workers`` ``dask worker`` processes (one thread each, in the
environment ``docs/flows.md`` gives them: :data:`WORKER_ENV`) are started as subprocesses on
loopback, and ``ltm reconstruct S --scheduler ADDRESS --keep-frames`` runs with every other
default on the store as ingest left it (an earlier run's later stages removed). A scheduler
plugin records every graph the scheduler receives and every task's compute time; the
scheduler's CPU time is read before and after; the peak resident memory of the whole process
tree (scheduler, workers, client) is sampled every 0.2 s. The store's SNR_Y is scored as
``bench/scale_4k.py`` scores it.

From the measured tasks, the wall time on 32 and 256 workers: each phase's tasks (resample
regions, solve groups) are list-scheduled with their measured durations on ``w`` workers; the
scheduler's CPU per task times the tasks bounds each phase from below; the client's own work
between the phases (placement, the image's method choice, gathering the factors, checks) is
kept as measured; the storage bandwidth a phase needs at ``w`` workers is its bytes over its
time (to compare with a cluster's shared file system). Writes ``cluster_4k.json`` and
``cluster_4k.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import heapq
import json
import statistics
import sys
from pathlib import Path

import cloudpickle
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import psutil  # noqa: E402
from distributed import Client  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import cluster_bench  # noqa: E402
from cluster_bench import (  # noqa: E402
    Recorder,
    disk_write_mb_s,
    plot_workers,
    recorded,
    start_cluster,
    stop_cluster,
)
from scale_4k import _command, _machine, _variable_bytes, score  # noqa: E402
from scale_bench import PeakMemory  # noqa: E402

from ltmstore.core import store as st  # noqa: E402
from ltmstore.synthetic.simulate import PLANE  # noqa: E402

cloudpickle.register_pickle_by_value(cluster_bench)  # the plugin runs in the scheduler
PHASES = {"resample": "resample_region", "solve": "solve_tiles_task"}
# A user's `dask worker` as docs/flows.md starts it: one BLAS thread, and glibc's mmap threshold
# fixed beside the nanny's MALLOC_TRIM_THRESHOLD_ (which alone slows a tile's solve 1.4x).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "MALLOC_MMAP_THRESHOLD_": "33554432"}
WORKERS = (1, 2, 4, 8, 16, 32, 64, 128, 256)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--work", required=True, help="bench/scale_4k.py's --work folder")
    parser.add_argument("--store", help="the ingested store (default: WORK/4k/cluster.zarr)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="bench/results/scale_4k")
    args = parser.parse_args()
    work = Path(args.work)
    store = Path(args.store or work / "4k" / "cluster.zarr")
    made = json.loads((work / "captures.json").read_text())
    result = {"command": "python bench/" + " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
              "machine": _machine(), "captures": made, "workers": args.workers}
    if not (store / "frames").exists():
        result["ingest"] = _command(["ingest", str(work / "4k" / "acq"), str(store),
                                     "--exposure-locked"])
    result["disk_write_mb_s"] = disk_write_mb_s(store.parent)
    result.update(_on_cluster(store, args.workers))
    plan_args = dict(scene="canvas", seed=0, size=made["render_size"], speed=0.095,
                     plane=PLANE)
    result.update(score(store, plan_args, made["exposure"]))
    result["variable_bytes"] = _variable_bytes(store)
    result["load_average_1min_end"] = psutil.getloadavg()[0]
    result["projection"] = project(result)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cluster_4k.json").write_text(json.dumps(result, indent=2, default=float) + "\n")
    chart(result, out / "cluster_4k.png")
    print(json.dumps({k: result[k] for k in ("reconstruct", "phases", "projection")},
                     indent=1, default=float))


def _on_cluster(store: Path, n_workers: int) -> dict:
    """``ltm reconstruct --scheduler`` on a fresh cluster: the command's wall time and peak
    memory (process tree), the graphs, the tasks by phase, the scheduler's CPU seconds."""
    _as_ingested(store)  # no earlier run's tiles resumed
    with PeakMemory() as memory:
        address, procs = start_cluster(n_workers, store.parent, WORKER_ENV)
        try:
            with Client(address, timeout=60) as client:
                client.wait_for_workers(n_workers, timeout=120)
                client.register_plugin(Recorder())
                scheduler = psutil.Process(procs[0].pid)
                cpu = sum(scheduler.cpu_times()[:2])
                run = _command(["reconstruct", str(store), "--keep-frames", "--scheduler",
                                address])
                cpu = sum(scheduler.cpu_times()[:2]) - cpu
                rec = client.run_on_scheduler(recorded)
        finally:
            stop_cluster(procs)
    record = st.stages(st.open_group(store, mode="r"))["reconstruct"]
    graph_of = {key: i for i, g in enumerate(rec["graphs"]) for key in g["keys"]}
    phases = {}  # "resample:0" (its first graph: the luminance), ..., "solve:0", ...
    for name, prefix in PHASES.items():
        graphs = sorted({graph_of[t["key"]] for t in rec["tasks"]
                         if t["prefix"].endswith(prefix)})
        for n, i in enumerate(graphs):
            phases[f"{name}:{n}"] = _phase([t for t in rec["tasks"]
                                            if graph_of[t["key"]] == i])
    return {"reconstruct": {**run, "peak_memory_gib_with_cluster": round(memory.peak / 2**30, 3),
                            "timings": record["timings"], "plan": record["plan"],
                            "methods_per_tile": record["methods_per_tile"]},
            "scheduler_cpu_s": cpu, "tasks_total": len(rec["tasks"]),
            "graphs": [{"tasks": len(g["keys"]), "prefixes": sorted(set(g["prefixes"]))}
                       for g in rec["graphs"]],
            "phases": phases}


def _as_ingested(store: Path) -> None:
    """The store as ``ltm ingest`` left it: every later stage's variables and records gone."""
    group = st.open_group(store, mode="r+")
    for name in list(group):
        if name not in (*st.STAGE_VARIABLES["ingest"], "t", "x", "y", "channel"):
            del group[name]
    group.attrs[st.STAGES_ATTR] = {"ingest": group.attrs[st.STAGES_ATTR]["ingest"]}


def _phase(tasks: list[dict]) -> dict:
    seconds = [t["stop"] - t["start"] for t in sorted(tasks, key=lambda t: t["start"])]
    return {"tasks": len(seconds), "median_s": statistics.median(seconds),
            "mean_s": statistics.fmean(seconds), "min_s": min(seconds), "max_s": max(seconds),
            "total_s": sum(seconds),
            "span_s": max(t["stop"] for t in tasks) - min(t["start"] for t in tasks),
            "seconds": seconds}


def makespan(seconds: list[float], workers: int) -> float:
    """The tasks, in the order they ran, each on the worker free first."""
    free = [0.0] * workers
    for s in seconds:
        heapq.heappush(free, heapq.heappop(free) + s)
    return max(free)


def project(result: dict) -> dict:
    """The reconstruct's wall time on ``WORKERS`` workers from its measured tasks."""
    phases, wall = result["phases"], result["reconstruct"]["wall_s"]
    per_task = result["scheduler_cpu_s"] / result["tasks_total"]
    client_s = wall - sum(p["span_s"] for p in phases.values())
    sizes = result["variable_bytes"]
    maps = ("albedo", "normal", "specular", "roughness", "ambient", "expected_error",
            "unsupported")
    moved = {"resample": sizes["frames"] + sizes["samples"],  # read, and written (luminance)
             "solve": sizes["samples"] + sum(v for k, v in sizes.items()
                                             if k.startswith("ltm_") or k in maps)}
    rows = []
    for w in WORKERS:
        row = {"workers": w, "client_s": client_s}
        for name, p in phases.items():
            compute = makespan(p["seconds"], w)
            scheduler = p["tasks"] * per_task
            row[f"{name}_s"] = max(compute, scheduler)
            row[f"{name}_limited_by"] = "compute" if compute >= scheduler else "scheduler"
        for name in PHASES:
            row[f"{name}_s"] = sum(row[f"{n}_s"] for n in phases if n.startswith(name + ":"))
            row[f"{name}_0_needs_mb_s"] = moved[name] / row[f"{name}:0_s"] / 1e6
        row["wall_s"] = client_s + sum(row[f"{n}_s"] for n in PHASES)
        rows.append(row)
    return {"scheduler_cpu_ms_per_task": 1e3 * per_task, "client_s": client_s,
            "bytes_moved": moved, "rows": rows,
            "model_at_measured_workers_s": next(r["wall_s"] for r in rows
                                                if r["workers"] == result["workers"])}


def chart(result: dict, path: Path) -> None:
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for name, p in result["phases"].items():  # per graph: colour has three of each
        a.hist(p["seconds"], bins=40, alpha=0.6,
               label=f"{name}: {p['tasks']} tasks, median {p['median_s']:.2f} s")
    a.axvline(1.0, color="grey", linestyle=":")
    a.set_xlabel("seconds per task")
    a.set_ylabel("tasks")
    a.set_title(f"measured: 4K reconstruct, {result['workers']} dask workers", fontsize=9)
    a.legend(fontsize=7)
    b.axhline(result["reconstruct"]["wall_s"] / 60, color="grey", linestyle=":",
              label="measured wall")
    plot_workers(b, result["projection"]["rows"],
                 (("wall_s", "k-o"), ("solve_s", "b--"), ("resample_s", "g-."),
                  ("client_s", "m:")), "projected from the measured tasks")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
