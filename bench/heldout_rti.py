"""Leave-lights-out on real RTI captures: every method of ``METHODS`` on the same pixels.

Run: ``python bench/heldout_rti.py [--data ../shared/data] [--out bench/results]``. Each capture
in ``--data`` (a folder with a ``dirs.lp``) is ingested
(:func:`ltmstore.stages.ingest_rti.ingest_rti`) and reconstructed on the automatic lattice (K/M
about 0.29), then :func:`ltmstore.judge.heldout.heldout_store`
hides a fifth of the observed cells (lights) five times over and scores each method's
prediction of them on the same ``--pixels`` random pixels. Writes ``heldout_rti.json`` and
prints a Markdown table of held-out SNR (dB). The captures are third-party data: they are read
in place and never copied.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
from pathlib import Path

from ltmstore import __version__
from ltmstore.judge.heldout import heldout_store
from ltmstore.solve import METHODS
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct


def capture(lp: Path, folder: Path) -> Path:
    """Ingest and reconstruct one capture; the store path."""
    store = folder / f"{lp.parent.name}.zarr"
    ingest_rti(lp, store, progress=False)
    reconstruct(store, progress=False)
    return store


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--pixels", default=256, type=int)
    parser.add_argument("--methods", default=",".join(sorted(METHODS)))
    args = parser.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    captures = sorted(args.data.glob("*/dirs.lp"))
    if not captures:
        raise SystemExit(f"no */dirs.lp under {args.data}")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for lp in captures:
            store = capture(lp, Path(tmp))
            results[lp.parent.name] = {}
            for method in methods:
                row = heldout_store(store, method=method, folds=5, max_pixels=args.pixels)
                results[lp.parent.name][method] = row
                print(f"{lp.parent.name:>20s} {method:>7s} {row['heldout_snr_db']:6.2f} dB "
                      f"({row['seconds']:.1f} s)", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "heldout_rti.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "ltmstore": __version__, "command": "python bench/heldout_rti.py",
        "pixels": args.pixels, "results": results}, indent=2))
    names = list(results)
    print("\n| method | " + " | ".join(names) + " |\n| --- |" + " --- |" * len(names))
    for method in methods:
        cells = [f"{results[n][method]['heldout_snr_db']:.1f}" for n in names]
        print(f"| `{method}` | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
