"""The 4K capture's time against its accuracy, every run of ``bench/scale_4k.py`` side by side.

Run: ``python bench/scale_4k_chart.py [--results bench/results/scale_4k] [--out DIR]``.

Reads every ``scale_4k*.json`` in ``--results`` and draws, for each run's 4K capture, the wall
time of ``ltm ingest`` + ``ltm reconstruct`` (minutes; the ingest's share printed beside each
point) against SNR_Y on the fixed pixel subset, coloured by the size the canvas was rendered at
and the video's bit rate, beside issue 25's bounds: the hour, and 0.5 dB below the 512 render's
own capture at 50 Mbit/s (``scale_reference_512_50mbit.json``, when present). Whether a run
shared the machine is in the README's row for it, not in its file. Writes
``time_accuracy_4k.png`` and ``.json`` to ``--out`` (default: ``--results``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HOUR_MIN = 60.0
REFERENCE_512 = "scale_reference_512_50mbit.json"
MARGIN_DB = 0.5


def points(results: Path) -> list[dict]:
    """One point per 4K run: its file, rendered size, bit rate, minutes and SNR_Y."""
    out = []
    for path in sorted(results.glob("scale_4k*.json")):
        report = json.loads(path.read_text())
        run = report["runs"].get("4k")
        if run is None:
            continue
        ingest, reconstruct = run["ingest"]["wall_s"], run["reconstruct"]["wall_s"]
        out.append({"file": path.name, "rendered": report.get("render_size", 384),
                    "bitrate_mbit_s": report.get("bitrate_mbit_s") or 50.0,
                    "colour": bool(report.get("colour")),
                    "ingest_min": ingest / 60, "reconstruct_min": reconstruct / 60,
                    "total_min": (ingest + reconstruct) / 60,
                    "snr_y_db": run["snr_y_db_pixel_subset"]})
    return out


def chart(found: list[dict], path: Path, reference_db: float | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.8))
    groups = sorted({(p["rendered"], p["bitrate_mbit_s"]) for p in found})
    colours = dict(zip(groups, plt.get_cmap("tab10").colors, strict=False))
    for group in groups:
        mine = [p for p in found if (p["rendered"], p["bitrate_mbit_s"]) == group]
        ax.scatter([p["total_min"] for p in mine], [p["snr_y_db"] for p in mine], s=60,
                   color=colours[group],
                   label=f"rendered at {group[0]}, {group[1]:g} Mbit/s")
        for p in mine:
            ax.annotate(f"{_code(p['file'])}: ingest {p['ingest_min']:.0f} min",
                        (p["total_min"], p["snr_y_db"]), fontsize=6, xytext=(5, -2),
                        textcoords="offset points")
    ax.axvline(HOUR_MIN, color="k", ls="--", lw=1, label="issue 25: one hour")
    if reference_db is not None:
        ax.axhline(reference_db - MARGIN_DB, color="grey", ls=":", lw=1,
                   label=f"the 512 render's capture ({reference_db:.2f} dB) - {MARGIN_DB} dB")
    ax.set_xlabel("ltm ingest + ltm reconstruct, wall time (min, 2 cores)")
    ax.set_ylabel("SNR_Y against the truth (dB)")
    ax.set_title("A 4K phone video of the canvas, whole: time against accuracy")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _code(name: str) -> str:
    """The code a result file was kept for (``scale_4k_99889ea.json``: 99889ea), or "latest"."""
    last = name.removesuffix(".json").rsplit("_", 1)[-1]
    return last if len(last) == 7 and all(c in "0123456789abcdef" for c in last) else "latest"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("bench/results/scale_4k"))
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    out = args.out or args.results
    found = points(args.results)
    out.mkdir(parents=True, exist_ok=True)
    (out / "time_accuracy_4k.json").write_text(json.dumps(found, indent=1) + "\n")
    reference = args.results / REFERENCE_512
    reference_db = (json.loads(reference.read_text())["runs"]["reference"]["snr_y_db_pixel_subset"]
                    if reference.exists() else None)
    chart(found, out / "time_accuracy_4k.png", reference_db)
    for p in found:
        print(f"{p['file']:42s} {p['total_min']:6.1f} min  {p['snr_y_db']:6.2f} dB")


if __name__ == "__main__":
    main()
