"""The far-light surface's cast shadows on the synthetic relief at several sizes: held-out PSNR
at lights between the dome's rings and the whole commands' time, with the shadows as chosen and
with them left out (docs/method.md, "Cast shadows").

Run: ``python bench/cast_shadows.py [--sizes 96 256 512] [--work DIR] [--out bench/results]``.

Each size renders the relief (blocks casting hard shadows, the renderer's own shadow rays) under
SynthRTI's dome (49 lights, rings at 10-90 degrees) and at 20 test lights on rings at 20-80
degrees between them (``bench/heldout_table.py``'s), both once into ``--work``. Then, alternating,
``ltm ingest-rti`` + ``ltm reconstruct`` (timed as one) and ``ltm relight`` of the test lights
(timed), once with the default and once with the shadows never taken (``SHADOW_MARGIN = 1``, in
this process: the same code otherwise). PSNR: 8-bit sRGB, every pixel and channel, mean over the
test lights (as ``heldout_table``). Writes ``cast_shadows.json``, ``cast_shadows.png`` and
``cast_shadows_relit.png`` (the largest size's photograph at its lowest test light beside both
variants' relit images).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from heldout_table import render  # noqa: E402

from ltmstore import __version__  # noqa: E402
from ltmstore.core.store import open_store  # noqa: E402
from ltmstore.judge.photos import load_photos, score  # noqa: E402
from ltmstore.stages import surface as sf  # noqa: E402
from ltmstore.stages.ingest_rti import ingest_rti  # noqa: E402
from ltmstore.stages.reconstruct import reconstruct  # noqa: E402
from ltmstore.stages.relight import relight  # noqa: E402

VARIANTS = {"default": sf.SHADOW_MARGIN, "no shadows": 1.0}  # 1: never taken


def run(folder: Path, name: str, margin: float) -> dict:
    """One variant: its times, method and held-out PSNR."""
    sf.SHADOW_MARGIN = margin
    store = folder / f"{name.replace(' ', '-')}.zarr"
    start = time.perf_counter()
    ingest_rti(folder / "dome" / "dirs.lp", store, progress=False, overwrite=True)
    record = reconstruct(store, progress=False)
    fitted = time.perf_counter() - start
    directions, photos = load_photos(folder / "test" / "dirs.lp")
    start = time.perf_counter()
    images = relight(open_store(store), directions=directions).values
    relit = time.perf_counter() - start
    scores = [score(image, photo)[0] for image, photo in zip(images, photos, strict=True)]
    return {"reconstruct_s": fitted, "relight_s": relit, "psnr_db": float(np.mean(scores)),
            "method": next(iter(record["chosen_per_tile"])),
            "shadow_scores": record["timings"].get("shadow_scores"),
            "shadow_choice_s": record["timings"].get("shadow_choice_s")}


def chart(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted(results, key=int)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for name in VARIANTS:
        axes[0].plot(sizes, [results[s][name]["psnr_db"] for s in sizes], "o-", label=name)
        axes[1].plot(sizes, [results[s][name]["reconstruct_s"] for s in sizes], "o-", label=name)
    axes[0].set(xlabel="relief side (px)", ylabel="held-out PSNR (dB)",
                title="between the dome's rings")
    axes[1].set(xlabel="relief side (px)", ylabel="ingest-rti + reconstruct (s)",
                title="time (median)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def pictures(folder: Path, path: Path) -> None:
    """The photograph at the lowest test light beside each variant's relit image."""
    import cv2

    from ltmstore.core.transfer import encode

    directions, photos = load_photos(folder / "test" / "dirs.lp")
    low = int(np.argmin(directions[:, 2]))
    tiles = [photos[low]]
    for name in VARIANTS:
        store = open_store(folder / f"{name.replace(' ', '-')}.zarr")
        tiles.append(encode(relight(store, directions=directions[low:low + 1]).values[0],
                            "srgb"))
    gap = np.full((photos.shape[1], 4, 3), 255, np.uint8)
    row = np.concatenate([x for tile in tiles for x in (tile, gap)][:-1], axis=1)
    cv2.imwrite(str(path), row[..., ::-1])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[96, 256, 512])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--work", type=Path, default=Path("/tmp/cast_shadows"))
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args(argv)
    results = {}
    for size in args.sizes:
        folder = args.work / str(size)
        render(folder, "relief-ggx-raking", size)  # heldout_table's render at this size
        runs = {name: [] for name in VARIANTS}
        for _ in range(args.repeats):  # alternating
            for name, margin in VARIANTS.items():
                runs[name].append(run(folder, name, margin))
        results[str(size)] = {name: {**done[0], **{k: float(np.median([d[k] for d in done]))
                                                   for k in ("reconstruct_s", "relight_s")}}
                              for name, done in runs.items()}
        print(size, {n: (round(r["psnr_db"], 2), round(r["reconstruct_s"], 1),
                         round(r["relight_s"], 1), r["method"]) for n, r in
                     results[str(size)].items()}, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cast_shadows.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cores": 2}, "ltmstore": __version__,
        "command": "python bench/cast_shadows.py " + " ".join(sys.argv[1:]),
        "repeats": args.repeats, "results": results}, indent=1))
    chart(results, args.out / "cast_shadows.png")
    pictures(args.work / str(max(args.sizes)), args.out / "cast_shadows_relit.png")


if __name__ == "__main__":
    main()
