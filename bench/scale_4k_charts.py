"""The charts of every ``bench/scale_4k.py`` run kept in ``--results``: where the 4K capture's
accuracy goes, and its time against its accuracy.

Run: ``python bench/scale_4k_charts.py [--results bench/results/scale_4k] [--out DIR]``.

* ``codec.png`` and ``codec.json``: SNR_Y against the bits per pixel and frame the video really
  holds (its bytes, not the bitrate asked of x264, which the small capture does not use up), one
  point per grey run of every ``scale_*.json`` (``--colour`` runs paint another picture and are
  left out), coloured by frame and rendered size and marked by the stored form and rank rule of
  their ``ltm reconstruct`` (a factored store made before the held-out threshold of 8332ee5 says
  so). Issue 25 compares a 4K capture with the same scene's small capture: the points of one
  rendered size, at the same bits per pixel.
* ``time_accuracy_4k.png`` and ``.json``: for each ``scale_4k*.json`` run's 4K capture, the wall
  time of ``ltm ingest`` + ``ltm reconstruct`` (minutes; the ingest's share printed beside each
  point) against SNR_Y on the fixed pixel subset, coloured by the size the canvas was rendered at
  and the video's bit rate, beside issue 25's bounds: the hour, and 0.5 dB below the 512 render's
  own capture at 50 Mbit/s (``scale_reference_512_50mbit.json``, when present).

Both are written to ``--out`` (default: ``--results``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HOUR_MIN = 60.0
REFERENCE_512 = "scale_reference_512_50mbit.json"
MARGIN_DB = 0.5


def codec_points(results: Path) -> list[dict]:
    """One point per run of every result file: size, bits per pixel and frame, SNR_Y, form."""
    out = []
    for path in sorted(results.glob("scale_*.json")):
        report = json.loads(path.read_text())
        if report.get("colour"):  # another painting: its luminance is not the grey one's
            continue
        captures = report["captures"]
        for name, run in report["runs"].items():
            height, width = run["image"][:2]
            record = run["stage_records"]["reconstruct"]
            form = record.get("form", "dense")
            if form == "factored":
                form += ", held-out threshold" if "rank_rule" in record else ", energy budget"
            bits = 8 * captures["video_bytes"][name] / (captures["frames"] * height * width)
            out.append({"file": path.name, "run": name, "size": f"{width} x {height}",
                        "rendered": report.get("render_size", 384),
                        "bits_per_pixel": bits, "snr_y_db": run["snr_y_db_pixel_subset"],
                        "form": form, "bitrate_mbit_s": report.get("bitrate_mbit_s")})
    unique = {(p["size"], round(p["bits_per_pixel"], 4), p["form"], round(p["snr_y_db"], 3)): p
              for p in out}  # the same run kept under several names
    return sorted(unique.values(), key=lambda p: (p["size"], p["bits_per_pixel"]))


def codec_chart(found: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    markers = {"dense": "o", "factored, held-out threshold": "s",
               "factored, energy budget": "^"}
    sizes = sorted({(p["size"], p["rendered"]) for p in found})
    colours = dict(zip(sizes, plt.get_cmap("tab10").colors, strict=False))
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    seen = set()
    for p in found:
        size = (p["size"], p["rendered"])
        key = (*size, p["form"])
        label = f"{size[0]} (rendered at {size[1]}), {p['form']}"
        ax.scatter(p["bits_per_pixel"], p["snr_y_db"], marker=markers[p["form"]], s=60,
                   color=colours[size], label=None if key in seen else label)
        seen.add(key)
    ax.set_xscale("log")
    bits = [p["bits_per_pixel"] for p in found]
    ax.set_xticks([t for t in (0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 20)
                   if min(bits) / 2 <= t <= 2 * max(bits)])
    ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("video bits per pixel and frame (log)")
    ax.set_ylabel("SNR_Y against the truth (dB)")
    ax.set_title("The canvas rendered at 192-512 pixels, scaled, H.264 at several rates")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def time_points(results: Path) -> list[dict]:
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


def time_chart(found: list[dict], path: Path, reference_db: float | None) -> None:
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
    parser.add_argument("--results", default=Path("bench/results/scale_4k"), type=Path)
    parser.add_argument("--out", type=Path, help="default: --results")
    args = parser.parse_args()
    out = args.out or args.results
    out.mkdir(parents=True, exist_ok=True)

    found = codec_points(args.results)
    for p in found:
        print(f"{p['size']:>12s} ({p['rendered']})  {p['bits_per_pixel']:7.3f} bit/pixel"
              f"  {p['snr_y_db']:6.2f} dB  {p['form']}  ({p['file']})")
    (out / "codec.json").write_text(json.dumps(
        {"command": "python bench/scale_4k_charts.py", "points": found}, indent=1))
    codec_chart(found, out / "codec.png")

    runs = time_points(args.results)
    (out / "time_accuracy_4k.json").write_text(json.dumps(runs, indent=1) + "\n")
    reference = args.results / REFERENCE_512
    reference_db = (json.loads(reference.read_text())["runs"]["reference"]["snr_y_db_pixel_subset"]
                    if reference.exists() else None)
    time_chart(runs, out / "time_accuracy_4k.png", reference_db)
    for p in runs:
        print(f"{p['file']:42s} {p['total_min']:6.1f} min  {p['snr_y_db']:6.2f} dB")


if __name__ == "__main__":
    main()
