"""The web export's whole command, ``ltm export S OUT --format relight``: wall time, peak memory
and the held-out PSNR it prints, this code beside an older tree's, alternating.

Run: ``python bench/export_speed.py NAME=STORE [NAME=STORE ...] [--old TREE] [--repeats 2]
[--out bench/results]``.

Each store is a reconstructed one (``ltm ingest-rti DATA/dirs.lp S --holdout-lights 6 && ltm
reconstruct S``). Per repeat, as subprocesses, in turn: this code's export, then ``--old``'s
(``PYTHONPATH=TREE``) into a temporary folder. Wall time and the export's own peak resident
memory (``wait4``), medians over ``--repeats``, the load average before and after; the held-out
PSNR is the line ``ltm export`` prints. Writes ``export_speed.json`` and ``export_speed.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ltmstore.core.provenance import commit

sys.path.insert(0, str(Path(__file__).parent))
from rti_scale import machine  # noqa: E402
from rti_speed import load, ltm_command  # noqa: E402

HELD_OUT = re.compile(r"([\d.]+) dB against the (\d+) held-out photographs")
VS_STORE = re.compile(r"([\d.]+) dB against ltm relight at \d+ of the capture's lights")


def export(store: Path, out: Path, env: dict | None) -> dict:
    """Wall seconds, peak GiB and the printed held-out PSNR of one web export."""
    start = time.perf_counter()
    proc = subprocess.Popen([*ltm_command(), "export", str(store), str(out), "--format",
                             "relight"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    text = proc.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"ltm export {store} failed: {text[-500:]}")
    found, near = HELD_OUT.search(text), VS_STORE.search(text)
    return {"s": wall, "gib": usage.ru_maxrss / 2**20,
            "heldout_db": float(found.group(1)) if found else None,
            "vs_store_db": float(near.group(1)) if near else None}


def measure(store: Path, tmp: Path, repeats: int, old: Path | None) -> dict:
    """Medians over ``repeats`` of this code's and the old code's exports of ``store``."""
    trees = {"": None} | ({"old_": {**os.environ, "PYTHONPATH": str(old)}} if old else {})
    rows: dict[str, list[float]] = {}
    for i in range(repeats):
        for prefix, env in trees.items():
            for key, value in export(store, tmp / f"{prefix}web{i}", env).items():
                rows.setdefault(prefix + key, []).append(value)
    return ({k: None if None in v else statistics.median(v) for k, v in rows.items()}
            | {"runs": rows})  # None: no held-out photographs (a near-light store)


def chart(result: dict, path: Path) -> None:
    """Wall time per store, this code beside the old code."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["stores"])
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.38
    for k, (prefix, label) in enumerate((("", "this code"), ("old_", result["old_label"]))):
        values = [result["stores"][n].get(prefix + "s", float("nan")) for n in names]
        bars = ax.bar([i + (k - 0.5) * width for i in range(len(names))], values, width,
                      label=label, color=("C0", "C1")[k])
        ax.bar_label(bars, fmt="%.1f", fontsize=8)
    ax.set_xticks(range(len(names)), names)
    ax.set_ylabel("seconds (ltm export --format relight)")
    ax.legend(fontsize=8)
    ax.set_title(f"{result['machine']['cores']} cores; medians of {result['repeats']}; load "
                 f"{result['load_start']} -> {result['load_end']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stores", nargs="+", help="NAME=STORE")
    parser.add_argument("--old", type=Path, help="a tree of earlier code (PYTHONPATH=OLD)")
    parser.add_argument("--old-label", default="old code")
    parser.add_argument("--repeats", default=2, type=int)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    args = parser.parse_args()
    result = {"machine": machine(), "command": "python " + " ".join(sys.argv),
              "commit": commit(), "repeats": args.repeats, "old_label": args.old_label,
              "load_start": load(), "stores": {}}
    with tempfile.TemporaryDirectory(prefix="ltm-export-speed-") as tmp:
        for pair in args.stores:
            name, _, store = pair.partition("=")
            (Path(tmp) / name).mkdir()
            row = measure(Path(store), Path(tmp) / name, args.repeats, args.old)
            result["stores"][name] = row
            db = row["heldout_db"] or row["vs_store_db"]  # a near-light store: against itself
            print(f"{name}: {row['s']:.1f} s, {row['gib']:.2f} GiB, {db} dB"
                  + (f" (old {row['old_s']:.1f} s, {row['old_gib']:.2f} GiB, "
                     f"{row['old_heldout_db'] or row['old_vs_store_db']} dB)" if args.old
                     else ""), flush=True)
    result["load_end"] = load()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "export_speed.json").write_text(json.dumps(result, indent=1) + "\n")
    chart(result, args.out / "export_speed.png")


if __name__ == "__main__":
    main()
