"""Where the 4K capture's accuracy goes: SNR_Y against the video's bits per pixel, by frame size.

Run: ``python bench/codec_chart.py [--results bench/results/scale_4k] [--out DIR]``.

Reads every grey ``bench/scale_4k.py`` result in ``--results`` (each run: the frame size, the
size the canvas was rendered at before scaling, the video's bytes, its frames and SNR_Y against
the truth on the fixed pixel subset; ``--colour`` runs paint another picture and are left out),
and draws SNR_Y against the bits per pixel and frame the video really holds (its bytes, not the
bitrate asked of x264, which the small capture does not use up). Points are coloured by frame
and rendered size, and marked by the stored form and rank rule of their ``ltm reconstruct`` (a
factored store made before the held-out threshold of 8332ee5 says so). Issue 25 compares a 4K
capture with the same scene's small capture: the points of one rendered size, at the same bits
per pixel. Writes ``codec.png`` and ``codec.json`` to
``--out`` (default: ``--results``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def points(results: Path) -> list[dict]:
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
    return out


def chart(found: list[dict], path: Path) -> None:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", default=Path("bench/results/scale_4k"), type=Path)
    parser.add_argument("--out", type=Path, help="default: --results")
    args = parser.parse_args()
    out = args.out or args.results
    found = points(args.results)
    unique = {(p["size"], round(p["bits_per_pixel"], 4), p["form"], round(p["snr_y_db"], 3)): p
              for p in found}  # the same run kept under several commits' names
    found = sorted(unique.values(), key=lambda p: (p["size"], p["bits_per_pixel"]))
    for p in found:
        print(f"{p['size']:>12s} ({p['rendered']})  {p['bits_per_pixel']:7.3f} bit/pixel"
              f"  {p['snr_y_db']:6.2f} dB"
              f"  {p['form']}  ({p['file']})")
    out.mkdir(parents=True, exist_ok=True)
    (out / "codec.json").write_text(json.dumps(
        {"command": "python bench/codec_chart.py", "points": found}, indent=1))
    chart(found, out / "codec.png")


if __name__ == "__main__":
    main()
