"""Speed on classic RTI captures: ``ltm ingest-rti`` + ``ltm reconstruct`` as whole commands, and
the fit alone, beside the C++ Relight fitter when one is installed.

Run: ``python bench/rti_speed.py [--data ../shared/data] [--out bench/results] [--repeats 3]
[--relight-cli PATH] [--before OLD.json] [--old TREE]``.

For each real capture of ``--data`` (icon, coin, loewenkopf) and a 0.22 MP, 47-light capture
(the peer's benchmark size: the SynthRTI scene ``multi-obj1-material1``'s first 47 dome
photographs resized to 469 x 469, written as JPEG to a temporary folder, never into the
repository), the median of ``--repeats`` runs of:

* ``ltm ingest-rti`` and ``ltm reconstruct`` as subprocesses: wall time, Python start-up and
  imports included, and their CPU time (user + system, all threads);
* the same two library calls in this process (no start-up), and from the ``reconstruct``
  record the fit alone: reading the frames and building the models (``prepare_s``) plus the
  leave-one-light-out choice of every tile's model (``fit_s``); ``solve_s`` adds evaluating
  the chosen models on the lattice for every pixel and writing ``ltm``;
* ``ltm --help`` (what the command costs before it does anything);
* ``relight-cli -b BASIS CAPTURE OUT`` for each of ``--relight-bases``, when ``--relight-cli``
  (default: ``relight-cli`` on ``PATH``) exists; the column is left out otherwise. ``CAPTURE``
  is the ``.lp``'s folder, or where its photographs lie in a subfolder (loewenkopf), a
  temporary folder of links to them (:func:`relight_input`).

The machine is shared: the load average is recorded before and after each capture, beside the
numbers (medians, no CPU pinning). Writes ``rti_speed.json`` and ``rti_speed.png`` to ``--out``;
``--before`` draws an earlier run's JSON beside this one. ``--old TREE`` (a copy of an earlier
commit, e.g. ``git archive HEAD | tar -x -C TREE``) also runs the two commands of that code
(``PYTHONPATH=TREE``) in every repeat, right after this code's, as ``old_*`` keys: old and new
under the same load.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.lp import read_lp
from ltmstore.core.provenance import commit
from ltmstore.core.store import open_group
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct

REAL = ("realrti-item9-coin", "realrti-item3-icon", "loewenkopf")
PEER_SCENE = "synthrti/multi-obj1-material1"
PEER_SIZE = (0.22e6, 47)  # pixels, lights: the capture relight-cli fits in 0.4-0.8 s
TARGET_BOTH_S = 5.0
OLD_CODE = "old code, same run"  # the chart's label of --old's bars

# relight-cli refuses ptm and hsh without the number of planes their colour fits take (RGB)
RELIGHT_PLANES = {"ptm": ("-p", "18"), "hsh": ("-p", "27")}


def ltm_command() -> list[str]:
    """The ``ltm`` console script beside this Python, or the same entry point through it."""
    script = Path(sys.executable).with_name("ltm")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "import sys; from ltmstore.cli import main; sys.exit(main())"]


def run(command: list[str], env: dict | None = None) -> tuple[float, float]:
    """Wall and CPU seconds (user + system of the child and its threads) of ``command``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def peer_capture(data: Path, tmp: Path) -> Path:
    """The first 47 dome photographs of :data:`PEER_SCENE` resized to about 0.22 MP (JPEG)."""
    pixels, lights = PEER_SIZE
    return resized_capture(data, tmp / "peer-0.22MP-47", pixels, lights)


def resized_capture(data: Path, folder: Path, pixels: float, lights: int) -> Path:
    """The first ``lights`` dome photographs of :data:`PEER_SCENE` resized to about ``pixels``
    (square, JPEG quality 95) in ``folder``; its ``.lp``."""
    lp = data / PEER_SCENE / "dome" / "dirs.lp"
    names, directions = read_lp(lp)
    folder.mkdir(parents=True)
    side = round(np.sqrt(pixels))
    lines = [str(lights)]
    for i, name in enumerate(names[:lights]):
        image = cv2.imread(str(lp.parent / name), cv2.IMREAD_COLOR)
        big = cv2.resize(image, (side, side), interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(folder / f"im{i:02d}.jpg"), big, [cv2.IMWRITE_JPEG_QUALITY, 95])
        lines.append(f"im{i:02d}.jpg {' '.join(f'{v:.6f}' for v in directions[i])}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"


def relight_input(lp: Path, tmp: Path) -> Path:
    """The folder ``relight-cli`` fits: the ``.lp``'s own where its photographs lie beside it,
    else (loewenkopf's ``jpg/``: relight-cli reads only the ``.lp``'s folder and refuses a
    count that differs) a temporary folder of links to them and an ``.lp`` naming the links."""
    names, directions = read_lp(lp)
    if all(Path(name).parent == Path(".") for name in names):
        return lp.parent
    folder = tmp / "relight-input"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    lines = [str(len(names))]
    for i, (name, direction) in enumerate(zip(names, directions, strict=True)):
        link = f"im{i:04d}{Path(name).suffix}"
        (folder / link).symlink_to((lp.parent / name).resolve())
        lines.append(f"{link} {' '.join(f'{v:.8f}' for v in direction)}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder


def speed(lp: Path, tmp: Path, repeats: int, relight_cli: str | None,
          bases: list[str], old: Path | None = None) -> dict:
    """Medians over ``repeats`` of the whole commands, the library calls and the fit."""
    ltm = ltm_command()
    store = tmp / "speed.zarr"
    rows: dict[str, list[float]] = {}
    refused: dict[str, str] = {}  # relight-cli basis: its last output line

    def add(key: str, value: float) -> None:
        rows.setdefault(key, []).append(value)

    peer_input = relight_input(lp, tmp) if relight_cli else None
    load_before = load()
    for _ in range(repeats):
        wall, cpu = run([*ltm, "ingest-rti", str(lp), str(store), "--overwrite"])
        add("ingest_rti_s", wall)
        add("ingest_rti_cpu_s", cpu)
        wall, cpu = run([*ltm, "reconstruct", str(store)])
        add("reconstruct_s", wall)
        add("reconstruct_cpu_s", cpu)
        add("both_s", rows["ingest_rti_s"][-1] + wall)
        if old is not None:  # the earlier code, the same commands, right after
            env = {**os.environ, "PYTHONPATH": str(old)}
            old_store = tmp / "speed-old.zarr"
            wall, cpu = run([*ltm, "ingest-rti", str(lp), str(old_store), "--overwrite"], env)
            add("old_ingest_rti_s", wall)
            add("old_ingest_rti_cpu_s", cpu)
            wall, cpu = run([*ltm, "reconstruct", str(old_store)], env)
            add("old_reconstruct_s", wall)
            add("old_reconstruct_cpu_s", cpu)
            add("old_both_s", rows["old_ingest_rti_s"][-1] + wall)
        start = time.perf_counter()
        ingest_rti(lp, store, overwrite=True, progress=False)
        add("ingest_call_s", time.perf_counter() - start)
        start = time.perf_counter()
        reconstruct(store, progress=False)
        add("reconstruct_call_s", time.perf_counter() - start)
        timings = open_group(store).attrs["stages"]["reconstruct"]["timings"]
        add("fit_s", timings["prepare_s"] + timings["fit_s"])
        add("fit_and_write_ltm_s", timings["prepare_s"] + timings["solve_s"])
        for basis in bases if relight_cli else ():
            out = tmp / f"relight-{basis}"
            shutil.rmtree(out, ignore_errors=True)
            try:
                add(f"relight_cli_{basis}_s", run([relight_cli, "-b", basis,
                                                   *RELIGHT_PLANES.get(basis, ()),
                                                   str(peer_input), str(out)])[0])
            except subprocess.CalledProcessError as exc:  # e.g. images in a subfolder
                refused[basis] = (exc.stdout + exc.stderr).decode(errors="replace").strip()
                refused[basis] = refused[basis].splitlines()[-1] if refused[basis] else ""
    names, _ = read_lp(lp)
    height, width = open_group(store)["frames"].shape[1:]
    result = {key: statistics.median(values) for key, values in rows.items()}
    return {**result, "relight_cli_refused": refused, "repeats": repeats, "lights": len(names),
            "pixels": int(height * width),
            "load_before": load_before, "load_after": load()}


def help_cost(repeats: int) -> dict:
    """Median wall and CPU seconds of ``ltm --help``."""
    runs = [run([*ltm_command(), "--help"]) for _ in range(repeats)]
    return {"wall_s": statistics.median(r[0] for r in runs),
            "cpu_s": statistics.median(r[1] for r in runs)}


def chart(result: dict, before: dict | None, path: Path) -> None:
    """Bars per capture: the two commands (wall) beside ``relight-cli``'s whole fit of the same
    lights (the fastest of its bases, with our time over it written above), their CPU time, and
    the two library calls in one process (no start-up) beside ``relight-cli`` again."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["captures"])
    runs = [("before", before), ("now", result)] if before else [("now", result)]
    if any("old_both_s" in r for r in result["captures"].values()):  # --old: the same run
        old = {n: {k.removeprefix("old_"): v for k, v in r.items() if k.startswith("old_")}
               for n, r in result["captures"].items()}
        runs.insert(-1, (OLD_CODE, {**result, "captures": old}))
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    slots = len(runs) + 1  # the peer's bar after the runs'
    width = 0.8 / slots
    x = np.arange(len(names))
    for k, (label, res) in enumerate(runs):
        rows = [res["captures"].get(n, {}) for n in names]
        ingest = np.array([r.get("ingest_rti_s", np.nan) for r in rows])
        rec = np.array([r.get("reconstruct_s", np.nan) for r in rows])
        pos = x + (k - (slots - 1) / 2) * width
        axes[0].bar(pos, ingest, width, label=f"ingest-rti ({label})", alpha=0.5 + 0.5 * k)
        axes[0].bar(pos, rec, width, bottom=ingest, label=f"reconstruct ({label})",
                    alpha=0.5 + 0.5 * k)
        axes[1].bar(pos, [r.get("ingest_rti_cpu_s", np.nan) + r.get("reconstruct_cpu_s", np.nan)
                          for r in rows], width, label=f"CPU ({label})", alpha=0.5 + 0.5 * k)
        axes[2].bar(pos, [r.get("ingest_call_s", np.nan) + r.get("reconstruct_call_s", np.nan)
                          for r in rows], width, label=f"library calls ({label})",
                    alpha=0.5 + 0.5 * k)
    rows = [result["captures"][n] for n in names]
    peer = np.array([min((r[k] for k in r if k.startswith("relight_cli_") and k.endswith("_s")),
                         default=np.nan) for r in rows])
    if np.isfinite(peer).any():
        pos = x + (slots - 1) / 2 * width
        for ax in (axes[0], axes[2]):
            ax.bar(pos, peer, width, color="0.3", label="relight-cli (fastest basis)")
        now = x + (len(runs) - 1 - (slots - 1) / 2) * width  # this run's bars
        for xi, r, p in zip(now, rows, peer, strict=True):
            if np.isfinite(p):
                axes[0].text(xi, r["both_s"], f"{r['both_s'] / p:.0f}x", ha="center",
                             va="bottom", fontsize=8)
    axes[0].axhline(TARGET_BOTH_S, color="k", ls="--", lw=1, label=f"{TARGET_BOTH_S:g} s")
    axes[0].set_title("ingest-rti + reconstruct, whole commands (wall)", fontsize=10)
    axes[1].set_title("the same two commands: CPU time (user + system)", fontsize=10)
    axes[2].set_title("the same two as library calls in one process (no start-up)", fontsize=10)
    for ax in axes:
        ax.set_xticks(x, [n.replace("realrti-item", "") for n in names], fontsize=8)
        ax.set_ylabel("seconds")
        ax.legend(fontsize=7, loc="upper left")
        ax.set_ylim(top=ax.get_ylim()[1] * 1.25)  # room for the legend
    loads = "; ".join(f"{label}: load average {res['load_start']} -> {res['load_end']}"
                      for label, res in runs if label != OLD_CODE)
    fig.suptitle(f"{loads} ({os.cpu_count()} cores); medians of {result['repeats']}",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--repeats", default=3, type=int)
    parser.add_argument("--relight-cli", default=shutil.which("relight-cli"))
    parser.add_argument("--relight-bases", default="rbf,hsh,ptm")
    parser.add_argument("--before", type=Path, help="an earlier rti_speed.json to draw beside")
    parser.add_argument("--only", help="comma-separated capture names (default: all)")
    parser.add_argument("--old", type=Path,
                        help="a tree of earlier code to run beside (PYTHONPATH=OLD)")
    args = parser.parse_args()
    relight_cli = args.relight_cli if args.relight_cli and Path(args.relight_cli).exists() \
        else None
    bases = args.relight_bases.split(",")
    result = {"machine": {"platform": platform.platform(), "python": platform.python_version(),
                          "cores": os.cpu_count()},
              "command": "python " + " ".join(sys.argv), "commit": commit(),
              "repeats": args.repeats,
              "load_start": load(), "relight_cli": relight_cli,
              "help": help_cost(args.repeats), "captures": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        lps = {name: args.data / name / "dirs.lp" for name in REAL
               if (args.data / name / "dirs.lp").is_file()}
        if (args.data / PEER_SCENE).is_dir():
            lps["peer-0.22MP-47"] = peer_capture(args.data, tmp)
        if args.only:
            lps = {k: v for k, v in lps.items() if k in args.only.split(",")}
        for name, lp in lps.items():
            row = speed(lp, tmp, args.repeats, relight_cli, bases, args.old)
            result["captures"][name] = row
            print(f"{name:>20s} {row['pixels'] / 1e6:.2f} MP {row['lights']:3d} lights: "
                  f"ingest-rti {row['ingest_rti_s']:.2f} s + reconstruct "
                  f"{row['reconstruct_s']:.2f} s = {row['both_s']:.2f} s "
                  f"(CPU {row['ingest_rti_cpu_s']:.2f} + {row['reconstruct_cpu_s']:.2f} s); "
                  f"fit {row['fit_s']:.2f} s; load {row['load_before']} -> "
                  f"{row['load_after']}", flush=True)
            if args.old:
                print(f"{'old code':>20s}: ingest-rti {row['old_ingest_rti_s']:.2f} s + "
                      f"reconstruct {row['old_reconstruct_s']:.2f} s = {row['old_both_s']:.2f} "
                      f"s (CPU {row['old_ingest_rti_cpu_s']:.2f} + "
                      f"{row['old_reconstruct_cpu_s']:.2f} s)", flush=True)
            print(f"{'relight-cli':>20s}: " + ", ".join(
                f"{b} {row[f'relight_cli_{b}_s']:.2f} s" for b in bases
                if f"relight_cli_{b}_s" in row), flush=True)
    result["load_end"] = load()
    print(f"ltm --help: {result['help']['wall_s']:.2f} s wall, {result['help']['cpu_s']:.2f} s "
          "CPU")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rti_speed.json").write_text(json.dumps(result, indent=1))
    before = json.loads(args.before.read_text()) if args.before else None
    chart(result, before, args.out / "rti_speed.png")
    print(f"wrote {args.out / 'rti_speed.json'} and {args.out / 'rti_speed.png'}")


if __name__ == "__main__":
    main()
