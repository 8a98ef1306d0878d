"""The whole default ``ltm reconstruct`` beside ``ltm reconstruct --method cs``, same captures.

Run: ``python bench/default_speed.py [--size 128] [--repeats 3] [--out bench/results]``.

For each simulated scene (canvas, icon, relief; the near-light surface model competes because
``ltm simulate`` declares the object's extent) the capture is simulated and ingested once, then
each command is run ``--repeats`` times as a user runs it (a subprocess, ``--overwrite``,
local Dask cluster started by the command) and timed end to end. Reports the median wall time,
their ratio and the SNR_Y of each result against the simulation's truth. Writes
``default_speed.json`` and ``default_speed.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import psutil  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.core.store import open_store  # noqa: E402
from ltmstore.judge.evaluate import snr_db  # noqa: E402
from ltmstore.stages.ingest import ingest  # noqa: E402
from ltmstore.synthetic.simulate import simulate_acquisition  # noqa: E402

SCENES = ("canvas", "icon", "relief")
COMMANDS = {"default": [], "cs": ["--method", "cs"]}
LTM = Path(sys.executable).parent / "ltm"


def run_command(store: Path, extra: list[str], repeats: int) -> dict:
    """Median wall time of ``ltm reconstruct STORE --overwrite EXTRA`` and its result."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run([LTM, "reconstruct", store, "--overwrite", *extra], check=True,
                       capture_output=True)
        times.append(time.perf_counter() - start)
    rec = open_store(store).attrs["stages"]["reconstruct"]
    return {"seconds": times, "seconds_median": statistics.median(times),
            "methods_per_tile": rec["methods_per_tile"], "lattice": rec["lattice"]["shape"]}


def scene_row(work: Path, scene: str, size: int, repeats: int) -> dict:
    acq = work / scene
    simulate_acquisition(acq, scene=scene, size=size, seed=0, progress=False)
    store = acq.with_name(acq.name + ".zarr")  # beside the acquisition, never inside it
    ingest(acq, store, progress=False)
    truth = open_store(acq / "truth.zarr")["ltm"]
    row = {"scene": scene, "size": size}
    for name, extra in COMMANDS.items():
        row[name] = run_command(store, extra, repeats)
        row[name]["snr_y_db"] = snr_db(truth, open_store(store)["ltm"])
    row["ratio"] = row["default"]["seconds_median"] / row["cs"]["seconds_median"]
    print(json.dumps(row), flush=True)
    return row


def chart(rows: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for row, colour in zip(rows, ("tab:blue", "tab:orange", "tab:green"), strict=False):
        for name, marker in (("default", "o"), ("cs", "s")):
            ax.scatter(row[name]["seconds_median"], row[name]["snr_y_db"], c=colour,
                       marker=marker, s=60, label=f"{row['scene']} {name}")
    ax.set_xlabel("ltm reconstruct wall time (s, median)")
    ax.set_ylabel("SNR_Y against the truth (dB)")
    ax.set_title("default (circles) against --method cs (squares)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="bench/results")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [scene_row(Path(tmp), scene, args.size, args.repeats) for scene in SCENES]
    result = {
        "command": f"python bench/default_speed.py --size {args.size} --repeats {args.repeats}",
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "memory_gib": psutil.virtual_memory().total / 2**30,
                    "load_average_1min": os.getloadavg()[0]},
        "ltmstore": __version__, "rows": rows,
        "ratio_median": statistics.median(r["ratio"] for r in rows)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "default_speed.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, out / "default_speed.png")
    for r in rows:
        print(f"{r['scene']:7s} default {r['default']['seconds_median']:6.1f} s "
              f"{r['default']['snr_y_db']:5.2f} dB  cs {r['cs']['seconds_median']:6.1f} s "
              f"{r['cs']['snr_y_db']:5.2f} dB  ratio {r['ratio']:.2f}")


if __name__ == "__main__":
    main()
