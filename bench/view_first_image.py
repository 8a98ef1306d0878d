"""``ltm view`` on a huge store: from the command to the first relit image in the browser, and
each new light at the fit and zoomed in to one image pixel per screen pixel.

Run: ``python bench/view_first_image.py STORE [--repeats 3] [--old TREE] [--out DIR]``.
Starts ``ltm view STORE`` as a real process (with ``--old``, the same command of an earlier
tree through ``PYTHONPATH=TREE``: old first), loads its page in headless
Chromium (1000 x 700 window; the DevTools driver of ``tests/browser.py``) and records:

* ``start_s``: from the command to its URL line (the server opening the store);
* ``load``: from loading the page to its first image (``first_s``: a preview where the page
  asks one) and to its whole picture (``full_s``), and that picture's PNG ``bytes``;
* ``fit`` and ``zoomed``: the same from moving the pointer to each of ``--repeats`` new
  lights, with the whole image fitted to the window and zoomed about its centre to at least
  one image pixel per screen pixel; medians.

Writes ``view_first_image.json`` into ``--out`` with the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).parent))
from browser import Browser  # noqa: E402
from rti_speed import load, ltm_command  # noqa: E402

from ltmstore.core.provenance import commit  # noqa: E402

STAGE = "JSON.parse(JSON.stringify(document.getElementById('stage').getBoundingClientRect()))"
VIEWPORT = ("JSON.parse(JSON.stringify(document.getElementById('viewport')"
            ".getBoundingClientRect()))")
BYTES = ("performance.getEntriesByType('resource').filter(e => e.name.includes('/relight?'))"
         ".map(e => e.encodedBodySize)")
LIGHTS = [(0.3, 0.2), (-0.25, 0.35), (0.1, -0.4), (0.45, -0.05), (-0.35, -0.3)]


def shown(browser: Browser, n: int, t0: float) -> dict:
    """Seconds from ``t0`` to the page's next image (a preview, where it asks one) and to its
    whole picture (nothing in flight), and the PNG bytes of that picture."""
    browser.wait_for(f"window.ltmView.requests > {n}", timeout=1800)
    first = time.perf_counter() - t0
    browser.wait_for("!window.ltmView.inflight", timeout=1800)
    return {"first_s": first, "full_s": time.perf_counter() - t0,
            "bytes": browser.evaluate(BYTES)[-1]}


def new_light(browser: Browser, u: float, v: float) -> dict:
    """Move the pointer to ``(u, v)`` over the image (kept inside the viewport): :func:`shown`."""
    n = browser.evaluate("window.ltmView.requests")
    rect = browser.evaluate(STAGE)
    vp = browser.evaluate(VIEWPORT)
    x = min(max(rect["left"] + (u + 1) / 2 * rect["width"], vp["left"] + 1), vp["right"] - 1)
    y = min(max(rect["top"] + (1 - v) / 2 * rect["height"], vp["top"] + 1), vp["bottom"] - 1)
    t0 = time.perf_counter()
    browser.move_mouse(x, y)
    return shown(browser, n, t0)


def zoom_to_pixels(browser: Browser, width: int) -> None:
    """Wheel about the viewport's centre until one image pixel covers a screen pixel."""
    vp = browser.evaluate(VIEWPORT)
    x, y = (vp["left"] + vp["right"]) / 2, (vp["top"] + vp["bottom"]) / 2
    browser.evaluate("document.getElementById('hold').checked = true")  # the light stays
    while browser.evaluate(STAGE)["width"] < width:
        browser.call("Input.dispatchMouseEvent", type="mouseWheel", x=x, y=y, deltaX=0,
                     deltaY=-400)
    browser.wait_for("!window.ltmView.inflight", timeout=1800)
    browser.evaluate("document.getElementById('hold').checked = false")


def measure(store: str, repeats: int, env: dict) -> dict:
    """One run of the page on ``store`` with ``env`` (an earlier tree's ``PYTHONPATH``)."""
    start = time.perf_counter()
    proc = subprocess.Popen([*ltm_command(), "view", store], stdout=subprocess.PIPE, text=True,
                            env=env)
    try:
        line = proc.stdout.readline()
        url = line.split(" at ")[1].split()[0]
        result = {"start_s": time.perf_counter() - start}
        with Browser(1000, 700, timeout=60) as browser:
            t0 = time.perf_counter()
            browser.goto(url)
            result["load"] = shown(browser, 0, t0)
            width = browser.evaluate("fetch('info').then(r => r.json()).then(i => i.width)")
            fit = [new_light(browser, *light) for light in LIGHTS[:repeats]]
            zoom_to_pixels(browser, width)
            zoomed = [new_light(browser, -u, -v) for u, v in LIGHTS[:repeats]]
    finally:
        proc.terminate()
        proc.wait()
    for key, runs in (("fit", fit), ("zoomed", zoomed)):
        result[key] = {k: statistics.median(run[k] for run in runs) for k in runs[0]}
        result[f"{key}_runs"] = runs
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("store")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--old", default=None, help="a tree of earlier code (git worktree)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = parser.parse_args()
    trees = ([("old", str(Path(args.old).resolve()))] if args.old else []) + [("this", None)]
    result = {"command": "python bench/view_first_image.py " + " ".join(sys.argv[1:]),
              "commit": commit(), "cores": os.cpu_count(), "load_start": load()}
    for label, tree in trees:
        env = dict(os.environ, **({"PYTHONPATH": tree} if tree else {}))
        result[label] = measure(args.store, args.repeats, env)
        print(label, json.dumps({k: v for k, v in result[label].items()
                                 if not k.endswith("runs")}), flush=True)
    result["load_end"] = load()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "view_first_image.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
