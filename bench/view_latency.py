"""Round trip of ``ltm view``: the page's request for a relit image, measured in Chromium.

Run: ``python bench/view_latency.py STORE`` (a reconstructed store; the docs' figure uses the
Toys-size store of ``bench/scale_bench.py --config toys``: 400 x 400 px, 50 x 50 lattice).
Starts ``ltm view STORE`` as a real process, loads the page in headless Chromium (Debian's
``chromium``; the DevTools driver of ``tests/browser.py``), moves the pointer to ``--repeats``
random light positions one after another (each waits for its image: new lattice blocks, read
from the store) and records the page's round trip (request sent to image decoded,
``performance.now``) and the server's render time; then steps of 1/200 of the plane's width (half
a cell of a 50 x 50 lattice: mostly blocks the server already holds); then an area light; then a
fast sweep (pointer moved every 10 ms for 3 s: the page keeps one request in flight and sends the
latest position) to count images shown per second.
Writes ``view_latency.json`` and a screenshot ``viewer.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import Browser  # noqa: E402

WAIT = ("(() => {{ const v = window.ltmView; return !v.inflight && v.requests > {n} && "
        "v.last; }})()")


def move(browser: Browser, u: float, v: float) -> None:
    rect = browser.evaluate("JSON.parse(JSON.stringify("
                            "document.getElementById('stage').getBoundingClientRect()))")
    browser.move_mouse(rect["left"] + (u + 1) / 2 * rect["width"],
                       rect["top"] + (1 - v) / 2 * rect["height"])


def timed_moves(browser: Browser, points: np.ndarray) -> dict:
    """Move to each point, wait for its image; the page's and the server's times (ms)."""
    page, server = [], []
    for u, v in points:
        n = browser.evaluate("window.ltmView.requests")
        move(browser, u, v)
        last = browser.wait_for(WAIT.format(n=n), timeout=60)
        page.append(last["ms"])
        server.append(last["render_ms"])
    return {"page_round_trip_ms_median": float(np.median(page)),
            "page_round_trip_ms_p90": float(np.percentile(page, 90)),
            "server_render_ms_median": float(np.median(server)),
            "page_round_trip_ms": [round(x, 1) for x in page], "repeats": len(page)}


def sweep(browser: Browser, seconds: float = 3.0) -> dict:
    """Pointer moved every 10 ms along a circle: images shown per second."""
    start_n = browser.evaluate("window.ltmView.requests")
    start = time.perf_counter()
    k = 0
    while time.perf_counter() - start < seconds:
        angle = 2 * np.pi * k / 150
        move(browser, 0.7 * np.cos(angle), 0.7 * np.sin(angle))
        k += 1
        time.sleep(0.01)
    browser.wait_for("!window.ltmView.inflight", timeout=60)
    elapsed = time.perf_counter() - start
    shown = browser.evaluate("window.ltmView.requests") - start_n
    return {"pointer_moves": k, "images_shown": shown, "seconds": elapsed,
            "images_per_second": shown / elapsed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("store")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--out", default="bench/results")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    ltm = Path(sys.executable).parent / "ltm"
    proc = subprocess.Popen([ltm, "view", args.store], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        url = line.split(" at ")[1].split()[0]
        startup = time.perf_counter() - start
        rng = np.random.default_rng(0)
        points = rng.uniform(-0.9, 0.9, size=(args.repeats, 2))
        with Browser(1200, 800) as browser:
            browser.goto(url)
            browser.wait_for("window.ltmView.ready", timeout=60)
            info = json.loads(browser.evaluate("fetch('info').then(r => r.text())"))
            point = timed_moves(browser, points)
            steps = timed_moves(browser, np.column_stack([0.3 + 0.01 * np.arange(args.repeats),
                                                          np.full(args.repeats, 0.3)]))
            fast = sweep(browser)
            browser.evaluate("document.querySelector('input[value=area]').click()")
            browser.wait_for("!window.ltmView.inflight && window.ltmView.last.light.radius > 0",
                             timeout=60)
            area = timed_moves(browser, points[: max(3, args.repeats // 2)])
            browser.evaluate("document.querySelector('input[value=point]').click()")
            move(browser, -0.45, 0.55)
            time.sleep(0.05)
            browser.wait_for("!window.ltmView.inflight && "
                             "window.ltmView.last.light.radius === 0", timeout=60)
            (out / "viewer.png").write_bytes(browser.screenshot())
    finally:
        proc.terminate()
        proc.wait()
    result = {
        "command": f"python bench/view_latency.py {args.store} --repeats {args.repeats}",
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "store": {k: info[k] for k in ("width", "height", "lattice", "far", "views")},
        "load_average_1min_at_end": os.getloadavg()[0],
        "server_startup_s": startup, "point_light_random": point,
        "point_light_small_steps": steps, "area_light_radius_0.1": area,
        "sweep": fast,
    }
    (out / "view_latency.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
