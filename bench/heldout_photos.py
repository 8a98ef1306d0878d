"""Held-out photographs on every real capture and SynthRTI scene; timings of the whole commands.

Run: ``python bench/heldout_photos.py [--data ../shared/data] [--out bench/results] [--quick]``.

* Accuracy (:func:`ltmstore.judge.photos.heldout_photos`): for each capture with a ``dirs.lp``
  hide every 6th light; for each SynthRTI scene fit on ``dome/`` and score on ``test/``. PSNR and
  SSIM of 8-bit sRGB images, default pipeline beside PTM, HSH2, HSH3 and RBF.
* Speed: ``ltm ingest-rti`` and ``ltm reconstruct`` as whole commands (``subprocess``), and the
  fit alone (leave-one-out model choice, from the ``reconstruct`` record), median of 3, on the
  real captures and on the coin upscaled to 0.22 MP with 47 lights (the peer's benchmark size;
  written to a temporary folder, never into the repository).
* The lattice's cost: held-out PSNR of the luminance relit from the fit directly against relit
  bilinearly from the stored ``ltm`` lattice.
* A figure: hidden photograph | default relit | best classic relit, for three captures.

Writes ``heldout_photos.json`` and ``heldout_photos.png`` to ``--out`` and prints the table. The
captures are third-party data: they are read in place and never copied.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from ltmstore import __version__
from ltmstore.core.dims import LUMA
from ltmstore.core.store import open_store
from ltmstore.core.transfer import encode, srgb_to_linear
from ltmstore.judge.photos import CLASSIC, heldout_photos, load_photos
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.stages.relight import relight

REAL = ("realrti-item3-icon", "realrti-item9-coin", "loewenkopf")
FIGURE = ("realrti-item9-coin", "loewenkopf", "synthrti/multi-obj2-material1")


def captures(data: Path, quick: bool) -> dict[str, dict]:
    """Name -> ``heldout_photos`` arguments, for every capture found under ``data``."""
    found = {name: {"lp": data / name / "dirs.lp", "every": 6} for name in REAL
             if (data / name / "dirs.lp").is_file()}
    scenes = sorted((data / "synthrti").glob("*/dome/dirs.lp"))
    for lp in scenes[:2] if quick else scenes:
        found[f"synthrti/{lp.parents[1].name}"] = {"lp": lp,
                                                   "test_lp": lp.parents[1] / "test" / "dirs.lp"}
    return found


def timed(command: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    return time.perf_counter() - start


def speed(lp: Path, tmp: Path, repeats: int) -> dict:
    """Median wall time of ``ltm ingest-rti`` and ``ltm reconstruct`` (whole commands, Python
    start-up included), of the same two library calls in this process, and of the fit alone."""
    rows = []
    for _ in range(repeats):
        store = tmp / "speed.zarr"
        ingest = timed(["ltm", "ingest-rti", str(lp), str(store), "--overwrite"])
        whole = timed(["ltm", "reconstruct", str(store)])
        timings = open_store(store).attrs["stages"]["reconstruct"]["timings"]
        start = time.perf_counter()
        ingest_rti(lp, store, overwrite=True, progress=False)
        reconstruct(store, progress=False)
        rows.append((ingest, whole, time.perf_counter() - start,
                     timings["prepare_s"] + timings["fit_s"]))
    ingest, whole, calls, fit = (statistics.median(c) for c in zip(*rows, strict=True))
    return {"ingest_rti_s": ingest, "reconstruct_s": whole, "both_s": ingest + whole,
            "library_calls_s": calls, "fit_s": fit, "repeats": repeats}


def upscaled_coin(data: Path, tmp: Path, pixels: float = 0.22e6, lights: int = 47) -> Path:
    """The coin's first ``lights`` photographs resized to about ``pixels`` pixels, in ``tmp``."""
    directions, photos = load_photos(data / "realrti-item9-coin" / "dirs.lp")
    scale = np.sqrt(pixels / np.prod(photos.shape[1:3]))
    folder = tmp / "coin-0.22MP"
    folder.mkdir()
    lines = [str(lights)]
    for i in range(lights):
        big = cv2.resize(photos[i], None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(folder / f"im{i:02d}.png"), big[..., ::-1])
        lines.append(f"im{i:02d}.png {' '.join(f'{v:.6f}' for v in directions[i])}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"


def lattice_cost(lp: Path, tmp: Path, shape: tuple[int, int], every: int = 6) -> dict:
    """Held-out luminance PSNR relit from the fit directly and bilinearly from a ``shape``
    lattice (held at the outer cell centres beyond them)."""
    directions, photos = load_photos(lp)
    hidden = np.arange(len(directions)) % every == every - 1
    store = tmp / "lattice.zarr"
    ingest_rti(lp, store, lights=np.flatnonzero(~hidden).tolist(), progress=False,
               overwrite=True)
    reconstruct(store, progress=False, lattice=shape)
    ds = open_store(store)
    truth = encode(srgb_to_linear(photos[hidden] / 255) @ LUMA, "srgb")
    direct = encode(relight(ds, directions=directions[hidden], color=False).values, "srgb")
    r, s = ds["r"].values, ds["s"].values  # bilinear inside the outer cell centres
    lattice = np.stack([encode(ds["ltm"].interp(r=np.clip(d[0], r[0], r[-1]),
                                                s=np.clip(d[1], s[0], s[-1])).values, "srgb")
                        for d in directions[hidden]])

    def psnr(pred):
        err = (pred.astype(float) - truth) ** 2
        return float(np.mean(10 * np.log10(255**2 / err.mean(axis=(1, 2)))))
    return {"capture": lp.parent.name, "lattice": list(ds["ltm"].shape[2:]),
            "from_fit_db": psnr(direct), "from_lattice_db": psnr(lattice),
            "cost_db": psnr(direct) - psnr(lattice)}


def figure(images: dict[str, dict], path: Path) -> None:
    """Rows of hidden photograph | default | best classic, labelled, as one PNG."""
    rows = []
    for name, row in images.items():
        tiles = [row["photograph"], row["default"], row[row["best"]]]
        height = 240
        tiles = [cv2.resize(t, (round(t.shape[1] * height / t.shape[0]), height),
                            interpolation=cv2.INTER_NEAREST) for t in tiles]
        labels = ["hidden photograph", f"default (mean {row['psnr']['default']:.1f} dB)",
                  f"{row['best']} (mean {row['psnr'][row['best']]:.1f} dB)"]
        for tile, label in zip(tiles, labels, strict=True):
            cv2.putText(tile, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1,
                        cv2.LINE_AA)
        strip = np.concatenate(tiles, axis=1)
        cv2.putText(strip, name, (4, height - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (255, 255, 0), 1, cv2.LINE_AA)
        rows.append(strip)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0))) for r in rows]
    cv2.imwrite(str(path), np.concatenate(rows)[..., ::-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--repeats", default=3, type=int)
    parser.add_argument("--quick", action="store_true", help="two SynthRTI scenes, one repeat")
    args = parser.parse_args()
    found = captures(args.data, args.quick)
    if not found:
        raise SystemExit(f"no captures under {args.data}")
    results, images = {}, {}
    for name, kwargs in found.items():
        report = heldout_photos(kwargs.pop("lp"), keep=0, **kwargs)
        kept = report.pop("images")
        results[name] = report
        row = {m: report["methods"][m]["mean_psnr"] for m in report["methods"]}
        print(f"{name:>34s} " + " ".join(f"{m} {v:6.2f}" for m, v in row.items())
              + f"  default - best {report['default_minus_best_classic_db']:+.2f} dB", flush=True)
        if name in FIGURE:
            images[name] = {**kept, "best": report["best_classic"], "psnr": row}
    repeats = 1 if args.quick else args.repeats
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        timing = {name: speed(args.data / name / "dirs.lp", tmp, repeats) for name in REAL
                  if name in found}
        if "realrti-item9-coin" in found:
            timing["coin-0.22MP-47"] = speed(upscaled_coin(args.data, tmp), tmp, repeats)
            cost = [lattice_cost(args.data / "realrti-item9-coin" / "dirs.lp", tmp, (n, n))
                    for n in (8, 16, 32)]
    args.out.mkdir(parents=True, exist_ok=True)
    figure(images, args.out / "heldout_photos.png")
    (args.out / "heldout_photos.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "ltmstore": __version__, "command": "python bench/heldout_photos.py"
        + " --quick" * args.quick, "results": results, "timings": timing,
        "lattice_cost": cost}, indent=1))
    print(table(results))
    for name, t in timing.items():
        print(f"{name}: ingest-rti {t['ingest_rti_s']:.2f} s + reconstruct "
              f"{t['reconstruct_s']:.2f} s = {t['both_s']:.2f} s (library calls "
              f"{t['library_calls_s']:.2f} s); fit {t['fit_s']:.2f} s")
    for c in cost:
        print(f"lattice cost ({c['capture']}, {c['lattice']}): {c['cost_db']:.3f} dB "
              f"({c['from_fit_db']:.2f} from the fit, {c['from_lattice_db']:.2f} from the lattice)")


def table(results: dict) -> str:
    """A Markdown table of mean held-out PSNR (dB) / SSIM per capture and method."""
    methods = ["default", *CLASSIC]
    lines = ["| capture | " + " | ".join(methods) + " | default - best |",
             "| --- |" + " --- |" * (len(methods) + 1)]
    for name, report in results.items():
        rows = [report["methods"][m] for m in methods]
        cells = [f"{r['mean_psnr']:.2f} / {r['mean_ssim']:.3f}" for r in rows]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {report['default_minus_best_classic_db']:+.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
