"""The two pages of ``ltm capture`` driven in headless Chromium, each fed by a fake camera that
plays a simulated raw capture (``tests/capture/test_live_pages.py``,
``bench/capture_screenshots.py``).

The raw capture is simulated small: phone A 640 x 360 (500 px focal, as ``test_two_phones``)
filming the ChArUco board, camera B 24 px, 225 frames (7.5 s) at 30 fps. Chromium plays a
``.y4m`` file in a loop from the moment a page opens its camera, in real time: phone A's file
holds every other frame (15 fps, so that it stays small), camera B's every frame. Camera B's
page meters the light for 1.5 s before it records, so both recordings end before either file
loops when phone A runs for :data:`RUN_S`.
"""

from __future__ import annotations

import inspect
import json
import subprocess
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
from browser import Browser
from pipeline_helpers import BIN

SEED = 3
LATTICE = (12, 12)
PHONE = {"size": (640, 360), "focal_px": 500.0}
PATH_DENSITY = 12.0  # 225 frames, 7.5 s
A_EVERY = 2  # phone A's fake camera: every other frame (15 fps)
RUN_S = 5.0  # s phone A streams (both files last 7.5 s; camera B's started 1.5 s earlier)
OFFLINE_S = (1.0, 2.5)  # camera B's page is offline from 1 s into phone A's run, for 2.5 s
VIEWPORT = (412, 915)  # a phone's CSS pixels
STATES_DONE = ("finished", "closed", "error")
PAGE_STATE = "JSON.stringify(window.ltmCapture)"
SHOWN = ("Object.fromEntries(['km', 'cells', 'snr', 'frames', 'enough', 'warning'].map((id) => "
         "[id, document.getElementById(id).hidden ? null : "
         "document.getElementById(id).textContent]))")


def simulate(out: Path) -> dict:
    """A raw capture with the board in view and no phone effects (the ``sim`` options where
    ``simulate_raw`` has them); its info dict."""
    from ltmstore.synthetic.raw import PhoneCamera, simulate_raw

    options = {"board": True, "effects": "none"}
    known = inspect.signature(simulate_raw).parameters
    return simulate_raw(out, scene="canvas", path_density=PATH_DENSITY, seed=SEED, size=24,
                        lattice=LATTICE, camera=PhoneCamera(**PHONE), calibration_views=0,
                        progress=False, **{k: v for k, v in options.items() if k in known})


def write_y4m(video: Path, out: Path, every: int = 1) -> int:
    """Every ``every``-th frame of ``video`` as a YUV4MPEG2 file (what Chromium's fake camera
    plays) at the matching frame rate; the number of frames written."""
    from ltmstore.capture.video import VideoReader

    count = 0
    with VideoReader(video) as reader, open(out, "wb") as f:
        rate = round(reader.fps)
        for i, rgb in enumerate(reader):
            if i % every:
                continue
            if not count:
                h, w = rgb.shape[:2]
                f.write(f"YUV4MPEG2 W{w} H{h} F{rate}:{every} Ip A1:1 C420jpeg\n".encode())
            yuv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YUV_I420)
            f.write(b"FRAME\n" + yuv.tobytes())
            count += 1
    return count


def fake_camera(y4m: Path) -> tuple[str, ...]:
    """Chromium flags: a camera that plays ``y4m``, granted without asking."""
    return ("--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream",
            f"--use-file-for-fake-video-capture={y4m}")


def start_capture(sim: Path, folder: Path) -> tuple[subprocess.Popen, str, str]:
    """``ltm capture FOLDER`` (board tracker, the simulation's intrinsics and LED offset) as a
    real process; it, phone A's address and camera B's."""
    raw = json.loads((sim / "truth" / "raw.json").read_text())
    proc = subprocess.Popen(
        [BIN / "ltm", "capture", folder, "--intrinsics", sim / "truth" / "intrinsics.json",
         "--board", sim / "board.json", "--led-offset", ",".join(map(str, raw["led_offset"])),
         "--lattice", "x".join(map(str, LATTICE)), "--no-qr"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    urls = {}
    for line in proc.stdout:
        if "http://127.0.0.1:" in line:
            urls["a" if line.startswith("phone A") else "b"] = line.split()[-1]
        if "ltm capture: listening" in line or proc.poll() is not None:
            break
    assert set(urls) == {"a", "b"}, (urls, proc.poll() is not None and proc.stderr.read())
    return proc, urls["a"], urls["b"]


def offline(page: Browser, on: bool) -> None:
    """Cut (or restore) the page's network, as a dropped Wi-Fi would."""
    page.call("Network.enable")
    page.call("Network.emulateNetworkConditions", offline=on, latency=0, downloadThroughput=-1,
              uploadThroughput=-1)


def click(page: Browser, button: str) -> None:
    page.evaluate(f"document.getElementById({json.dumps(button)}).click()")


def wait_page(page: Browser, expression: str, timeout: float) -> None:
    """:meth:`Browser.wait_for` on a capture page; a timeout names what the page holds and shows
    (its ``ltmCapture`` and banner), not only the expression."""
    try:
        page.wait_for(expression, timeout)
    except AssertionError as error:
        held = page.evaluate("JSON.stringify({capture: window.ltmCapture, "
                             "message: document.getElementById('message').textContent})")
        raise AssertionError(f"{error}; the page holds {held}") from None


def start_page(page: Browser, state: str) -> None:
    """Press the page's Start and wait until its state is ``state``. A page not there in 40 s
    is loaded again and started once more, as its user would, with a warning naming what it
    held. The start waits on Chromium's fake camera: in clean-clone suite runs camera B's page
    once took over 20 s to record and once never did in 60 s (cause not found; Chromium now
    runs unthrottled and camera B no longer waits on its preview)."""
    expression = f"window.ltmCapture.state === {json.dumps(state)}"
    click(page, "start")
    try:
        wait_page(page, expression, 40)
    except AssertionError as error:
        warnings.warn(f"{error}: the page is loaded again and started once more", stacklevel=2)
        page.evaluate("window.ltmReloading = true")
        page.call("Page.reload")
        page.wait_for("!window.ltmReloading && document.readyState === 'complete'")
        click(page, "start")
        wait_page(page, expression, 60)


def run_capture(sim: Path, folder: Path, work: Path, *, shots: dict | None = None) -> dict:
    """Camera B's page records, phone A's page streams for :data:`RUN_S` (camera B's network
    cut meanwhile, :data:`OFFLINE_S`), camera B stops, then phone A (the protocol
    ``ltm capture --help`` gives). Returns both pages' ``ltmCapture``,
    the texts phone A's page shows, the server's exit status and timings. ``shots``: where to
    save a PNG of each page (``{"a": path, "b": path}``) while phone A streams."""
    y4m_a, y4m_b = work / "phone_a.y4m", work / "camera_b.y4m"
    write_y4m(sim / "phone_a.mkv", y4m_a, A_EVERY)
    write_y4m(sim / "video.mkv", y4m_b)
    proc, url_a, url_b = start_capture(sim, folder)
    try:
        with Browser(*VIEWPORT, args=fake_camera(y4m_b)) as b, \
                Browser(*VIEWPORT, args=fake_camera(y4m_a)) as a:
            b.goto(url_b)
            a.goto(url_a)
            start_page(b, "recording")
            start_page(a, "running")
            started = time.monotonic()
            time.sleep(OFFLINE_S[0])
            offline(b, True)  # camera B's Wi-Fi drops: its pieces must wait, then all arrive
            time.sleep(OFFLINE_S[1])
            offline(b, False)
            time.sleep(RUN_S - sum(OFFLINE_S))
            if shots:
                shots["a"].write_bytes(a.screenshot())
                shots["b"].write_bytes(b.screenshot())
            streamed = time.monotonic() - started
            click(b, "stop")
            wait_page(b, "window.ltmCapture.state !== 'stopping'", 60)
            click(a, "stop")
            done = f"{json.dumps(STATES_DONE)}.includes(window.ltmCapture.state)"
            wait_page(a, done, 60)
            error = a.evaluate("window.ltmCapture.error")
            assert error is None, f"phone A's page stopped with: {error}"
            wait_page(b, done, 60)
            pages = {"a": json.loads(a.evaluate(PAGE_STATE)), "shown": a.evaluate(SHOWN),
                     "b": json.loads(b.evaluate(PAGE_STATE)),
                     "messages": {k: p.evaluate("document.getElementById('message').textContent")
                                  for k, p in (("a", a), ("b", b))},
                     "exposure": b.evaluate("document.getElementById('exposure').textContent")}
        pages["returncode"] = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return {**pages, "streamed_s": streamed}
