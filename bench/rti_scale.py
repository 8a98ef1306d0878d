"""Museum-size classic captures: ``ltm ingest-rti`` + ``ltm reconstruct`` wall time (to the
relightable store and to the refined one) and peak memory against the image's size, beside
earlier code and the C++ Relight fitter.

Run: ``python bench/rti_scale.py [--data ../shared/data] [--out bench/results] [--sizes 1,4,12]
[--lights 47] [--repeats 2] [--old TREE] [--old-sizes 1,4,12] [--relight-cli PATH]
[--stage1-only] [--name rti_scale]``.

Each capture is SynthRTI ``multi-obj1-material1``'s first ``--lights`` dome photographs resized
to ``SIZE`` megapixels (square, JPEG quality 95, in a temporary folder, never the repository):
the content is a 320 x 320 render's, so only the time and memory are measured here, not the
accuracy (``bench/heldout_table.py`` does that at the photographs' own size). Per size and repeat,
as subprocesses, in turn: this code's commands (``ingest-rti``, ``reconstruct --stage classic``,
``relight`` of one light (the first relit image), then ``reconstruct``, the refinement, which
``--stage1-only`` leaves out), ``--old``'s (``PYTHONPATH=TREE``, at
``--old-sizes`` only: the old code may not fit in memory at the largest) and ``relight-cli -b
rbf`` when it exists. Wall time and the peak resident memory of each command (its own
``ru_maxrss`` from ``wait4``), medians over ``--repeats``; the load average before and after.
Writes ``NAME.json`` and ``NAME.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ltmstore.core.provenance import commit

sys.path.insert(0, str(Path(__file__).parent))
from rti_speed import load, ltm_command, resized_capture  # noqa: E402


def machine() -> dict:
    """This machine as a result JSON records it: platform, Python, cores, memory (GiB)."""
    return {"platform": platform.platform(), "python": platform.python_version(),
            "cores": os.cpu_count(),
            "memory_gib": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30,
                                1)}


def size_options(parser: argparse.ArgumentParser, sizes: str) -> None:
    """The options of a bench over resized classic captures beside an older tree's code."""
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--sizes", default=sizes, help="megapixels, comma-separated")
    parser.add_argument("--lights", default=47, type=int)
    parser.add_argument("--old", type=Path, help="a tree of earlier code (PYTHONPATH=OLD)")
    parser.add_argument("--old-label", default="old code")
    parser.add_argument("--old-sizes", help="sizes at which --old runs (default: all)")


def run(command: list[str], env: dict | None = None) -> tuple[float, float]:
    """Wall seconds and peak resident memory (GiB) of ``command`` (its own, from wait4)."""
    with tempfile.TemporaryFile() as log:  # a pipe would fill with progress bars and block
        start = time.perf_counter()
        proc = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            log.seek(0)
            tail = log.read().decode(errors="replace")[-500:]
            raise RuntimeError(f"{' '.join(command)} exited {proc.returncode}: {tail}")
    return wall, usage.ru_maxrss / 2**20  # kB on Linux


def ours(lp: Path, store: Path, env: dict | None = None, refine: bool = True) -> dict:
    """The commands' wall seconds and peak memory: ``ingest-rti``, ``reconstruct --stage
    classic`` (with it, ``stage1_s``: the store relights), ``relight`` of one light
    (``first_image_s``: the first relit image) and, where ``refine``, ``reconstruct`` (the
    surface's refinement; ``both_s``: the whole default)."""
    ltm = ltm_command()
    ingest = run([*ltm, "ingest-rti", str(lp), str(store), "--overwrite"], env)
    classic = run([*ltm, "reconstruct", str(store), "--stage", "classic"], env)
    image = store.with_suffix(".png")
    image.unlink(missing_ok=True)
    relit = run([*ltm, "relight", str(store), "--direction", "0.3,0.2,0.9", "-o", str(image)],
                env)
    row = {"ingest_rti_s": ingest[0], "classic_s": classic[0], "relight_s": relit[0],
           "stage1_s": ingest[0] + classic[0], "first_image_s": ingest[0] + classic[0] + relit[0],
           "ingest_rti_gib": ingest[1], "reconstruct_gib": classic[1], "relight_gib": relit[1]}
    if refine:
        again = run([*ltm, "reconstruct", str(store)], env)
        row.update(refine_s=again[0], reconstruct_s=classic[0] + again[0],
                   both_s=ingest[0] + classic[0] + again[0],
                   reconstruct_gib=max(classic[1], again[1]))
    shutil.rmtree(store)
    return row


def measure(lp: Path, tmp: Path, repeats: int, old: Path | None, relight_cli: str | None,
            refine: bool = True) -> dict:
    """Medians over ``repeats`` of this code's, the old code's and relight-cli's runs."""
    rows: dict[str, list[float]] = {}
    load_before = load()
    for _ in range(repeats):
        runs = {"": ours(lp, tmp / "new.zarr", refine=refine)}
        if old is not None:
            runs["old_"] = ours(lp, tmp / "old.zarr", {**os.environ, "PYTHONPATH": str(old)},
                                refine)
        if relight_cli:
            out = tmp / "relight-rbf"
            shutil.rmtree(out, ignore_errors=True)
            wall, peak = run([relight_cli, "-b", "rbf", str(lp.parent), str(out)])
            runs["relight_cli_"] = {"rbf_s": wall, "rbf_gib": peak}
        for prefix, values in runs.items():
            for key, value in values.items():
                rows.setdefault(prefix + key, []).append(value)
    return {**{k: statistics.median(v) for k, v in rows.items()}, "runs": rows,
            "load_before": load_before, "load_after": load()}


def chart(result: dict, path: Path) -> None:
    """Wall time and peak memory against megapixels: this code, the old code, relight-cli."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = result["sizes"]
    mp = np.array([float(s) for s in sizes])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    series = [("", "ltm (this code)", "C0"), ("old_", f"ltm ({result['old_label']})", "C1"),
              ("relight_cli_", "relight-cli -b rbf", "0.3")]
    for prefix, label, color in series:
        for ax, keys, style, suffix in ((axes[0], ("both_s", "rbf_s"), "o-", ""),
                                        (axes[0], ("stage1_s",), "s--", ", relightable"),
                                        (axes[0], ("first_image_s",), "^:", ", first image"),
                                        (axes[1], ("reconstruct_gib", "rbf_gib"), "o-", ""),
                                        (axes[1], ("ingest_rti_gib",), "s--", ", ingest-rti")):
            values = np.array([next((sizes[s][prefix + k] for k in keys
                                     if prefix + k in sizes[s]), np.nan) for s in sizes])
            if np.isfinite(values).any():
                ax.plot(mp, values, style, color=color, label=label + suffix)
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    axes[1].axhline(memory, color="k", ls="--", lw=1, label=f"this machine ({memory:.0f} GiB)")
    axes[0].set_title("ingest-rti + reconstruct (wall): both stages, relightable\n"
                      "(--stage classic) and its first relit image (+ ltm relight)", fontsize=10)
    axes[0].set_ylabel("seconds")
    axes[1].set_title("peak resident memory of reconstruct (and of ingest-rti)", fontsize=10)
    axes[1].set_ylabel("GiB")
    for ax in axes:
        ax.set_xlabel(f"megapixels ({result['lights']} photographs)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result['machine']['cores']} cores; medians of {result['repeats']}; "
                 f"load average {result['load_start']} -> {result['load_end']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--sizes", default="1,4,12", help="megapixels, comma-separated")
    parser.add_argument("--lights", default=47, type=int)
    parser.add_argument("--repeats", default=2, type=int)
    parser.add_argument("--old", type=Path, help="a tree of earlier code (PYTHONPATH=OLD)")
    parser.add_argument("--old-label", default="old code")
    parser.add_argument("--old-sizes", help="sizes at which --old runs (default: all)")
    parser.add_argument("--relight-cli", default=shutil.which("relight-cli"))
    parser.add_argument("--stage1-only", action="store_true",
                        help="leave the refinement out: the relightable store and its first image")
    parser.add_argument("--name", default="rti_scale", help="the results' file name")
    args = parser.parse_args()
    relight_cli = args.relight_cli if args.relight_cli and Path(args.relight_cli).exists() \
        else None
    old_sizes = set((args.old_sizes or args.sizes).split(","))
    result = {"machine": {"platform": platform.platform(), "python": platform.python_version(),
                          "cores": os.cpu_count()},
              "command": "python " + " ".join(sys.argv), "commit": commit(),
              "repeats": args.repeats, "lights": args.lights, "relight_cli": relight_cli,
              "old_label": args.old_label, "load_start": load(), "sizes": {}}
    with tempfile.TemporaryDirectory(prefix="ltm-rti-scale-") as tmp:
        tmp = Path(tmp)
        # once each, not timed: Numba compiles and caches its kernels in a tree's first run
        warm = resized_capture(args.data, tmp / "warm-up", 1e4, args.lights)
        ours(warm, tmp / "new.zarr", refine=not args.stage1_only)
        if args.old:
            ours(warm, tmp / "old.zarr", {**os.environ, "PYTHONPATH": str(args.old)},
                 not args.stage1_only)
        for size in args.sizes.split(","):
            lp = resized_capture(args.data, tmp / f"capture-{size}MP", float(size) * 1e6,
                                 args.lights)
            old = args.old if size in old_sizes else None
            row = measure(lp, tmp, args.repeats, old, relight_cli, not args.stage1_only)
            result["sizes"][size] = row
            line = (f"{size:>5s} MP: ltm {row.get('both_s', np.nan):.1f} s (relightable after "
                    f"{row['stage1_s']:.1f} s, first image {row['first_image_s']:.1f} s), "
                    f"reconstruct peak {row['reconstruct_gib']:.2f} GiB")
            if "old_stage1_s" in row:
                line += (f"; old {row.get('old_both_s', np.nan):.1f} s "
                         f"({row['old_stage1_s']:.1f} s, {row['old_first_image_s']:.1f} s), "
                         f"{row['old_reconstruct_gib']:.2f} GiB")
            if "relight_cli_rbf_s" in row:
                line += (f"; relight-cli {row['relight_cli_rbf_s']:.1f} s, "
                         f"{row['relight_cli_rbf_gib']:.2f} GiB")
            print(line + f"; load {row['load_before']} -> {row['load_after']}", flush=True)
            shutil.rmtree(lp.parent)
            result["load_end"] = load()
            args.out.mkdir(parents=True, exist_ok=True)  # after every size: a long run
            (args.out / f"{args.name}.json").write_text(json.dumps(result, indent=1))
    chart(result, args.out / f"{args.name}.png")
    print(f"wrote {args.out / args.name}.json and .png")


if __name__ == "__main__":
    main()
