"""``auto`` against every single method on simulated handheld captures (SNR_Y against the truth).

Run: ``python bench/auto_handheld.py [--out bench/results]``. The three scenes of ``ltm bench`` at
three path densities (K/M about 0.17-0.38 on the 32 x 32 lattice); on each, the pixels of one
tile are reconstructed as ``ltm reconstruct`` does per tile: ``auto`` (the method by held-out
cells, :func:`ltmstore.solve.select.choose_method`, then its regularisation) beside ``cs`` (with
its regularisation chosen the same way), ``cubic``, ``hsh`` (order 2 and 3), ``ptm``, ``rbf``
and ``kernel``. Writes ``auto_handheld.json`` and prints a Markdown table; the truth is only
used to score.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ltmstore.judge.benchmark import SCENES, make_cases
from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import Geometry, get_method
from ltmstore.solve.select import choose_method, choose_params

DENSITIES = (15.0, 27.0, 45.0)
SINGLE = {"cs": ("cs", {}), "cubic": ("cubic", {}), "hsh2": ("hsh", {"order": 2}),
          "hsh3": ("hsh", {"order": 3}), "ptm": ("ptm", {}), "rbf": ("rbf", {}),
          "kernel": ("kernel", {})}


def as_reconstruct(batch: np.ndarray, geometry: Geometry, method: str, params: dict):
    """One tile as ``ltm reconstruct`` solves it (``auto``: the method first), and its label."""
    label = method
    if method == "auto":
        picked = choose_method(batch, geometry)
        label, method, params = picked.label, picked.method, picked.params
    choice = choose_params(batch, geometry, method, params=params)
    return get_method(method)(batch, geometry, **choice.params), label


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--pixels", default=256, type=int)
    args = parser.parse_args()
    rows = []
    with threadpool_limits(1):
        for scene in SCENES:
            for density in DENSITIES:
                (case,) = make_cases(scene, density, (32,), size=32, seed=0)
                pick = np.random.default_rng(0).choice(len(case.samples), args.pixels,
                                                       replace=False)
                batch, truth = case.samples[pick], case.truth[pick]
                row = {"scene": scene, "path_density": density, "K/M": case.ratio}
                for name, (method, params) in {"auto": ("auto", {}), **SINGLE}.items():
                    estimate, label = as_reconstruct(batch, case.geometry, method, params)
                    row[name] = snr_db(truth, estimate)
                    row["auto_chose"] = label if name == "auto" else row.get("auto_chose")
                best = max(SINGLE, key=lambda m: row[m])
                row["best_single"], row["auto_minus_best_db"] = best, row["auto"] - row[best]
                rows.append(row)
                print(json.dumps(row), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "auto_handheld.json").write_text(json.dumps(
        {"command": "python bench/auto_handheld.py", "rows": rows}, indent=1))
    print("| scene | density | K/M | auto (chose) | best single | auto - best |\n"
          "| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['scene']} | {r['path_density']:g} | {r['K/M']:.2f} | {r['auto']:.2f} "
              f"({r['auto_chose']}) | {r[r['best_single']]:.2f} ({r['best_single']}) | "
              f"{r['auto_minus_best_db']:+.2f} |")


if __name__ == "__main__":
    main()
