"""Two versions of the code on the same scale scene, side by side: every run's stage times and
SNR_Y, their medians, and a chart of time against accuracy.

Run: ``python bench/scale_compare.py OLD_DIR [OLD_DIR ...] --new NEW_DIR [NEW_DIR ...]
[--labels OLD NEW] [--out bench/results]``, where each directory holds the
``scale_<config>.json`` of one ``python bench/scale_bench.py --reuse --out DIR`` run (the old
version's with ``PYTHONPATH`` on a ``git archive`` of its commit, run alternately with the new
one on the same ingested scene). Writes ``scale_<config>_compare.json`` and ``.png``. Runs made
with ``--subset-to`` (no truth) are compared by their LTMs at the SNR pixels instead: whether
every run's equals the first old run's bit for bit (``ltm_identical``).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import numpy as np

STAGES = ("resample_s", "placement_s", "solve_s", "by_light_s")


def load(directories: list[str]) -> list[dict]:
    """The ``scale_*.json`` of each run directory (one per directory)."""
    return [json.loads(next(Path(d).glob("scale_*.json")).read_text()) for d in directories]


def summary(runs: list[dict]) -> dict:
    """Medians over the runs of each stage's seconds, the whole reconstruct and SNR_Y."""
    timings = [run["timings"] for run in runs]
    keys = ("reconstruct_s", *STAGES)
    return {"runs": len(runs),
            "median": {k: statistics.median(t[k] for t in timings) for k in keys},
            "reconstruct_s": [t["reconstruct_s"] for t in timings],
            "snr_y_db": [run["snr_y_db_pixel_subset"] for run in runs],
            "peak_memory_gib": [run["peak_memory_gib_reconstruct"] for run in runs],
            "point_light_s": [run["relight_point_light"]["seconds_median"] for run in runs]}


def chart(results: dict, path: Path) -> None:
    """Stacked median stage times per version (left) and every run's reconstruct time against
    its SNR_Y (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (bars, scatter) = plt.subplots(1, 2, figsize=(10, 4))
    labels = list(results)
    for i, label in enumerate(labels):
        bottom = 0.0
        median = results[label]["median"]
        for j, stage in enumerate((*STAGES, "other")):
            value = (median["reconstruct_s"] - sum(median[s] for s in STAGES)
                     if stage == "other" else median[stage])
            bars.bar(i, value, bottom=bottom, color=f"C{j}", label=stage if i == 0 else None)
            bottom += value
        bars.text(i, bottom, f"{bottom:.0f} s", ha="center", va="bottom")
        if None not in results[label]["snr_y_db"]:
            scatter.scatter(results[label]["reconstruct_s"], results[label]["snr_y_db"],
                            label=label, s=40)
        else:  # no truth: the runs' LTMs compared with each other (ltm_identical)
            scatter.scatter(results[label]["reconstruct_s"],
                            [i] * len(results[label]["reconstruct_s"]), label=label, s=40)
    bars.set_xticks(range(len(labels)), labels)
    bars.set_ylabel("reconstruct, median (s)")
    bars.legend(fontsize=8)
    scatter.set_xlabel("reconstruct (s), every run")
    if any(None in results[label]["snr_y_db"] for label in labels):
        scatter.set_yticks(range(len(labels)), labels)
        scatter.set_ylim(-0.5, len(labels) - 0.5)
        scatter.set_ylabel("version (no truth: their LTMs compared)")
    else:
        scatter.set_ylabel("SNR_Y against the truth (dB)")
    scatter.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("old", nargs="+", help="run directories of the old version")
    parser.add_argument("--new", nargs="+", required=True, help="run directories of the new")
    parser.add_argument("--labels", nargs=2, default=("old", "new"))
    parser.add_argument("--out", default="bench/results")
    args = parser.parse_args()
    old, new = load(args.old), load(args.new)
    config = new[0]["config"]
    results = {args.labels[0]: summary(old), args.labels[1]: summary(new)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {"config": config, "pixels": new[0]["pixels"], "lattice": new[0]["lattice"],
              "machine": new[0]["machine"], "versions": results,
              "command": "python bench/scale_compare.py " + " ".join(args.old) + " --new "
                         + " ".join(args.new) + " --labels " + " ".join(args.labels)}
    subsets = [run["ltm_subset"] for run in old + new if run.get("ltm_subset")]
    if subsets:
        first = np.load(subsets[0])
        record["ltm_identical"] = all(np.array_equal(first, np.load(p), equal_nan=True)
                                      for p in subsets[1:])
    (out / f"scale_{config}_compare.json").write_text(json.dumps(record, indent=2) + "\n")
    chart(results, out / f"scale_{config}_compare.png")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
