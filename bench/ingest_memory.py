"""Peak memory and time of ``ltm ingest-rti`` on classic captures of 1-24 MP, this code beside
an earlier tree's (issue 62 item 3: one pass over each photograph, < 2 GiB at 24 MP).

Run: ``python bench/ingest_memory.py [--data ../shared/data] [--out bench/results]
[--sizes 1,4,12,24] [--lights 47] [--old TREE] [--old-label LABEL] [--old-sizes 1,4]``.

Each capture is SynthRTI ``multi-obj1-material1``'s first ``--lights`` dome photographs resized
to ``SIZE`` megapixels (``bench/rti_speed.py``'s ``resized_capture``, JPEG, in a temporary
folder), then ``ltm ingest-rti`` runs as a subprocess with this code and, where ``--old`` names
a tree of earlier code (``git worktree add TREE COMMIT``), with it (``PYTHONPATH=TREE``),
alternating. Peak resident memory is each command's own ``ru_maxrss`` (from ``wait4``); memory
does not vary with the load as time does, so the wall and CPU times are only comparable within
one run, beside the load averages recorded before and after. Writes ``ingest_memory.json`` and
``ingest_memory.png`` (peak memory and wall time against the size) to ``--out``; ``--chart
JSON`` redraws the chart of a written result.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from rti_scale import machine, run, size_options  # noqa: E402
from rti_speed import load, ltm_command, resized_capture  # noqa: E402

from ltmstore.core.provenance import commit  # noqa: E402

GOAL_GIB = 2.0


def ingest(lp: Path, store: Path, env: dict | None = None) -> dict:
    """Wall seconds, CPU seconds and peak GiB of ``ltm ingest-rti lp store``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall, gib = run([*ltm_command(), "ingest-rti", str(lp), str(store), "--overwrite"], env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "peak_gib": round(gib, 3)}


def chart(result: dict, path: Path) -> None:
    """Peak memory and wall time against the size, this code's and the old tree's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (mem, wall) = plt.subplots(1, 2, figsize=(10, 4))
    for key, label, style in (("old", result.get("old_label") or "old", "s--"),
                              ("new", "this code", "o-")):
        sizes = [float(s) for s, row in result["sizes"].items() if key in row]
        rows = [row[key] for row in result["sizes"].values() if key in row]
        mem.plot(sizes, [r["peak_gib"] for r in rows], style, label=label)
        wall.plot(sizes, [r["wall_s"] for r in rows], style, label=label)
    mem.axhline(result["goal_gib"], color="grey", lw=0.8, ls=":", label="goal")
    mem.set(xlabel="megapixels", ylabel="peak resident memory (GiB)", title="ltm ingest-rti")
    wall.set(xlabel="megapixels", ylabel="wall time (s, loaded machine)", title="ltm ingest-rti")
    for ax in (mem, wall):
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    size_options(parser, "1,4,12,24")
    parser.add_argument("--chart", type=Path, help="only redraw the chart of this result JSON")
    args = parser.parse_args()
    if args.chart is not None:
        chart(json.loads(args.chart.read_text()), args.chart.with_suffix(".png"))
        return
    old_sizes = set((args.old_sizes or args.sizes).split(","))
    result = {"machine": machine(),
              "command": "python " + " ".join(sys.argv), "commit": commit(),
              "lights": args.lights, "goal_gib": GOAL_GIB,
              "old_label": args.old_label if args.old else None, "sizes": {}}
    with tempfile.TemporaryDirectory(prefix="ltm-ingest-memory-") as tmp:
        for size in args.sizes.split(","):
            work = Path(tmp) / f"{size}MP"
            lp = resized_capture(args.data, work / "capture", float(size) * 1e6, args.lights)
            row: dict = {"load_before": load(), "new": ingest(lp, work / "new.zarr")}
            if args.old is not None and size in old_sizes:
                env = {**os.environ, "PYTHONPATH": str(args.old)}
                row["old"] = ingest(lp, work / "old.zarr", env)
            row["load_after"] = load()
            result["sizes"][size] = row
            old = row.get("old")
            print(f"{size:>5s} MP: {row['new']['peak_gib']:.2f} GiB, {row['new']['wall_s']} s"
                  + (f"; old {old['peak_gib']:.2f} GiB, {old['wall_s']} s" if old else ""),
                  flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ingest_memory.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    chart(result, path.with_suffix(".png"))
    print(f"wrote {path} and its chart")


if __name__ == "__main__":
    main()
