"""Chart the dense and factored forms of ``ltm reconstruct`` side by side: whole time, LTM
bytes, one point light and accuracy, from ``scale_bench.py`` runs of each form.

Run after ``python bench/scale_bench.py --config C --work W --reuse [--form factored]`` for both
forms (Notre Dame-b with ``--subset-to F.npy``, its truth not rendered):
``python bench/factored_compare.py --dense D.json ... --factored F.json ... --subsets D.npy
F.npy``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--dense", nargs="+", type=Path, required=True)
    parser.add_argument("--factored", nargs="+", type=Path, required=True)
    parser.add_argument("--subsets", nargs=2, type=Path, metavar=("DENSE", "FACTORED"),
                        help="LTM subsets (.npy) of a config without truth: SNR of factored "
                             "against dense")
    parser.add_argument("--out", type=Path, default=Path("bench/results/factored_compare"))
    args = parser.parse_args()
    runs = [(json.loads(d.read_text()), json.loads(f.read_text()))
            for d, f in zip(args.dense, args.factored, strict=True)]
    rows = []
    for dense, fact in runs:
        snr = {"dense": dense["snr_y_db_pixel_subset"], "factored": fact["snr_y_db_pixel_subset"]}
        if snr["dense"] is None and args.subsets:
            d, f = (np.load(p).astype(np.float64) for p in args.subsets)
            snr = {"factored_vs_dense": float(10 * np.log10(np.sum(d ** 2) / np.sum((d - f) ** 2)))}
        rows.append({"config": dense["config"], "snr_db": snr, **{
            form: {"reconstruct_s": r["timings"]["reconstruct_s"],
                   "ltm_bytes": r["ltm_stored_bytes"], "peak_gib": r["peak_memory_gib_reconstruct"],
                   "point_light_s": r["relight_point_light"]["seconds_median"]}
            for form, r in (("dense", dense), ("factored", fact))}})
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=2) + "\n")
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    keys = (("reconstruct_s", "ltm reconstruct (s)", False),
            ("ltm_bytes", "LTM on disk (bytes)", True),
            ("point_light_s", "one point light (s)", True))
    x = np.arange(len(rows))
    for ax, (key, label, log) in zip(axes, keys, strict=True):
        for k, form in enumerate(("dense", "factored")):
            ax.bar(x + (k - 0.5) * 0.38, [r[form][key] for r in rows], 0.38, label=form)
        ax.set_xticks(x, [r["config"] for r in rows])
        ax.set_title(label)
        if log:
            ax.set_yscale("log")
    axes[0].legend()
    notes = "; ".join(f"{r['config']}: " + ", ".join(f"{k} {v:.2f} dB"
                                                     for k, v in r["snr_db"].items())
                      for r in rows)
    fig.suptitle(f"ltm reconstruct --form dense / factored (SNR_Y: {notes})", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out.with_suffix(".png"), dpi=110)
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
