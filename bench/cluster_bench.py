"""``ltm reconstruct --scheduler`` on a Dask cluster started as a user starts one, measured and
extrapolated to the 4K capture on 32 and 256 workers.

Run: ``python bench/cluster_bench.py [--size 256] [--lattice 32] [--workers 2]`` (about 10
minutes here); ``--keep`` keeps the scratch folder and its ``raw.json``, ``--reuse`` starts from
the ingested store a kept run left, ``--analyse RAW_JSON`` only redoes the tables, the model and
the chart.

A handheld capture is simulated (``canvas``, ``--size`` px square, ``--lattice`` cells square)
and ingested once. Then, as real subprocesses, ``dask scheduler --port P`` and ``--workers``
times ``dask worker tcp://127.0.0.1:P --nworkers 1 --nthreads 1`` are started and
``ltm reconstruct STORE --scheduler tcp://127.0.0.1:P`` runs (the default method); a
:class:`SchedulerPlugin` on that scheduler records every graph it receives and every task's
compute time, and the scheduler's CPU time is read before and after. The same command without
``--scheduler`` (the default local cluster) runs on a copy of the ingested store, and the two
``ltm`` arrays are compared. An address where nothing answers is tried too (exit status, lines,
seconds).

The extrapolation to the issue's 4K capture (3840 x 2160 px, 32 x 32 cells, 1,300 frames) uses
the measured costs: solve seconds per tile (tiles of the same pixel and cell count as here),
resample task seconds per frame-pixel, the serial parts per pixel (the light-major copy, written
by the client process), the scheduler's CPU seconds per task, the bytes per pixel of the store
and the scratch disk's write bandwidth. Its graphs are counted by building them (lazily, on
zeros of the 4K shape). Writes ``cluster.json`` and ``cluster.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import socket
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import psutil  # noqa: E402
from distributed import Client  # noqa: E402
from distributed.diagnostics.plugin import SchedulerPlugin  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.core.store import open_store  # noqa: E402
from ltmstore.stages.ingest import ingest  # noqa: E402
from ltmstore.synthetic.simulate import simulate_acquisition  # noqa: E402

BIN = Path(sys.executable).parent
LOOPBACK = ["--host", "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0"]
K4 = {"image": (2160, 3840), "lattice": (32, 32), "frames": 1300}
WORKERS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
SOLVE_PREFIX = "solve_tile"  # dask.utils.key_split drops the leading underscore


class Recorder(SchedulerPlugin):
    """Every graph the scheduler receives (its keys and their prefixes) and every finished
    task (key, prefix, worker, compute start and stop)."""

    name = "ltm-cluster-bench"

    def __init__(self) -> None:
        self.graphs: list[dict] = []
        self.tasks: list[dict] = []

    def update_graph(self, scheduler, *, tasks, **kwargs) -> None:
        from dask.utils import key_split

        self.graphs.append({"time": time.time(), "keys": [str(k) for k in tasks],
                            "prefixes": [key_split(k) for k in tasks]})

    def transition(self, key, start, finish, *args, **kwargs) -> None:
        from dask.utils import key_split

        if start == "processing" and finish == "memory":
            for ss in kwargs.get("startstops", ()):
                if ss["action"] == "compute":
                    self.tasks.append({"key": str(key), "prefix": key_split(key),
                                       "worker": kwargs.get("worker"),
                                       "start": ss["start"], "stop": ss["stop"]})


def recorded(dask_scheduler) -> dict:
    plugin = dask_scheduler.plugins[Recorder.name]
    return {"graphs": plugin.graphs, "tasks": plugin.tasks}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start_cluster(n_workers: int, cwd: Path,
                  env: dict | None = None) -> tuple[str, list[subprocess.Popen]]:
    """`dask scheduler` and ``n_workers`` `dask worker` processes, as a user starts them, with
    ``env`` added to their environment (default: ``OMP_NUM_THREADS=1``)."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, **(env or {"OMP_NUM_THREADS": "1"})}
    logs = cwd / "dask-logs"
    logs.mkdir(exist_ok=True)
    procs = [subprocess.Popen([BIN / "dask", "scheduler", "--port", str(port), *LOOPBACK],
                              env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                              stderr=open(logs / "scheduler.log", "w"))]  # noqa: SIM115
    for i in range(n_workers):
        procs.append(subprocess.Popen(
            [BIN / "dask", "worker", address, "--nworkers", "1", "--nthreads", "1", *LOOPBACK],
            env=env, cwd=cwd, stdout=subprocess.DEVNULL,
            stderr=open(logs / f"worker{i}.log", "w")))  # noqa: SIM115
    return address, procs


def stop_cluster(procs: list[subprocess.Popen]) -> None:
    for proc in procs[::-1]:
        proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()


def run_ltm(*args) -> dict:
    start = time.perf_counter()
    proc = subprocess.run([BIN / "ltm", *map(str, args)], capture_output=True, text=True)
    return {"command": "ltm " + " ".join(map(str, args)), "returncode": proc.returncode,
            "seconds": time.perf_counter() - start, "stderr_tail": proc.stderr[-600:]}


def disk_write_mb_s(folder: Path, mib: int = 256) -> float:
    """Sequential write bandwidth of ``folder``'s disk, fsync included (MB/s)."""
    block = np.random.default_rng(0).bytes(4 * 2**20)
    path = folder / "bandwidth.bin"
    start = time.perf_counter()
    with open(path, "wb") as f:
        for _ in range(mib // 4):
            f.write(block)
        f.flush()
        os.fsync(f.fileno())
    seconds = time.perf_counter() - start
    path.unlink()
    return mib * 2**20 / seconds / 1e6


def variable_bytes(store: Path) -> dict[str, int]:
    """Bytes on disk of each variable of the store."""
    return {d.name: sum(f.stat().st_size for f in d.rglob("*") if f.is_file())
            for d in sorted(store.iterdir()) if d.is_dir()}


def graph_phases(graphs: list[dict]) -> list[str]:
    """The phase of each graph: ``solve:<n>`` for the n-th graph holding solve tasks (one per
    LTM: luminance, then Cb and Cr for a colour LTM), ``resample`` before the first of them
    (the binned samples, written), ``check`` after it (the stage's finite-where-observed
    check)."""
    names, n = [], 0
    for g in graphs:
        if SOLVE_PREFIX in g["prefixes"]:
            names.append(f"solve:{n}")
            n += 1
        else:
            names.append("check" if n else "resample")
    return names


def _row(ds: list[float]) -> dict:
    return {"count": len(ds), "median_s": statistics.median(ds), "mean_s": statistics.fmean(ds),
            "total_s": sum(ds), "max_s": max(ds)}


def task_phases(rec: dict) -> list[str]:
    """The phase of each recorded task: that of the last graph holding its key submitted
    before the task started (a key can recur: the same array read by two graphs)."""
    phases = graph_phases(rec["graphs"])
    sent = defaultdict(list)
    for g, name in zip(rec["graphs"], phases, strict=True):
        for k in g["keys"]:
            sent[k].append((g["time"], name))
    out = []
    for t in rec["tasks"]:
        before = [name for when, name in sent.get(t["key"], []) if when <= t["start"]]
        out.append(before[-1] if before else "other")
    return out


def task_table(rec: dict) -> dict:
    """Count, median and total compute seconds of the recorded tasks by phase and prefix, the
    graphs' sizes, and each phase's span (first start to last stop)."""
    table, spans = defaultdict(lambda: defaultdict(list)), defaultdict(list)
    for t, where in zip(rec["tasks"], task_phases(rec), strict=True):
        table[where][t["prefix"]].append(t["stop"] - t["start"])
        spans[where] += [t["start"], t["stop"]]
    return {"by_phase": {p: {"all": _row([d for ds in rows.values() for d in ds]),
                             "span_s": max(spans[p]) - min(spans[p]),
                             "by_prefix": {q: _row(ds) for q, ds in sorted(rows.items())}}
                         for p, rows in sorted(table.items())},
            "graphs": [{"phase": name, "tasks": len(g["keys"])}
                       for g, name in zip(rec["graphs"], graph_phases(rec["graphs"]),
                                          strict=True)]}


def tile_tasks(table: dict) -> dict[str, dict]:
    """Per solve phase, the row of its tile tasks: the prefix that holds the phase's compute
    (Dask fuses each tile's read into its solve; the ``solve_tile`` key is an alias)."""
    out = {}
    for p, ph in table["by_phase"].items():
        if p.startswith("solve:"):
            out[p] = max(ph["by_prefix"].values(), key=lambda r: r["total_s"])
    return out


def worker_gaps(rec: dict) -> dict:
    """Idle time between consecutive tasks on the same worker during the solve phases: the
    per-task round trip to the scheduler (median), with the tile's transfer and bookkeeping."""
    per_worker = defaultdict(list)
    for t, where in zip(rec["tasks"], task_phases(rec), strict=True):
        if where.startswith("solve:") and t["stop"] - t["start"] > 0.01:  # tiles, not aliases
            per_worker[t["worker"]].append((t["start"], t["stop"]))
    gaps = []
    for spans in per_worker.values():
        spans.sort()
        gaps += [b[0] - a[1] for a, b in zip(spans, spans[1:], strict=False)]
    return {"median_s": statistics.median(gaps) if gaps else None,
            "mean_s": statistics.fmean(gaps) if gaps else None, "n": len(gaps)}


def graph_sizes_4k(tile: int) -> dict:
    """Tasks of one pass of reconstruct's resample graph at the 4K size, built lazily on zeros
    chunked as ingest chunks frames (32 frames x 256 x 256 pixels), and its tile count."""
    import dask.array as da

    from ltmstore.core.binning import bin_positions
    from ltmstore.core.dims import Lattice, Plane
    from ltmstore.stages.plan import plan_tiles
    from ltmstore.stages.resample import bin_frames

    (h, w), lat, n = K4["image"], K4["lattice"], K4["frames"]
    frames = da.zeros((n, h, w), chunks=(32, 256, 256), dtype=np.float32)
    plane = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)
    rng = np.random.default_rng(0)
    binning = bin_positions(Lattice.from_plane(plane, lat),
                            (rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n)))
    plan = plan_tiles((h, w), lat, tile=tile)
    start = time.perf_counter()
    binned = bin_frames(frames, binning, tile=plan.tile).rechunk(plan.block, method="tasks")
    tasks = len(binned.__dask_graph__()) + binned.npartitions  # + one store task per block
    return {"tiles": plan.n_tiles, "tile": list(plan.tile), "resample_tasks_per_pass": tasks,
            "seconds_to_build": time.perf_counter() - start}


def model_4k(raw: dict, table: dict) -> dict:
    """The measured costs, scaled to the 4K capture."""
    pixels, k4_pixels = raw["size"] ** 2, K4["image"][0] * K4["image"][1]
    tiles = tile_tasks(table)
    n_tiles = sum(r["count"] for r in tiles.values()) / max(len(tiles), 1)
    phases = table["by_phase"]
    timings, run_s = raw["cluster"]["timings"], raw["cluster"]["run"]["seconds"]
    resample = phases.get("resample", {"all": {"total_s": 0.0}, "span_s": 0.0})
    check = phases.get("check", {"all": {"total_s": 0.0, "count": 0}, "span_s": 0.0})
    bytes_ = raw["store_bytes"]
    ingested = ("frames", "frame_chroma", "chroma", "pose_r", "pose_s", "pose_z", "pose_valid",
                "t", "x", "y", "channel")
    written = sum(v for k, v in bytes_.items() if k not in ingested)
    # the client's own work outside the cluster's phases: start, connection, planning,
    # metadata (fixed); placement (per pixel of the side) and the light-major copy (per pixel)
    fixed = (run_s - timings.get("solve_s", 0) - timings.get("by_light_s", 0)
             - timings.get("placement_s", 0) - resample["span_s"] - check["span_s"])
    n_tasks = len(raw["recorded"]["tasks"])
    m = {"passes": len(tiles), "tiles_measured": n_tiles,
         "tile_s_mean": sum(r["total_s"] for r in tiles.values())
         / max(sum(r["count"] for r in tiles.values()), 1),
         "tile_s_median_per_pass": {p: r["median_s"] for p, r in tiles.items()},
         "solve_s_per_pixel_all_passes": sum(r["total_s"] for r in tiles.values()) / pixels,
         "resample_task_s_per_frame_pixel": resample["all"]["total_s"]
         / (raw["frames"] * pixels),
         "check_task_s_per_pixel": check["all"]["total_s"] / pixels,
         "scheduler_cpu_ms_per_task": 1e3 * raw["cluster"]["scheduler_cpu_s"] / n_tasks,
         "tasks_measured": n_tasks,
         "disk_write_mb_s": raw["disk_write_mb_s"],
         "bytes_written_per_pixel": written / pixels,
         "frames_bytes_per_frame_pixel": bytes_.get("frames", 0) / (raw["frames"] * pixels),
         "by_light_s_per_pixel": timings.get("by_light_s", 0) / pixels,
         # placement reads a bounded number of pixel lines: it grows with the image's side
         "placement_s_per_side_pixel": timings.get("placement_s", 0) / raw["size"],
         "fixed_serial_s": fixed}
    sizes = graph_sizes_4k(raw["cluster"]["plan"]["tile"][0])
    per_tile = {"solve": 2 + 1 / n_tiles,  # a read and its alias per tile (+1 array)
                "check": check["all"]["count"] / max(m["passes"], 1) / n_tiles}
    k4 = {"pixels": k4_pixels, "tiles": sizes["tiles"],
          "frame_pixels": K4["frames"] * k4_pixels,
          "tasks": m["passes"] * (sizes["resample_tasks_per_pass"]
                                  + sizes["tiles"] * (per_tile["solve"] + per_tile["check"])),
          "bytes_written": m["bytes_written_per_pixel"] * k4_pixels,
          "frames_bytes_read": m["frames_bytes_per_frame_pixel"] * K4["frames"] * k4_pixels,
          "serial_s": fixed + m["by_light_s_per_pixel"] * k4_pixels
          + m["placement_s_per_side_pixel"] * max(K4["image"])}
    return {"assumptions": K4, "measured": m, "graph_4k": sizes, "k4": k4}


def extrapolate(model: dict, workers=WORKERS) -> list[dict]:
    """Wall time of the 4K reconstruct on ``workers`` workers from the measured costs.

    The tiles run in waves over the workers at the measured mean seconds per tile; resample and
    check tasks cost their measured seconds per frame-pixel and per pixel, spread evenly; the
    scheduler (one process) spends its measured CPU per task; the store's new bytes are written
    at the measured disk bandwidth. Time = serial (the client's own work) + the largest of
    compute, scheduler and storage, which names the limit.
    """
    m, k4 = model["measured"], model["k4"]
    rows = []
    for w in workers:
        solve = math.ceil(k4["tiles"] * m["passes"] / w) * m["tile_s_mean"]
        other = (m["resample_task_s_per_frame_pixel"] * k4["frame_pixels"]
                 + m["check_task_s_per_pixel"] * k4["pixels"]) / w
        parts = {"compute": solve + other,
                 "scheduler": k4["tasks"] * m["scheduler_cpu_ms_per_task"] / 1e3,
                 "storage": k4["bytes_written"] / (m["disk_write_mb_s"] * 1e6)}
        limit = max(parts, key=parts.get)
        rows.append({"workers": w, **{f"{k}_s": v for k, v in parts.items()},
                     "solve_s": solve, "serial_s": k4["serial_s"],
                     "wall_s": k4["serial_s"] + parts[limit], "limited_by": limit})
    return rows


def chart(result: dict, path: Path) -> None:
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    rows = [(f"{p} {q}", r) for p, ph in result["tasks"]["by_phase"].items()
            for q, r in ph["by_prefix"].items() if r["total_s"] > 0.5]
    rows.sort(key=lambda x: -x[1]["total_s"])
    rows = rows[:10]
    a.barh([n for n, _ in rows], [r["median_s"] for _, r in rows], color="tab:blue")
    for i, (_, r) in enumerate(rows):
        a.text(r["median_s"], i, f" n={r['count']}, {r['total_s']:.0f} s", va="center",
               fontsize=7)
    a.axvline(1.0, color="grey", linestyle=":")  # the "about a second" per task
    a.set_xscale("log")
    a.tick_params(axis="y", labelsize=7)
    a.set_xlabel("seconds per task (median)")
    a.set_title(f"measured: {result['size']} px, {result['workers']} dask workers", fontsize=9)
    plot_workers(b, result["extrapolation_4k"]["rows"],
                 (("wall_s", "k-o"), ("compute_s", "b--"), ("scheduler_s", "r:"),
                  ("storage_s", "g-."), ("serial_s", "m:")),
                 "extrapolated: 4K (3840 x 2160), 32 x 32 cells, 1,300 frames")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_workers(ax, rows: list[dict], series, title: str) -> None:
    """Minutes of each ``(key, style)`` of ``series`` against the rows' dask workers (log-log)."""
    ws = [r["workers"] for r in rows]
    for key, style in series:
        ax.plot(ws, [r[key] / 60 for r in rows], style, label=key[:-2])
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("dask workers")
    ax.set_ylabel("minutes")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)


def measure(args, work: Path) -> dict:
    """Simulate and ingest (or reuse), run on the user-started cluster and locally; the raw
    measurements."""
    ingested = work / "ingested.zarr"
    lattice = (args.lattice, args.lattice)
    raw = {"command": "python bench/cluster_bench.py " + " ".join(sys.argv[1:]),
           "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                       "load_avg_start": os.getloadavg()},
           "ltmstore": __version__, "size": args.size, "lattice": list(lattice),
           "workers": args.workers}
    raw["code_hash"] = code_hash()
    if not ingested.exists():
        start = time.perf_counter()
        simulate_acquisition(work / "acq", scene="canvas", size=args.size, seed=0,
                             lattice=lattice, path_density=args.path_density, truth=False,
                             progress=False)
        raw["simulate_s"] = time.perf_counter() - start
        start = time.perf_counter()
        ingest(work / "acq", ingested, progress=False)
        raw["ingest_s"] = time.perf_counter() - start
    raw["frames"] = int(open_store(ingested)["frames"].shape[0])
    for name in ("cluster.zarr", "local.zarr"):
        shutil.rmtree(work / name, ignore_errors=True)
        shutil.copytree(ingested, work / name)
    raw["disk_write_mb_s"] = disk_write_mb_s(work)
    lat_arg = ["--lattice", f"{args.lattice}x{args.lattice}"]

    address, procs = start_cluster(args.workers, work)
    try:
        with Client(address, timeout=60) as client:
            client.wait_for_workers(args.workers, timeout=120)
            client.register_plugin(Recorder())
            sched = psutil.Process(procs[0].pid)
            cpu0 = sum(sched.cpu_times()[:2])
            run = run_ltm("reconstruct", work / "cluster.zarr", *lat_arg, "--scheduler", address)
            cpu1 = sum(sched.cpu_times()[:2])
            raw["recorded"] = client.run_on_scheduler(recorded)
    finally:
        stop_cluster(procs)
    if run["returncode"] != 0:
        raise SystemExit(f"ltm reconstruct --scheduler failed: {run['stderr_tail']}")
    info = open_store(work / "cluster.zarr").attrs["stages"]["reconstruct"]
    raw["cluster"] = {"address": address, "run": run, "scheduler_cpu_s": cpu1 - cpu0,
                      "timings": info["timings"], "plan": info["plan"], "color": info["color"],
                      "methods_per_tile": info["methods_per_tile"],
                      "sampling_ratio": info["sampling_ratio"]}
    raw["store_bytes"] = variable_bytes(work / "cluster.zarr")
    local = run_ltm("reconstruct", work / "local.zarr", *lat_arg)
    raw["local"] = {"run": local,
                    "timings": open_store(work / "local.zarr").attrs["stages"]["reconstruct"][
                        "timings"]}
    raw["same_ltm"] = compare(work / "cluster.zarr", work / "local.zarr")
    raw["same_code_both_runs"] = code_hash() == raw["code_hash"]  # nobody edited it meanwhile
    raw["bad_address"] = bad_addresses(work / "cluster.zarr", lat_arg)
    raw["machine"]["load_avg_end"] = os.getloadavg()
    return raw


def code_hash() -> str:
    """A hash of the ltmstore sources the ``ltm`` commands import."""
    import hashlib

    import ltmstore

    digest = hashlib.sha256()
    for f in sorted(Path(ltmstore.__file__).parent.rglob("*.py")):
        digest.update(f.read_bytes())
    return digest.hexdigest()[:16]


def bad_addresses(store: Path, lat_arg: list[str]) -> dict:
    """``--scheduler`` at a listener that never answers (accepts no connection) and at a
    closed port: exit status, stderr lines, seconds."""
    mute = socket.socket()
    mute.bind(("127.0.0.1", 0))
    mute.listen(0)
    bad = {}
    for name, addr in (("silent_listener", f"tcp://127.0.0.1:{mute.getsockname()[1]}"),
                       ("closed_port", f"tcp://127.0.0.1:{free_port()}")):
        r = run_ltm("reconstruct", store, *lat_arg, "--overwrite", "--scheduler", addr)
        bad[name] = {"returncode": r["returncode"], "seconds": r["seconds"],
                     "stderr_lines": r["stderr_tail"].strip().splitlines()}
    mute.close()
    return bad


def compare(a_path: Path, b_path: Path) -> dict:
    """How far apart the ``ltm`` of two stores are."""
    results = {}
    for name in ("ltm", "ltm_cb", "ltm_cr"):
        ds_a, ds_b = open_store(a_path), open_store(b_path)
        if name not in ds_a:
            continue
        a, b = ds_a[name].values, ds_b[name].values
        both = np.isfinite(a) & np.isfinite(b)
        results[name] = {
            "nan_pattern_equal": bool((np.isnan(a) == np.isnan(b)).all()),
            "max_abs_diff": float(np.abs(a - b)[both].max()),
            "max_abs_value": float(np.abs(b[both]).max()),
            "allclose_rtol_1e-5": bool(np.allclose(a, b, rtol=1e-5, atol=1e-7, equal_nan=True))}
    return results


def analyse(raw: dict) -> dict:
    """The task tables, the 4K model and its rows, from the raw measurements."""
    table = task_table(raw["recorded"])
    model = model_4k(raw, table)
    cluster = {**raw["cluster"], "tasks_total": len(raw["recorded"]["tasks"]),
               "graph_tasks_submitted": sum(g["tasks"] for g in table["graphs"]),
               "tile_tasks": tile_tasks(table),
               "gap_between_tile_tasks": worker_gaps(raw["recorded"])}
    return {**{k: v for k, v in raw.items() if k != "recorded"}, "cluster": cluster,
            "tasks": table, "extrapolation_4k": {**model, "rows": extrapolate(model)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=256, help="image side in pixels")
    parser.add_argument("--lattice", type=int, default=32, help="cells along each side")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--path-density", type=float, default=27.0)
    parser.add_argument("--work", default="/tmp/ltm-cluster", help="scratch folder")
    parser.add_argument("--out", default="bench/results")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    parser.add_argument("--reuse", action="store_true",
                        help="reuse the simulated and ingested store a --keep run left")
    parser.add_argument("--analyse", metavar="RAW_JSON",
                        help="only analyse the raw measurements of an earlier run")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.analyse:
        raw = json.loads(Path(args.analyse).read_text())
    else:
        work = Path(args.work)
        if not (args.reuse and (work / "ingested.zarr").exists()):
            shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True, exist_ok=True)
        raw = measure(args, work)
        (work / "raw.json").write_text(json.dumps(raw, default=float))
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    result = analyse(raw)
    (out / "cluster.json").write_text(json.dumps(result, indent=2, default=float) + "\n")
    chart(result, out / "cluster.png")
    print(json.dumps({k: result[k] for k in ("same_ltm", "bad_address")}, indent=1))
    print(json.dumps(result["extrapolation_4k"]["rows"], indent=1))


if __name__ == "__main__":
    main()
