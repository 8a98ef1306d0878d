"""Peak memory of ``ltm relight`` on a classic (far-light) capture, one light and three, beside
``ltm reconstruct``'s on the same store, against the image's size (issue 64 item 13).

Run: ``python bench/relight_memory.py [--data ../shared/data] [--out bench/results]
[--sizes 1,4] [--lights 47] [--old TREE] [--old-label LABEL] [--old-sizes 1,4]``.

Each capture is SynthRTI ``multi-obj1-material1``'s first ``--lights`` dome photographs resized
to ``SIZE`` megapixels (``bench/rti_speed.py``'s ``resized_capture``, in a temporary folder),
ingested and reconstructed once (``ltm reconstruct``'s wall time and peak recorded); then, as
subprocesses, ``ltm relight STORE --direction ...`` at one light and at three (one PNG per
light), with this code and, where ``--old`` names a tree of earlier code, with it
(``PYTHONPATH=TREE``, at ``--old-sizes`` only: it may not fit in memory at the largest). Peak
resident memory is each command's own ``ru_maxrss`` (from ``wait4``, as ``/usr/bin/time -v``
reports it); one run each (memory does not vary with the load as time does); the load average
before and after. Whether the old and new PNGs are byte for byte the same is recorded. Writes
``relight_memory.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from rti_scale import machine, run, size_options  # noqa: E402
from rti_speed import load, ltm_command, resized_capture  # noqa: E402

from ltmstore.core.provenance import commit  # noqa: E402

LIGHTS = {1: [(0.3, 0.2, 1)], 3: [(0.3, 0.2, 1), (-0.4, 0.1, 0.8), (0, 0, 1)]}


def relight(store: Path, out: Path, n: int, env: dict | None = None) -> tuple[float, float]:
    """Wall seconds and peak GiB of ``ltm relight`` of ``store`` at ``n`` lights into ``out``."""
    directions = [arg for d in LIGHTS[n] for arg in ("--direction", ",".join(map(str, d)))]
    return run([*ltm_command(), "relight", str(store), *directions, "-o", str(out),
                "--overwrite"], env)


def pngs(folder: Path, stem: str) -> dict[str, bytes]:
    return {p.name.removeprefix(stem): p.read_bytes() for p in sorted(folder.glob(stem + "*"))}


def measure(lp: Path, tmp: Path, old: Path | None) -> dict:
    """Reconstruct's and relight's (this code's, ``old``'s) wall seconds and peak GiB."""
    ltm = ltm_command()
    store = tmp / "store.zarr"
    row: dict = {"load_before": load()}
    run([*ltm, "ingest-rti", str(lp), str(store), "--overwrite"])
    row["reconstruct_s"], row["reconstruct_gib"] = run([*ltm, "reconstruct", str(store)])
    for n in LIGHTS:
        row[f"relight{n}_s"], row[f"relight{n}_gib"] = relight(store, tmp / f"new{n}.png", n)
        if old is not None:
            env = {**os.environ, "PYTHONPATH": str(old)}
            row[f"old_relight{n}_s"], row[f"old_relight{n}_gib"] = relight(
                store, tmp / f"old{n}.png", n, env)
            row[f"relight{n}_png_identical"] = pngs(tmp, f"new{n}") == pngs(tmp, f"old{n}")
    row["load_after"] = load()
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    size_options(parser, "1,4")
    args = parser.parse_args()
    old_sizes = set((args.old_sizes or args.sizes).split(","))
    result = {"machine": machine(),
              "command": "python " + " ".join(sys.argv), "commit": commit(),
              "lights": args.lights, "relight_directions": LIGHTS,
              "old_label": args.old_label if args.old else None, "load_start": load(),
              "sizes": {}}
    with tempfile.TemporaryDirectory(prefix="ltm-relight-memory-") as tmp:
        for size in args.sizes.split(","):
            work = Path(tmp) / f"{size}MP"
            lp = resized_capture(args.data, work / "capture", float(size) * 1e6, args.lights)
            row = measure(lp, work, args.old if size in old_sizes else None)
            result["sizes"][size] = row
            line = (f"{size:>5s} MP: reconstruct {row['reconstruct_gib']:.2f} GiB, relight "
                    f"{row['relight1_gib']:.2f} GiB (1 light), {row['relight3_gib']:.2f} GiB (3)")
            if "old_relight1_gib" in row:
                line += (f"; old relight {row['old_relight1_gib']:.2f} / "
                         f"{row['old_relight3_gib']:.2f} GiB")
            print(line, flush=True)
    result["load_end"] = load()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "relight_memory.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
