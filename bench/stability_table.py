"""Which method fails where: every method of ``METHODS`` on every failure regime.

Run: ``python bench/stability_table.py [--out bench/results] [--methods cs,lars]``. Builds the
regimes of :mod:`ltmstore.synthetic.regimes` (16 x 16 pixels on a 16 x 16 lattice; ``lossy``: a
24 x 24 pixel simulated mp4v capture, ingested and binned), solves every pixel with every method
and writes ``stability.json``: per (method, regime) the SNR against the truth over the whole
batch (the paper's SNR_Y), the held-out SNR (5 folds, from the samples alone), the median
expected error (:func:`ltmstore.solve.confidence.expected_error`), the fraction of flagged pixels,
how far the estimate leaves the observed range, and the solve time. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from ltmstore import __version__
from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import METHODS
from ltmstore.solve.confidence import coverage, expected_error, flag_unsupported
from ltmstore.solve.validate import heldout_error
from ltmstore.synthetic.regimes import Regime, build_regimes, lossy_regime, overshoot


def measure(method: str, regime: Regime) -> dict:
    """Accuracy, stability and confidence numbers of one method on one regime."""
    start = time.perf_counter()
    estimate = METHODS[method](regime.samples, regime.geometry)
    seconds = time.perf_counter() - start
    finite = bool(np.isfinite(estimate).all())
    held = heldout_error(regime.samples, regime.geometry, method, folds=5)
    expected = expected_error(regime.samples, regime.geometry, method)
    return {"snr_db": snr_db(regime.truth, estimate) if finite else float("nan"),
            "finite": finite, "overshoot_max": float(np.nanmax(overshoot(regime.samples,
                                                                         estimate))),
            "heldout_snr_db": held.snr_db,
            "expected_error_median": float(np.nanmedian(expected)),
            "solve_s": seconds, "ms_per_pixel": 1e3 * seconds / len(regime.samples)}


def regime_info(regime: Regime) -> dict:
    mask = np.isfinite(regime.samples)
    return {"pixels": len(regime.samples), "lattice": list(regime.geometry.shape),
            "sampling_ratio": regime.ratio,
            "coverage": float(np.median(coverage(mask, regime.geometry))),
            "flagged_fraction": float(flag_unsupported(regime.samples, regime.geometry).mean()),
            "observed_snr_db": snr_db(regime.truth[mask], regime.samples[mask])}


def markdown(table: dict, regimes: dict) -> str:
    names = list(regimes)
    lines = ["| method | " + " | ".join(names) + " |", "| --- |" + " --- |" * len(names),
             "| K/M | " + " | ".join(f"{regimes[r]['sampling_ratio']:.3f}" for r in names) + " |",
             "| flagged | " + " | ".join(f"{regimes[r]['flagged_fraction']:.0%}" for r in names)
             + " |"]
    for method, row in table.items():
        cells = [f"{row[r]['snr_db']:.1f}" if "error" not in row[r] else "crash" for r in names]
        lines.append(f"| `{method}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results", type=Path)
    parser.add_argument("--methods", default=",".join(sorted(METHODS)))
    args = parser.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    regimes = build_regimes()
    with tempfile.TemporaryDirectory() as tmp:
        regimes["lossy"] = lossy_regime(tmp)
    info = {name: regime_info(r) for name, r in regimes.items()}
    table = {}
    for method in methods:
        table[method] = {}
        for name, regime in regimes.items():
            try:
                row = measure(method, regime)
            except Exception as exc:  # a method that crashes is a result too
                row = {"snr_db": float("nan"), "error": f"{type(exc).__name__}: {exc}"}
            table[method][name] = row
            print(f"{method:>7s} {name:>10s} {row['snr_db']:6.2f} dB {row.get('error', '')}",
                  flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    result = {"machine": {"platform": platform.platform(), "python": platform.python_version()},
              "ltmstore": __version__, "command": "python bench/stability_table.py",
              "regimes": info, "snr_db_table": {m: {r: row[r]["snr_db"] for r in row}
                                                for m, row in table.items()},
              "methods": table}
    (args.out / "stability.json").write_text(json.dumps(result, indent=2))
    print("\nSNR against the truth (dB), every pixel of each regime:\n")
    print(markdown(table, info))


if __name__ == "__main__":
    main()
