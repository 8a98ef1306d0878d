"""Held-out photographs on every real capture and SynthRTI scene.

Run: ``python bench/heldout_photos.py [--data ../shared/data] [--out bench/results] [--quick]``.

* Accuracy (:func:`ltmstore.judge.photos.heldout_photos`): for each capture with a ``dirs.lp``
  hide every 6th light; for each SynthRTI scene fit on ``dome/`` and score on ``test/``. PSNR and
  SSIM of 8-bit sRGB images, default pipeline beside PTM, HSH2, HSH3, RBF and HSH3 + RBF
  residual.
* The lattice's cost: held-out PSNR of the luminance relit from the fit directly against relit
  bilinearly from the stored ``ltm`` lattice.
* A figure: hidden photograph | default relit | best classic relit, for three captures.

Writes ``heldout_photos.json`` and ``heldout_photos.png`` to ``--out`` and prints the table. The
captures are third-party data: they are read in place and never copied. The speed of the same
captures is ``bench/rti_speed.py``'s.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
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
    parser.add_argument("--quick", action="store_true", help="two SynthRTI scenes")
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
    cost = []
    with tempfile.TemporaryDirectory() as tmp:
        if "realrti-item9-coin" in found:
            cost = [lattice_cost(args.data / "realrti-item9-coin" / "dirs.lp", Path(tmp), (n, n))
                    for n in (8, 16, 32)]
    args.out.mkdir(parents=True, exist_ok=True)
    figure(images, args.out / "heldout_photos.png")
    (args.out / "heldout_photos.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "ltmstore": __version__, "command": "python bench/heldout_photos.py"
        + " --quick" * args.quick, "results": results,
        "lattice_cost": cost}, indent=1))
    print(table(results))
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
