"""Issue-30 benchmark: how fast ``ltm capture`` tracks phone A's frames, and how many frames per
second its page can stream with back-pressure (the page sends the next frame when the answer
arrives).

For each phone-A resolution, a raw two-phone capture is simulated (``simulate_raw``: phone A
films the ChArUco board; no phone effects), a live server is started on 127.0.0.1 (in this
process, a thread, as ``ltm capture`` runs it) and the frames are posted one after the other as
JPEG (quality 90, encoded beforehand: the phone's work), each with its ``X-Frame-Time``:

* ``tracking_ms``: the tracker alone per frame (JPEG decode + board detection + pose), timed in
  the server;
* ``tracking_cpu_ms``: the CPU time of the same (on a shared machine the wall time above
  includes waiting for a core; ``1000 / tracking_cpu_ms`` is the rate an idle core keeps up with);
* ``request_ms``: the whole round trip of ``POST /api/a/frame`` (HTTP, decode, tracking,
  coverage, answer);
* ``fps``: frames answered per second over the run (the rate the page is kept to);
* ``state_ms``: ``GET /api/state`` (the page's redraw of path and cells) after the run.

Run: ``python bench/capture_latency.py [--sizes 1280x720,640x360] [--frames 90]
[--out bench/results]``. Writes ``capture_latency.json`` and ``capture_latency.png``.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np

from ltmstore import __version__
from ltmstore.capture.board import load_board, video_frames
from ltmstore.capture.calibrate import load_intrinsics
from ltmstore.capture.live import LiveConfig, LiveSession, board_tracker
from ltmstore.capture.live_server import make_server
from ltmstore.capture.track import TrackConfig
from ltmstore.core.dims import Plane
from ltmstore.synthetic.raw import PhoneCamera, simulate_raw

PLANE = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)


def simulate(folder: Path, size: tuple[int, int], frames: int) -> Path:
    """A raw capture with about ``frames`` phone-A frames at ``size`` (board in view)."""
    extra = {"board": True, "effects": "none"}
    params = inspect.signature(simulate_raw).parameters
    density = 5.0 * frames / 91  # 91 frames at path density 5 on the 40 cm plane
    simulate_raw(folder, scene="canvas", path_density=density, seed=3, size=24,
                 lattice=(12, 12), camera=PhoneCamera(size=size, focal_px=500.0 * size[0] / 640),
                 time_offset=0.0, calibration_views=0, progress=False,
                 **{k: v for k, v in extra.items() if k in params})
    return folder


def timed_tracker(make, spent: list[float], cpu: list[float]):
    """``make`` wrapped so that each tracking call's wall seconds go to ``spent`` and its
    process CPU seconds to ``cpu`` (the client waits meanwhile: the CPU is the tracker's)."""
    def factory(size):
        track = make(size)

        def run(gray, t):
            start, start_cpu = time.perf_counter(), time.process_time()
            pose = track(gray, t)
            spent.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
            return pose
        return run
    return factory


def post(url: str, body: bytes, headers: dict) -> dict:
    req = urllib.request.Request(url, data=body, headers=headers, method="POST")
    with urllib.request.urlopen(req, timeout=60) as resp:
        return json.loads(resp.read())


def run_size(work: Path, size: tuple[int, int], frames: int) -> dict:
    sim = simulate(work / f"sim_{size[0]}x{size[1]}", size, frames)
    raw = json.loads((sim / "truth" / "raw.json").read_text())
    spent: list[float] = []
    cpu: list[float] = []
    tracker = timed_tracker(board_tracker(load_board(sim / "board.json"),
                                          load_intrinsics(sim / "truth" / "intrinsics.json"),
                                          TrackConfig(led_offset=tuple(raw["led_offset"]))),
                            spent, cpu)
    config = LiveConfig(plane=PLANE, lattice=(32, 32), target_km=0.29, height_tolerance=0.015)
    server = make_server(LiveSession(work / f"cap_{size[0]}x{size[1]}", config, tracker))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    jpegs = [(t, cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
             for _, t, g in video_frames(sim / "phone_a.mkv")][:frames]
    url = server.url("/api/a/frame")
    trips, placed = [], 0
    start = time.perf_counter()
    for t, body in jpegs:
        t0 = time.perf_counter()
        placed += post(url, body, {"X-Frame-Time": repr(t)})["placed"]
        trips.append(time.perf_counter() - t0)
    wall = time.perf_counter() - start
    states = []
    for _ in range(10):
        t0 = time.perf_counter()
        urllib.request.urlopen(server.url("/api/state"), timeout=60).read()
        states.append(time.perf_counter() - t0)
    server.shutdown()
    server.server_close()

    def stats(seconds: list[float]) -> dict:
        ms = 1e3 * np.asarray(seconds)
        return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)),
                "max": float(ms.max())}

    return {"size": list(size), "frames": len(jpegs), "placed": placed,
            "jpeg_kib_median": float(np.median([len(b) for _, b in jpegs]) / 1024),
            "tracking_ms": stats(spent), "tracking_cpu_ms": stats(cpu), "request_ms": stats(trips),
            "fps": len(jpegs) / wall, "state_ms": stats(states),
            "raw_ms": {"tracking": [1e3 * s for s in spent], "request": [1e3 * s for s in trips]}}


def chart(rows: list[dict], path: Path, load: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    data, labels = [], []
    for row in rows:
        name = "x".join(map(str, row["size"]))
        data += [row["raw_ms"]["tracking"], row["raw_ms"]["request"]]
        labels += [f"{name}\ntracking", f"{name}\nrequest ({row['fps']:.1f} fps)"]
    ax.boxplot(data, whis=(5, 95), showfliers=False)
    ax.set_xticks(range(1, len(labels) + 1), labels)
    ax.set_ylabel("ms per phone-A frame")
    ax.set_title("ltm capture: board tracking and POST /api/a/frame round trip\n"
                 f"(box: quartiles, whiskers 5-95 %; load average {load:.1f} on "
                 f"{os.cpu_count()} cores)", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1280x720,640x360")
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--out", default="bench/results")
    a = parser.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in a.sizes.split(",")]
    out = Path(a.out)
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="capture_latency_") as tmp:
        rows = [run_size(Path(tmp), size, a.frames) for size in sizes]
    result = {"command": "python bench/capture_latency.py "
              f"--sizes {a.sizes} --frames {a.frames}", "ltmstore": __version__,
              "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "load_average_1min": [load_start[0], os.getloadavg()[0]]},
              "rows": [{k: v for k, v in r.items() if k != "raw_ms"} for r in rows]}
    out.mkdir(parents=True, exist_ok=True)
    (out / "capture_latency.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(rows, out / "capture_latency.png", result["machine"]["load_average_1min"][1])
    for r in result["rows"]:
        print(f"{r['size'][0]}x{r['size'][1]}: tracking {r['tracking_ms']['median']:.1f} ms "
              f"(p95 {r['tracking_ms']['p95']:.1f}; CPU {r['tracking_cpu_ms']['median']:.1f}), "
              f"request {r['request_ms']['median']:.1f} ms "
              f"(p95 {r['request_ms']['p95']:.1f}), {r['fps']:.1f} fps, state "
              f"{r['state_ms']['median']:.1f} ms, placed {r['placed']}/{r['frames']}")


if __name__ == "__main__":
    main()
