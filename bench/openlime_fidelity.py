"""The web export drawn by OpenLIME itself at the held-out lights of real captures: its canvas
(headless Chromium, WebGL, ``LayerRTI.setLight``) against the held-out photographs, beside the
format's own math (``tests/rti_readers.py``) and ``ltm relight``; drawn by OpenLIME's default
page and by a page that keeps the colour in full precision (``tests/browser.py``,
``openlime_page(..., full_precision=True)``: no 8-bit linear framebuffer).

Usage (stores made by ``ltm ingest-rti DIRS.lp S.zarr --holdout-lights 6`` + ``ltm
reconstruct``; OpenLIME's sources as for ``tests/share/test_openlime.py``)::

    python bench/openlime_fidelity.py coin=/tmp/coin.zarr icon=/tmp/icon.zarr [--quality 95]

Writes ``bench/results/openlime_fidelity.json`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from browser import OPENLIME_SRC, Browser, draw_openlime, openlime_page, serve  # noqa: E402
from export_fidelity import held_out, store_images  # noqa: E402
from rti_readers import psnr, read_web, relit  # noqa: E402

from ltmstore.share.export import export  # noqa: E402


def drawn(folder: Path, report: dict, dirs: np.ndarray) -> dict[bool, np.ndarray]:
    """OpenLIME's canvas ``(n, y, x, 3)`` at ``dirs`` by its default page (``False``) and the
    full-precision one (``True``), the export served from ``folder``."""
    (folder / "openlime").symlink_to(OPENLIME_SRC.resolve(), target_is_directory=True)
    size = (report["width"], report["height"])
    for full in (False, True):
        (folder / f"page-{full}.html").write_text(openlime_page(
            *size, "rti", "image", "/web/info.json", full_precision=full))
    with serve(folder) as url, Browser(64, 64) as browser:
        return {full: draw_openlime(browser, f"{url}/page-{full}.html", size, dirs)
                for full in (False, True)}


def measure(store: str, quality: int | None) -> dict:
    dirs, photos = held_out(store)
    store_png = store_images(store, dirs)
    with tempfile.TemporaryDirectory() as tmp:
        report = export(store, Path(tmp) / "web", fmt="relight", quality=quality)
        coef, basis = read_web(Path(tmp) / "web")
        reader = relit(coef, basis(dirs))
        openlime, full = drawn(Path(tmp), report, dirs).values()
    return {"held_out_lights": len(dirs), "quality": report["quality"],
            "ltm_relight_db": round(psnr(store_png, photos), 2),
            "reader_db": round(psnr(reader, photos), 2),
            "openlime_db": round(psnr(openlime, photos), 2),
            "openlime_vs_reader_db": round(psnr(openlime, reader), 2),
            "openlime_full_precision_db": round(psnr(full, photos), 2),
            "openlime_full_precision_vs_reader_db": round(psnr(full, reader), 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stores", nargs="+", help="NAME=STORE")
    parser.add_argument("--quality", type=int, help="the planes' JPEG quality (default: auto)")
    parser.add_argument("--out", type=Path, default=HERE / "results")
    args = parser.parse_args()
    results = {"command": " ".join(sys.argv), "openlime": "src of commit 5b4e27b"}
    for item in args.stores:
        name, store = item.split("=", 1)
        results[name] = measure(store, args.quality)
        print(name, results[name], flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "openlime_fidelity.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
