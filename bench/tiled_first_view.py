"""First view of a big web export in OpenLIME: bytes fetched and time to first image, the planes
whole (``ltm export --format relight``) against tiled (``--layout deepzoom``).

Each export is opened by OpenLIME's own sources (``$LTM_OPENLIME_SRC``, as
``tests/share/test_openlime.py`` runs them) in a fresh headless Chromium (no cache) with a page of
``--viewport`` CSS pixels: OpenLIME fits the image to the page. A loopback server counts the
requests and bytes of the export it serves. Measured per run:

* ``first_image_ms``: from navigation start until OpenLIME's canvas first shows a pixel that is
  not the background (sampled every 20 ms in the page, ``performance.now()``);
* ``view_ms``: until the layer has no tile queued or requested (the view complete);
* ``requests`` and ``bytes`` of the export fetched by then (OpenLIME's code excluded);
* on loopback, and with ``--mbps M``, also through Chromium's network throttled to M Mbit/s
  (20 ms latency; runs keyed ``image@M``, ``deepzoom@M``);
* then the camera goes to 1:1 at the image centre (``camera.setPosition(0, 0, 0, 1, 0)``) and the
  further requests, bytes and time until the view is complete again are recorded (``zoom_*``).

Usage (exports of the same store, ``ltm export S IMG --format relight`` and ``ltm export S DZ
--format relight --layout deepzoom``)::

    python bench/tiled_first_view.py --image IMG --deepzoom DZ [--repeats 3]

writes ``bench/results/tiled_first_view.json``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import tempfile
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import OPENLIME_SRC, Browser, openlime_import_map  # noqa: E402

PAGE = """<!doctype html><html><head><style>
html, body {{ margin: 0; background: #000 }}
#lime {{ width: 100vw; height: 100vh; position: relative; overflow: hidden }}
</style><script type="importmap">{imports}</script>
</head><body><div id="lime"></div><script type="module">
import {{ Viewer }} from '/openlime/Viewer.js';
import {{ Layer }} from '/openlime/Layer.js';
import '/openlime/LayerRTI.js';
import '/openlime/LayoutTiles.js';
const viewer = new Viewer('#lime', {{ background: 'black',
                                      canvas: {{ preserveDrawingBuffer: true }} }});
const layer = new Layer({{ type: 'rti', layout: '{layout}', url: '/{folder}/info.json' }});
viewer.addLayer('rti', layer);
layer.setLight([0.3, 0.4], 0);
const probe = document.createElement('canvas');
probe.width = probe.height = 32;
const ctx = probe.getContext('2d', {{ willReadFrequently: true }});
function shown() {{
  viewer.draw(performance.now());
  ctx.drawImage(viewer.canvasElement, 0, 0, 32, 32);
  const px = ctx.getImageData(0, 0, 32, 32).data;
  for (let i = 0; i < px.length; i += 4) if (px[i] + px[i + 1] + px[i + 2] > 0) return true;
  return false;
}}
function idle() {{ return layer.queue.length === 0 && layer.requested.size === 0; }}
window.watch = () => {{
  window.done = null;
  const timer = setInterval(() => {{
    viewer.draw(performance.now());  // OpenLIME queues and requests the view's tiles here
    if (window.first == null && shown()) window.first = performance.now();
    if (window.first != null && idle()) {{ viewer.draw(performance.now());
                                          window.done = performance.now(); clearInterval(timer); }}
  }}, 20);
}};
window.watch();
Object.assign(window, {{ viewer, layer }});
</script></body></html>"""


class Counter(SimpleHTTPRequestHandler):
    """Static files; counts the requests and bytes of the exports it serves."""

    counts: dict = {"requests": 0, "bytes": 0}
    lock = threading.Lock()

    def translate_path(self, path: str) -> str:
        found = super().translate_path(path)
        if not os.path.exists(found) and os.path.exists(found + ".js"):
            return found + ".js"
        return found

    def copyfile(self, source, outputfile) -> None:
        if not self.path.startswith(("/openlime/", "/page-")):
            size = os.fstat(source.fileno()).st_size
            with self.lock:
                self.counts["requests"] += 1
                self.counts["bytes"] += size
        super().copyfile(source, outputfile)

    def log_message(self, *args) -> None:
        pass


def snapshot() -> dict:
    return dict(Counter.counts)


def one_run(url: str, viewport: tuple[int, int], mbps: float | None) -> dict:
    """Open ``url`` in a fresh browser (its network throttled to ``mbps`` megabits a second and
    20 ms of latency, if given): first view, then 1:1 at the centre."""
    Counter.counts.update(requests=0, bytes=0)
    with Browser(*viewport, timeout=60) as browser:
        if mbps:
            browser.call("Network.enable")
            browser.call("Network.emulateNetworkConditions", offline=False, latency=20,
                         downloadThroughput=mbps * 1e6 / 8, uploadThroughput=mbps * 1e6 / 8)
        browser.goto(url)
        browser.wait_for("window.done != null", timeout=300)
        first = browser.evaluate("({first: window.first, done: window.done})")
        view = snapshot()
        browser.evaluate("window.t0 = performance.now(); viewer.camera.setPosition(0, 0, 0, 1, 0);"
                         " window.first = 0; window.watch(); 1")
        browser.wait_for("window.done != null", timeout=300)
        zoom_ms = browser.evaluate("window.done - window.t0")
    total = snapshot()
    return {"first_image_ms": round(first["first"], 1), "view_ms": round(first["done"], 1),
            "requests": view["requests"], "bytes": view["bytes"], "zoom_ms": round(zoom_ms, 1),
            "zoom_requests": total["requests"] - view["requests"],
            "zoom_bytes": total["bytes"] - view["bytes"]}


def whole_from_deepzoom(dz: Path, out: Path) -> Path:
    """The ``image`` layout of a deepzoom export, its full levels put back together and written
    as whole plane JPEGs at the export's quality (a stand-in for ``ltm export`` without
    ``--layout``, where that export would take too long to run again)."""
    import numpy as np
    from PIL import Image

    from ltmstore.share.tiles import level_count, tile_span

    info = json.loads((dz / "info.json").read_text())
    out.mkdir()
    (out / "info.json").write_text((dz / "info.json").read_text())
    w, h, side = info["width"], info["height"], 256
    for dzi in sorted(dz.glob("plane_*.dzi")):
        text = dzi.read_text()
        side = int(text.split('TileSize="')[1].split('"')[0])
        over = int(text.split('Overlap="')[1].split('"')[0])
        top = dz / f"{dzi.stem}_files" / str(level_count(w, h, side) - 1)
        image = np.zeros((h, w, 3), np.uint8)
        for y in range(-(-h // side)):
            rows = tile_span(y, h, side, over)
            for x in range(-(-w // side)):
                cols = tile_span(x, w, side, over)
                with Image.open(top / f"{x}_{y}.jpg") as tile:
                    image[rows, cols] = np.asarray(tile.convert("RGB"))
        Image.fromarray(image).save(out / f"{dzi.stem}.jpg", quality=info["quality"],
                                    subsampling=0)
    return out


def folder_size(folder: Path) -> tuple[int, int]:
    files = [p for p in folder.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", type=Path,
                        help="export, layout image (default: the deepzoom export's full "
                        "levels as whole planes)")
    parser.add_argument("--deepzoom", type=Path, required=True, help="export, layout deepzoom")
    parser.add_argument("--viewport", default="1000x700")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--mbps", type=float, action="append",
                        help="also throttled to this many megabits a second (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("bench/results/tiled_first_view.json"))
    a = parser.parse_args()
    viewport = tuple(int(v) for v in a.viewport.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if a.image is None:
            a.image = whole_from_deepzoom(a.deepzoom, root / "whole")
        info = json.loads((a.image / "info.json").read_text())
        (root / "openlime").symlink_to(OPENLIME_SRC.resolve(), target_is_directory=True)
        for name, folder, layout in (("image", a.image, "image"),
                                     ("deepzoom", a.deepzoom, "deepzoom")):
            (root / name).symlink_to(folder.resolve(), target_is_directory=True)
            (root / f"page-{name}.html").write_text(PAGE.format(
                layout=layout, folder=name, imports=openlime_import_map()))
        server = ThreadingHTTPServer(("127.0.0.1", 0),
                                     functools.partial(Counter, directory=str(root)))
        threading.Thread(target=server.serve_forever, daemon=True).start()
        base = f"http://127.0.0.1:{server.server_address[1]}"
        runs = {f"{name}@{mbps or 'loopback'}": [] for mbps in [None, *(a.mbps or [])]
                for name in ("image", "deepzoom")}
        for _ in range(a.repeats):
            for key in runs:
                name, mbps = key.split("@")
                runs[key].append(one_run(f"{base}/page-{name}.html", viewport,
                                         None if mbps == "loopback" else float(mbps)))
                print(key, runs[key][-1], flush=True)
        server.shutdown()
        exports = {name: dict(zip(("files", "bytes"), folder_size(folder), strict=True))
                   for name, folder in (("image", a.image), ("deepzoom", a.deepzoom))}
    result = {"image_px": [info["width"], info["height"]], "viewport": list(viewport),
              "basis": info["type"], "nplanes": info["nplanes"],
              "date": time.strftime("%Y-%m-%d"),
              "load": os.getloadavg()[0], "runs": runs, "exports": exports,
              "image_layout": "exported" if a.image.parent != root else "from the deepzoom tiles"}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
