"""Headless Chromium driven over the DevTools protocol (a WebSocket): enough to load a page,
move the mouse, evaluate JavaScript and take screenshots. Debian's ``chromium`` package; no
browser download, no driver besides ``websockets``."""

from __future__ import annotations

import base64
import contextlib
import functools
import io
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
from PIL import Image

CHROMIUM = ("chromium", "/usr/bin/chromium", "chromium-browser")
# Set (to anything but "" or "0") where a missing browser must fail the run: .ci/run sets it.
REQUIRE = "LTM_REQUIRE_BROWSER"
MISSING = ("chromium is missing: the browser tests need Debian's chromium package "
           "(`sudo apt-get install chromium`; .ci/run installs it)")


# OpenLIME's sources (not on npm): a checkout's src/ (commit 5b4e27b, version 1.2.6)
OPENLIME_SRC = Path(os.environ.get(
    "LTM_OPENLIME_SRC", Path.home() / ".cache" / "ltmstore-tests" / "openlime" / "src"))


# OpenSeadragon's published build, from the npm registry (BSD-3-Clause)
OPENSEADRAGON = "openseadragon@5.0.1"
OPENSEADRAGON_JS = Path(os.environ.get(
    "LTM_OPENSEADRAGON_JS", Path.home() / ".cache" / "ltmstore-tests" / OPENSEADRAGON
    / "openseadragon.min.js"))


def openseadragon_js() -> Path:
    """OpenSeadragon's ``openseadragon.min.js``, fetched once with ``npm pack`` where it is
    missing; a skip with the reason where npm cannot fetch it."""
    import pytest

    if OPENSEADRAGON_JS.is_file():
        return OPENSEADRAGON_JS
    npm = shutil.which("npm")
    if npm is None:
        pytest.skip(f"OpenSeadragon absent at {OPENSEADRAGON_JS} and npm is missing")
    with tempfile.TemporaryDirectory() as folder:
        proc = subprocess.run([npm, "pack", OPENSEADRAGON, "--silent"], cwd=folder, text=True,
                              capture_output=True, timeout=120)
        if proc.returncode != 0:
            pytest.skip(f"npm pack {OPENSEADRAGON} failed: {proc.stderr.strip()[-200:]}")
        import tarfile

        with tarfile.open(Path(folder) / proc.stdout.strip().splitlines()[-1]) as tar:
            body = tar.extractfile("package/build/openseadragon/openseadragon.min.js").read()
        OPENSEADRAGON_JS.parent.mkdir(parents=True, exist_ok=True)
        part = OPENSEADRAGON_JS.with_suffix(f".{os.getpid()}.part")
        part.write_bytes(body)
        part.replace(OPENSEADRAGON_JS)  # whole or not at all, under parallel workers
    return OPENSEADRAGON_JS


OPENSEADRAGON_PAGE = """<!doctype html><html><head><style>
html, body {{ margin: 0; background: #000 }}
#osd {{ width: {w}px; height: {h}px }}
</style><script src="/openseadragon.min.js"></script></head><body><div id="osd"></div>
<script>
const viewer = OpenSeadragon({{ id: 'osd', tileSources: '{url}', drawer: 'canvas',
  showNavigationControl: false, animationTime: 0, immediateRender: true,
  imageSmoothingEnabled: false, crossOriginPolicy: 'Anonymous' }});
viewer.world.addHandler('add-item', (e) => e.item.addHandler('fully-loaded-change', (f) => {{
  if (f.fullyLoaded) window.ready = true; }}));
window.viewer = viewer;
</script></body></html>"""


def openseadragon_page(width: int, height: int, url: str) -> str:
    """A page that opens the Deep Zoom image at ``url`` in OpenSeadragon (its canvas drawer) in
    a ``width`` x ``height`` viewer, served beside ``/openseadragon.min.js``; ``window.ready``
    once every tile on the screen is drawn."""
    return OPENSEADRAGON_PAGE.format(w=width, h=height, url=url)


def openlime_import_map() -> str:
    """An import map for OpenLIME's sources served at ``/openlime/``. Its modules import each
    other with and without ``.js`` (``LayoutTiles.js``: ``from "./Layout"``, ``Layer.js``: ``from
    './Layout.js'``); without a bundler the browser would load two ``Layout`` modules, and
    ``LayoutTiles`` would register its types on the one ``Layer`` does not use. The map makes the
    two names one module."""
    names = sorted(p.stem for p in OPENLIME_SRC.glob("*.js"))
    return json.dumps({"imports": {f"/openlime/{n}": f"/openlime/{n}.js" for n in names}})


OPENLIME_PAGE = """<!doctype html><html><head><style>
html, body {{ margin: 0; background: #000 }}
#lime {{ width: {w}px; height: {h}px; position: relative; overflow: hidden }}
#lime canvas {{ position: absolute; left: 0; top: 0; width: 100%; height: 100%; display: block }}
</style><script type="importmap">{imports}</script></head><body><div id="lime"></div>
<script type="module">
import {{ Viewer }} from '/openlime/Viewer.js';
import {{ Layer }} from '/openlime/Layer.js';
import '/openlime/LayerImage.js';
import '/openlime/LayerRTI.js';
import '/openlime/LayoutTiles.js';
import {{ ShaderFilter }} from '/openlime/ShaderFilter.js';
// the layer's linear colour encoded back to sRGB by its own shader (see openlime_page)
class ShaderFilterEncode extends ShaderFilter {{
  fragDataSrc() {{ return `vec4 ${{this.functionName()}}(vec4 c) {{ return linear2srgb(c); }}`; }}
}}
const full = {full};
const viewer = new Viewer('#lime', {{ background: 'black', canvas: {{
  preserveDrawingBuffer: true, useOffscreenFramebuffer: !full }} }});
const layer = new Layer({{ type: '{kind}', layout: '{layout}', url: '{url}' }});
viewer.addLayer('{kind}', layer);
layer.addEvent('ready', () => {{
  if (full) layer.shader.addFilter(new ShaderFilterEncode());
  window.ready = true;
}});
Object.assign(window, {{ viewer, layer }});
</script></body></html>"""


def openlime_page(width: int, height: int, kind: str, layout: str, url: str, *,
                  full_precision: bool = False) -> str:
    """A page that draws one OpenLIME layer (``kind`` ``rti`` or ``image``, its ``layout`` and
    ``url``) in a ``width`` x ``height`` canvas, as OpenLIME's own viewer does; ``window.ready``
    once the layer is, ``window.viewer`` and ``window.layer`` for the test.

    ``full_precision``: OpenLIME's canvas without its offscreen framebuffer (``canvas:
    {useOffscreenFramebuffer: false}``), the layer's shader encoding its linear colour back to
    sRGB as its last step (a :class:`ShaderFilter` calling the shader's own ``linear2srgb``): the
    colour stays in the shader's floats until the canvas's 8-bit sRGB, where by default it
    passes through an 8-bit *linear* framebuffer that crushes the darkest levels."""
    return OPENLIME_PAGE.format(w=width, h=height, imports=openlime_import_map(), kind=kind,
                                layout=layout, url=url, full="true" if full_precision else "false")


class StaticHandler(SimpleHTTPRequestHandler):
    """Static files; OpenLIME's sources import some modules without their ``.js``."""

    def translate_path(self, path: str) -> str:
        found = super().translate_path(path)
        if not os.path.exists(found) and os.path.exists(found + ".js"):
            return found + ".js"
        return found

    def log_message(self, *args) -> None:
        pass


@contextlib.contextmanager
def serve(folder: Path) -> Iterator[str]:
    """A loopback-only server of ``folder`` (page, export, OpenLIME's sources); its URL."""
    server = ThreadingHTTPServer(("127.0.0.1", 0),
                                 functools.partial(StaticHandler, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


# a frame drawn now, as a PNG data URL: headless Chromium runs requestAnimationFrame (which
# OpenLIME's redraw waits on) about once a second here, so the tests draw synchronously
FRAME = "viewer.draw(performance.now()), viewer.canvasElement.toDataURL('image/png')"


def canvas(browser: Browser) -> np.ndarray:
    """The canvas (y, x, 3) once two frames in a row agree (its planes may still be loading)."""
    last = None
    for _ in range(50):
        data = browser.evaluate(FRAME)
        frame = np.asarray(Image.open(io.BytesIO(base64.b64decode(data.split(",", 1)[1])))
                           .convert("RGB"), float)
        if last is not None and np.array_equal(frame, last) and frame.any():  # drawn
            return frame
        last = frame
        time.sleep(0.02)
    raise AssertionError("OpenLIME's canvas did not settle in 50 frames")


def draw_openlime(browser: Browser, url: str, size: tuple[int, int],
                  dirs: np.ndarray) -> np.ndarray:
    """OpenLIME's canvas ``(n, y, x, 3)`` of the page at ``url`` (:func:`openlime_page`, its
    canvas ``size = (width, height)``) at each light of ``dirs`` (directions ``(x, y, z)``;
    OpenLIME's light is ``(x, y)`` with ``z = sqrt(1 - x^2 - y^2)``)."""
    browser.goto(url)
    browser.wait_for(f"window.ready === true && viewer.canvasElement.width === {size[0]} && "
                     f"viewer.canvasElement.height === {size[1]}")
    frames = []
    for x, y, _ in dirs:
        browser.evaluate(f"layer.setLight([{x}, {y}], 0), 1")
        frames.append(canvas(browser))
    return np.stack(frames)


def chromium_path() -> str:
    """The Chromium executable. When it is missing: a skip naming it and how to get it, or an
    AssertionError (a failure) where ``LTM_REQUIRE_BROWSER`` is set, as in CI."""
    import pytest

    found = next((p for p in map(shutil.which, CHROMIUM) if p), None)
    if found is None:
        assert os.environ.get(REQUIRE, "") in ("", "0"), f"{MISSING} ({REQUIRE} is set)"
        pytest.skip(MISSING)
    return found


class Browser:
    """One headless Chromium with one page of ``width`` x ``height`` CSS pixels; ``args``: extra
    command-line flags (a fake camera, say)."""

    def __init__(self, width: int = 1000, height: int = 700, timeout: float = 20,
                 args: tuple[str, ...] = ()) -> None:
        from websockets.sync.client import connect

        executable = chromium_path()  # skips (or fails in CI) before anything starts
        self.profile = Path(tempfile.mkdtemp(prefix="ltm-chromium-"))
        self.proc = subprocess.Popen(
            [executable, "--headless", "--no-sandbox", "--disable-gpu",
             "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
             f"--user-data-dir={self.profile}", f"--window-size={width},{height}",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions",
             "--hide-scrollbars", "--force-device-scale-factor=1", "--mute-audio",
             # a page runs at full speed whatever Chromium thinks of its window (Playwright's
             # and Puppeteer's switches): under load a page's camera start once took > 60 s
             "--disable-background-timer-throttling", "--disable-backgrounding-occluded-windows",
             "--disable-renderer-backgrounding",
             *args, "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port = self._devtools_port(timeout)
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=timeout) as r:
            page = next(t for t in json.load(r) if t["type"] == "page")
        # no keepalive pings: a local socket needs none, and under load Chromium once left one
        # unanswered for websockets' 20 s while its page finished a recording, which closed the
        # connection mid-test (5 errors of tests/capture/test_live_pages.py in a clean-clone run,
        # 2026-11-28); every call's own receive timeout is the guard
        self.ws = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=timeout,
                          ping_interval=None)
        self.ids = itertools.count(1)
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height,
                  deviceScaleFactor=1, mobile=False)

    def _devtools_port(self, timeout: float) -> int:
        marker = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if marker.exists() and marker.read_text().strip():
                return int(marker.read_text().split()[0])
            assert self.proc.poll() is None, f"chromium exited with {self.proc.returncode}"
            time.sleep(0.05)
        raise AssertionError("chromium did not open its DevTools port")

    def call(self, method: str, **params) -> dict:
        """Send one DevTools command and return its result (events are skipped)."""
        ident = next(self.ids)
        self.ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv(timeout=30))
            if message.get("id") == ident:
                assert "error" not in message, f"{method}: {message['error']}"
                return message["result"]

    def evaluate(self, expression: str):
        """The value of a JavaScript expression (promises awaited)."""
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True,
                           returnByValue=True)
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"].get("value")

    def goto(self, url: str) -> None:
        """Load ``url`` and wait for its load event."""
        self.call("Page.navigate", url=url)
        self.wait_for(f"document.URL === {json.dumps(url)} && "
                      "document.readyState === 'complete'")

    def wait_for(self, expression: str, timeout: float = 20):
        """Poll ``expression`` until it is truthy; return its value."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.02)
        raise AssertionError(f"timed out waiting for {expression}")

    def move_mouse(self, x: float, y: float) -> None:
        self.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)

    def screenshot(self, clip: dict | None = None) -> bytes:
        """A PNG of the page (or of ``clip``: x, y, width, height in CSS pixels)."""
        params = {"format": "png"}
        if clip:
            params["clip"] = {**clip, "scale": 1}
        return base64.b64decode(self.call("Page.captureScreenshot", **params)["data"])

    def close(self) -> None:
        try:
            self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
