"""Held-out PSNR of the default beside every classic fit, on every capture and on far-light
renders made with other assumptions (docs/benchmarks.md, "Real captures: held-out photographs").

Run: ``python bench/heldout_table.py [--data ../shared/data] [--cache DIR] [--out bench/results]
[--figure] [NAME ...]``.

* Captures: the real ones of ``--data`` (every 6th light hidden) and the SynthRTI scenes
  (fitted on ``dome/``, scored on ``test/``);
* renders (``render/SCENE-SHADING-DOME``, made once into ``--cache``): the synthetic canvas,
  icon and relief (96 x 96 pixels) under far lights (a point light 50 m away) with the GGX
  shading of :mod:`ltmstore.synthetic.render`, a Beckmann lobe, or :data:`MISMATCHED`
  (Beckmann, cos^2 LED, ambient floor, clear coat); lit from a dome with raking lights (rings
  at 10-90 degrees of elevation, SynthRTI's counts), a dome without them (30-90 degrees), or 49
  random directions above 12 degrees; scored at 20 test lights on rings at 20, 40, 60 and 80
  degrees (those of a ``raking`` dome lie between its rings; below a ``noraking`` dome's lowest
  ring, 20 degrees is an extrapolation).

For each: :func:`ltmstore.judge.photos.heldout_photos` (PSNR of 8-bit sRGB images over every
pixel and channel, averaged over the held-out lights) of the default pipeline and of PTM, HSH2,
HSH3, RBF and HSH3 + RBF residual. Each capture's result is cached in ``--cache`` (the run can be
stopped and resumed; ``--rerun`` scores again). Writes ``heldout_table.json`` and
``heldout_table.md`` to ``--out`` from every cached result of the current names; ``--figure``
also ``heldout_photos.png`` (the README's and the gallery's picture): the first held-out
photograph of three captures beside the default's and the best classic fit's relit images
(those three scored again, keeping the images). The captures are third-party data: they are
read in place and never copied.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from ltmstore import __version__
from ltmstore.core.transfer import linear_to_srgb
from ltmstore.judge.photos import CLASSIC, heldout_photos
from ltmstore.synthetic.render import GGX, MISMATCHED, Shading, iter_frames
from ltmstore.synthetic.scenes import make_scene

REAL = ("realrti-item3-icon", "realrti-item9-coin", "loewenkopf")
SHADINGS = {"ggx": GGX, "beckmann": Shading(lobe="beckmann"), "mismatched": MISMATCHED}
DOMES = {"raking": {10: 18, 30: 12, 50: 10, 70: 8, 90: 1},
         "noraking": {30: 16, 45: 14, 60: 11, 75: 7, 90: 1}, "random": None}
TEST = {20: 5, 40: 5, 60: 5, 80: 5}
SCENES = ("canvas", "icon", "relief")
RENDER_SIZE = 96
DISTANCE = 50.0  # metres: a point light this far from a 20 cm object is a far light
FIGURE = ("realrti-item9-coin", "loewenkopf", "synthrti/multi-obj2-material1")
FIGURE_NAME = "heldout_photos.png"


def rings(spec: dict[int, int], offset: float = 0.0) -> np.ndarray:
    """Unit directions on rings ``{elevation (degrees): count}``."""
    out = []
    for elevation, count in spec.items():
        azimuth = np.linspace(0, 2 * np.pi, count, endpoint=False) + offset + elevation / 100
        e = np.radians(elevation)
        out += [[np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)] for a in azimuth]
    return np.array(out)


def random_directions(n: int, seed: int = 1, lowest: float = 12.0) -> np.ndarray:
    """``n`` directions uniform on the hemisphere above ``lowest`` degrees."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(np.sin(np.radians(lowest)), 1, n)
    azimuth = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(azimuth), r * np.sin(azimuth), z])


def write_lp(folder: Path, frames, directions: np.ndarray) -> Path:
    """8-bit sRGB PNGs of linear ``frames`` and their ``dirs.lp``."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = [str(len(directions))]
    for i, (d, image) in enumerate(zip(directions, frames, strict=True)):
        code = np.round(linear_to_srgb(np.clip(image, 0, 1)) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"im{i:02d}.png"), code[..., ::-1])
        lines.append(f"im{i:02d}.png {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"


def render(folder: Path, name: str, size: int = RENDER_SIZE) -> None:
    """The capture ``SCENE-SHADING-DOME`` (``size`` px square) into ``folder/dome`` and
    ``folder/test``."""
    if (folder / "test" / "dirs.lp").is_file():
        return
    scene_name, shading_name, dome = name.split("-")
    scene, shading = make_scene(scene_name, size=size, seed=0), SHADINGS[shading_name]
    top = next(iter_frames(scene, [np.array([0, 0, DISTANCE])], shading=shading,
                           intensity=DISTANCE**2))
    intensity = DISTANCE**2 * 0.6 / max(float(np.percentile(top, 99)), 1e-6)
    spec = DOMES[dome]
    for part, directions in (("dome", random_directions(49) if spec is None else rings(spec)),
                             ("test", rings(TEST, 0.3))):
        frames = iter_frames(scene, [DISTANCE * d for d in directions], shading=shading,
                             intensity=intensity)
        write_lp(folder / part, frames, directions)


def captures(data: Path, cache: Path) -> dict[str, tuple[Path, dict]]:
    """Name -> (``.lp``, ``heldout_photos`` arguments) of every capture; renders are made
    when first scored."""
    found = {name: (data / name / "dirs.lp", {"every": 6}) for name in REAL
             if (data / name / "dirs.lp").is_file()}
    for lp in sorted((data / "synthrti").glob("*/dome/dirs.lp")):
        found[f"synthrti/{lp.parents[1].name}"] = (lp, {"test_lp": lp.parents[1] / "test"
                                                        / "dirs.lp"})
    for scene in SCENES:
        for shading in SHADINGS:
            for dome in DOMES:
                folder = cache / "renders" / f"{scene}-{shading}-{dome}"
                found[f"render/{folder.name}"] = (folder / "dome" / "dirs.lp",
                                                  {"test_lp": folder / "test" / "dirs.lp"})
    return found


def scored(name: str, lp: Path, kwargs: dict, cache: Path, rerun: bool) -> dict:
    """The cached or fresh ``heldout_photos`` report of one capture (images left out)."""
    path = cache / "results" / (name.replace("/", "__") + ".json")
    if path.is_file() and not rerun:
        return json.loads(path.read_text())
    if name.startswith("render/"):
        render(lp.parents[1], name.split("/", 1)[1])
    start = time.perf_counter()
    report = heldout_photos(lp, **kwargs)
    report["seconds"] = time.perf_counter() - start
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1))
    return report


def table(results: dict[str, dict]) -> str:
    """A Markdown table of mean held-out PSNR (dB) per capture and method."""
    methods = ["default", *CLASSIC]
    lines = ["| capture | " + " | ".join(methods) + " | default - best classic |",
             "| --- |" + " ---: |" * (len(methods) + 1)]
    for name, report in results.items():
        psnr = {m: report["methods"][m]["mean_psnr"] for m in methods}
        best = max(CLASSIC, key=psnr.get)
        cells = [f"**{psnr[m]:.2f}**" if m == best else f"{psnr[m]:.2f}" for m in methods]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {psnr['default'] - psnr[best]:+.2f} |")
    return "\n".join(lines)


def summary(results: dict[str, dict]) -> dict:
    """Mean, worst and count below -0.2 dB of the default minus the best classic fit."""
    gaps = np.array([r["default_minus_best_classic_db"] for r in results.values()])
    return {"captures": len(gaps), "mean_db": float(gaps.mean()), "worst_db": float(gaps.min()),
            "below_0.2_db": int((gaps < -0.2).sum())}


def figure(found: dict[str, tuple[Path, dict]], path: Path) -> None:
    """Rows of hidden photograph | default | best classic fit for the captures of
    :data:`FIGURE` found, labelled, as one PNG."""
    rows = []
    for name in (n for n in FIGURE if n in found):
        lp, kwargs = found[name]
        report = heldout_photos(lp, keep=0, **kwargs)
        psnr = {m: report["methods"][m]["mean_psnr"] for m in report["methods"]}
        best, images = report["best_classic"], report["images"]
        height = 240
        tiles = [cv2.resize(t, (round(t.shape[1] * height / t.shape[0]), height),
                            interpolation=cv2.INTER_NEAREST)
                 for t in (images["photograph"], images["default"], images[best])]
        labels = ["hidden photograph", f"default (mean {psnr['default']:.1f} dB)",
                  f"{best} (mean {psnr[best]:.1f} dB)"]
        for tile, label in zip(tiles, labels, strict=True):
            cv2.putText(tile, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1,
                        cv2.LINE_AA)
        strip = np.concatenate(tiles, axis=1)
        cv2.putText(strip, name, (4, height - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (255, 255, 0), 1, cv2.LINE_AA)
        rows.append(strip)
    if not rows:
        raise SystemExit(f"none of the figure's captures {FIGURE} found")
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0))) for r in rows]
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(rows)[..., ::-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="captures to score (default: every one)")
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--cache", default=Path(tempfile.gettempdir()) / "ltm-heldout-table",
                        type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--rerun", action="store_true", help="score cached captures again")
    parser.add_argument("--no-write", action="store_true", help="score only, write no table")
    parser.add_argument("--figure", action="store_true",
                        help=f"also draw {FIGURE_NAME} from {', '.join(FIGURE)}")
    args = parser.parse_args()
    found = captures(args.data, args.cache)
    unknown = sorted(set(args.names) - set(found))
    if unknown:
        raise SystemExit(f"unknown captures {unknown}; expected some of {sorted(found)}")
    results = {}
    for name in args.names or found:
        lp, kwargs = found[name]
        report = scored(name, lp, kwargs, args.cache, args.rerun)
        results[name] = report
        row = {m: report["methods"][m]["mean_psnr"] for m in report["methods"]}
        print(f"{name:>34s} " + " ".join(f"{m} {v:6.2f}" for m, v in row.items())
              + f"  default - best {report['default_minus_best_classic_db']:+.2f} dB"
              f"  ({report['methods']['default']['model']})", flush=True)
    if args.figure:
        figure(found, args.out / FIGURE_NAME)
    if args.no_write:
        return
    cached = {name: json.loads(path.read_text()) for name in found
              if (path := args.cache / "results" / (name.replace("/", "__") + ".json")).is_file()}
    command = "python bench/heldout_table.py"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "heldout_table.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "ltmstore": __version__, "command": command, "summary": summary(cached),
        "results": cached}, indent=1))
    stats = summary(cached)
    (args.out / "heldout_table.md").write_text(
        f"Held-out PSNR (dB, 8-bit sRGB, mean over the held-out lights), `{command}`; the best "
        "classic fit in bold.\n\n" + table(cached) + "\n\n"
        f"Over {stats['captures']} captures the default is {stats['mean_db']:+.2f} dB above the "
        f"best classic fit on average, {stats['worst_db']:+.2f} dB at worst, and more than 0.2 dB "
        f"below it on {stats['below_0.2_db']}.\n")
    print(table(cached))
    print(stats)


if __name__ == "__main__":
    main()
