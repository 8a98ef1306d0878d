"""Export fidelity: each ``ltm export`` format, read back by the independent readers of
``tests/rti_readers.py`` (written from the formats' specifications and OpenLIME's shader), relit at
the held-out lights of real captures and scored against the held-out photographs, beside
``ltm relight`` at the same lights.

Usage (stores made by ``ltm ingest-rti DIRS.lp S.zarr --holdout-lights 6`` + ``ltm reconstruct``)::

    OMP_NUM_THREADS=1 nice -n 15 python bench/export_fidelity.py coin=/tmp/coin.zarr ... \
        [--only=web-bilinear,ptm] [--relight-cli=PATH]

With ``--relight-cli`` (Relight's ``relight-cli``, built as in ``docs/development.md``) each web
export is also drawn by Relight's own renderer at the held-out lights (``relight-cli -L x:y:z -D
image.png web``) and scored the same way. Writes (merges ``--only`` runs into)
``bench/results/export_fidelity.json``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from rti_readers import psnr, read_ptm, read_rti, read_web, relit  # noqa: E402

import ltmstore  # noqa: E402
from ltmstore.core.transfer import encode_images  # noqa: E402
from ltmstore.share.export import export  # noqa: E402

CASES = {  # name: (export arguments, output name, reader)
    "ptm": ({"fmt": "ptm"}, "out.ptm", read_ptm),
    "hsh-3": ({"fmt": "hsh", "order": 3}, "out.rti", read_rti),
    "web-hsh": ({"fmt": "relight", "basis": "hsh"}, "web", read_web),
    "web-bilinear": ({"fmt": "relight", "basis": "bilinear"}, "web", read_web),  # quality auto
    "web-bilinear-q95": ({"fmt": "relight", "basis": "bilinear", "quality": 95}, "web",
                         read_web),
    "web-bilinear-q100": ({"fmt": "relight", "basis": "bilinear", "quality": 100}, "web",
                          read_web),
}


def held_out(store: str) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``(n, 3)`` and 8-bit photographs ``(n, y, x, 3)`` of the held-out lights."""
    ds = ltmstore.open_store(store)
    record = ds.attrs["stages"]["ingest"]["held_out"]
    folder = Path(ds.attrs["acquisition"]["lp_path"]).parent
    photos = np.stack([np.asarray(Image.open(folder / r["image"]).convert("RGB"), float)
                       for r in record])
    return np.array([r["direction"] for r in record], float), photos


def store_images(store: str, dirs: np.ndarray) -> np.ndarray:
    """``ltm relight``'s 8-bit images at ``dirs``, as its PNGs hold them."""
    ds = ltmstore.open_store(store)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return encode_images(ltmstore.relight(ds, directions=dirs).values,
                             ds.attrs["acquisition"].get("transfer", "srgb"))


def size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*")) if path.is_dir() else path.stat().st_size


def drawn_by_relight(relight_cli: str, web: Path, dirs: np.ndarray) -> np.ndarray:
    """The web export ``web`` drawn by ``relight-cli -L x:y:z -D`` at ``dirs``: 8-bit RGB."""
    images = []
    for d in dirs:
        out = web.parent / "drawn.png"
        subprocess.run([relight_cli, "-L", ":".join(f"{v:.6f}" for v in d), "-D", str(out),
                        str(web)], check=True, capture_output=True)
        images.append(np.asarray(Image.open(out).convert("RGB"), float))
    return np.stack(images)


def measure(store: str, only: list[str], relight_cli: str | None = None) -> dict:
    dirs, photos = held_out(store)
    store_png = store_images(store, dirs)
    out = {"held_out_lights": len(dirs), "ltm_relight_db": round(psnr(store_png, photos), 2),
           "formats": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name in only:
            kwargs, file, reader = CASES[name]
            t0 = time.perf_counter()
            (Path(tmp) / name).mkdir()
            report = export(store, Path(tmp) / name / file, **kwargs)
            seconds = time.perf_counter() - t0
            coef, basis = reader(Path(tmp) / name / file)
            images = relit(coef, basis(dirs))
            printed = report.get("fidelity", {})
            out["formats"][name] = {
                "printed": printed.get("text"),
                "db_vs_photos": round(psnr(images, photos), 2),
                "db_vs_ltm_relight": round(psnr(images, store_png.astype(float)), 2),
                "bytes": size(Path(tmp) / name / file), "seconds": round(seconds, 1),
                **{k: report[k] for k in ("terms", "directions", "quality") if k in report}}
            if relight_cli and reader is read_web:
                drawn = drawn_by_relight(relight_cli, Path(tmp) / name / file, dirs)
                out["formats"][name]["relight_cli_db_vs_photos"] = round(psnr(drawn, photos), 2)
            print(name, out["formats"][name], flush=True)
    return out


def main(argv: list[str]) -> None:
    only = [a.split("=", 1)[1].split(",") for a in argv if a.startswith("--only=")]
    names = only[0] if only else list(CASES)
    relight_cli = next((a.split("=", 1)[1] for a in argv if a.startswith("--relight-cli=")),
                       None)
    target = HERE / "results" / "export_fidelity.json"
    results = json.loads(target.read_text()) if target.is_file() else {}  # --only: merged
    for arg in (a for a in argv if not a.startswith("--")):
        label, store = arg.split("=", 1)
        measured = measure(store, names, relight_cli)
        formats = {**results.get(label, {}).get("formats", {}), **measured.pop("formats")}
        results[label] = {**measured, "formats": formats}
        print(label, results[label]["ltm_relight_db"], flush=True)
    target.parent.mkdir(exist_ok=True)
    target.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
