"""Server-side relighting by URL: time to the first relit IIIF tile and bytes read, beside
``ltm relight`` of the whole image, on classic (far-light) captures of 1 and 4 MP.

Run: ``python bench/iiif_tiles.py [--data ../shared/data] [--sizes 1,4] [--repeats 3]
[--work DIR]``. Each capture is SynthRTI ``multi-obj1-material1``'s first 47 dome photographs
resized to SIZE megapixels (``bench/rti_speed.py``'s ``resized_capture``), ingested and
reconstructed once under ``--work``. Per size, each repeat at a light not asked before (no
cache helps; medians over ``--repeats``):

* ``relight_cli_s``: ``ltm relight STORE --light LX,LY -o OUT.png`` as a subprocess (what a
  user runs: Python's start, opening the store, the whole image, the PNG);
* ``relight_whole_s`` and ``relight_whole_bytes``: the same in one warm process
  (``relight`` + ``encoded_images``), through a byte-counting Zarr store;
* ``tile_http_s``: from a GET of a 256 x 256 tile at full resolution (the image's centre) to its
  last byte, from ``ltm view STORE`` already serving (started before, as a viewer's user has it);
  ``overview_http_s``: the same for the whole image at the scale that fits one tile (what a
  tiled viewer asks first: it reads the whole image);
* ``tile_bytes`` and ``overview_bytes``: the bytes those read, in process (``RelitTiles`` on the
  dataset ``ltm view`` serves: variables up to 32 MB held in memory, through a counting store);
* ``view_start_s``: ``ltm view`` from its start to its URL line (opening the store, once).

Writes ``bench/results/iiif_tiles.json`` with the load average (``uptime``) before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zarr

sys.path.insert(0, str(Path(__file__).parent))
from rti_speed import load, ltm_command, resized_capture  # noqa: E402

from ltmstore.core.provenance import commit  # noqa: E402
from ltmstore.core.store import CountingStore, open_store  # noqa: E402
from ltmstore.share import iiif  # noqa: E402
from ltmstore.share.iiif import LightId  # noqa: E402
from ltmstore.share.relit_tiles import RelitTiles  # noqa: E402
from ltmstore.share.view import in_memory  # noqa: E402
from ltmstore.stages.relight import encoded_images, relight  # noqa: E402

LIGHTS = [(0.30, 0.20), (-0.25, 0.35), (0.10, -0.40), (0.45, -0.05), (-0.35, -0.30)]


def build(data: Path, work: Path, mp: float) -> Path:
    """The reconstructed store of the ``mp`` megapixel capture (built once)."""
    store = work / f"rti-{mp:g}MP.zarr"
    if (store / "zarr.json").exists():
        return store
    lp = resized_capture(data, work / f"capture-{mp:g}MP", mp * 1e6, 47)
    subprocess.run([*ltm_command(), "ingest-rti", str(lp), str(store)], check=True,
                   capture_output=True)
    subprocess.run([*ltm_command(), "reconstruct", str(store)], check=True, capture_output=True)
    return store


def get(port: int, path: str) -> tuple[float, int]:
    """Seconds from sending a GET to its last byte, and its status."""
    start = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=600) as sock:
        sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                     "Connection: close\r\n\r\n".encode())
        data = b""
        while chunk := sock.recv(1 << 16):
            data += chunk
    return time.perf_counter() - start, int(data.split(b" ", 2)[1])


def requests(width: int, height: int) -> dict[str, str]:
    """The full-resolution centre tile and the one-tile overview, as IIIF paths' tails."""
    x, y = (width // 2) // 256 * 256, (height // 2) // 256 * 256
    scale = iiif.scale_factors(width, height)[-1]
    w, h = -(-width // scale), -(-height // scale)
    return {"tile": f"{x},{y},256,256/256,256/0/default.png",
            "overview": f"full/{w},{h}/0/default.png"}


def counted(store: Path, light: tuple[float, float], what: str,
            tail: str | None = None) -> tuple[float, int]:
    """Seconds and bytes read of the whole image (``what`` = whole) or a tile, in process."""
    counting = CountingStore(zarr.storage.LocalStore(str(store), read_only=True))
    ds = open_store(counting)
    transfer = ds.attrs["acquisition"].get("transfer", "srgb")
    if what == "whole":
        before, start = counting.bytes_read, time.perf_counter()
        list(encoded_images(relight(ds, [light]), transfer))
        return time.perf_counter() - start, counting.bytes_read - before
    tiles = RelitTiles(in_memory(ds), transfer)
    request = iiif.parse_request([f"{light[0]},{light[1]}", *tail.split("/")],
                                 tiles.width, tiles.height)
    tiles.image(LightId(light=light))  # the light's checks (as info.json does first)
    before, start = counting.bytes_read, time.perf_counter()
    tiles.tile(request)
    return time.perf_counter() - start, counting.bytes_read - before


def measure(store: Path, repeats: int) -> dict:
    """Every measure of one store, per repeat at a new light."""
    ds = open_store(store)
    width, height = int(ds.sizes["x"]), int(ds.sizes["y"])
    tails = requests(width, height)
    runs: dict[str, list] = {}

    def add(key: str, value: float) -> None:
        runs.setdefault(key, []).append(value)

    start = time.perf_counter()
    view = subprocess.Popen([*ltm_command(), "view", str(store)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        line = view.stdout.readline()
        add("view_start_s", time.perf_counter() - start)
        port = int(line.split(" at ")[1].split()[0].rstrip("/").rsplit(":", 1)[1])
        for k in range(repeats):
            light = LIGHTS[k % len(LIGHTS)]
            ident = f"{light[0]},{light[1]}"
            for name, tail in tails.items():
                seconds, status = get(port, f"/iiif/{ident};ev={0.01 * (k + 1)}/{tail}")
                assert status == 200, status
                add(f"{name}_http_s", seconds)
    finally:
        view.kill()
        view.wait()
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            light = LIGHTS[(k + 1) % len(LIGHTS)]
            t0 = time.perf_counter()
            subprocess.run([*ltm_command(), "relight", str(store), "--light",
                            f"{light[0]},{light[1]}", "-o", f"{tmp}/relit.png", "--overwrite"],
                           check=True, capture_output=True)
            add("relight_cli_s", time.perf_counter() - t0)
            for what, tail in [("whole", None), *((n, t) for n, t in tails.items())]:
                seconds, nbytes = counted(store, light, what, tail)
                add(f"{'relight_whole' if what == 'whole' else what}_s_in_process", seconds)
                add(f"{'relight_whole' if what == 'whole' else what}_bytes", nbytes)
    result = {"width": width, "height": height, "requests": tails,
              **{k: statistics.median(v) for k, v in runs.items()}, "runs": runs}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=str(Path(__file__).parents[1] / ".." / "shared" /
                                              "data"))
    parser.add_argument("--sizes", default="1,4")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "ltm-iiif-bench"))
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    a = parser.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    stores = {s: build(Path(a.data), work, float(s)) for s in a.sizes.split(",")}
    result = {"command": "python bench/iiif_tiles.py " + " ".join(sys.argv[1:]),
              "commit": commit(), "cores": os.cpu_count(), "repeats": a.repeats,
              "lights": 47, "load_start": load(), "sizes": {}}
    for size, store in stores.items():
        result["sizes"][size] = measure(store, a.repeats)
        print(size, json.dumps({k: v for k, v in result["sizes"][size].items() if k != "runs"}),
              flush=True)
    result["load_end"] = load()
    out = Path(a.out) / "iiif_tiles.json"
    out.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
