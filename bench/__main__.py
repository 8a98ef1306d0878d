"""The benchmarks by name.

    python -m bench list                 # every benchmark, one line each
    python -m bench run NAME [ARGS ...]  # run one; ARGS go to it (``run NAME --help``)

Run from the clone's root. Each benchmark writes its JSON and chart into ``bench/results/``
(where ``docs/benchmarks.md`` reads them) unless given another ``--out``; the results there are
the published ones, so measure elsewhere (``--out bench-out/``, which git ignores) until a
result is meant to replace them. A benchmark is a script of this folder (``run`` starts it as
``python bench/SCRIPT.py ARGS``, which works as well) or, for ``bench``, ``ltm bench``. None
runs as a test; most take many minutes on two cores.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

HERE = Path(__file__).resolve().parent


class Benchmark(NamedTuple):
    script: str  # in this folder; "" for ``ltm bench``
    about: str  # one line: what it measures


BENCHMARKS = {
    "bench": Benchmark("", "every method, speed against accuracy (ltm bench: bench.json)"),
    "auto_handheld": Benchmark("auto_handheld.py", "auto against single methods on handheld "
                               "paths, physics the model lacks"),
    "pipeline": Benchmark("pipeline_bench.py", "cs against per-pixel LARS through the real "
                          "pipeline (pipeline.json)"),
    "default_speed": Benchmark("default_speed.py", "the default ltm reconstruct against "
                               "--method cs: time, SNR_Y"),
    "stability": Benchmark("stability_table.py", "every method in nine failure regimes"),
    "heldout_table": Benchmark("heldout_table.py", "held-out photographs: the default against "
                               "every classic fit"),
    "cast_shadows": Benchmark("cast_shadows.py", "the far surface's cast shadows on the "
                              "relief at 96-512 px: held-out PSNR, time, with and without"),
    "heldout_protocols": Benchmark("heldout_protocols.py", "other held-out rules for the far "
                                   "surface's choice"),
    "rti_speed": Benchmark("rti_speed.py", "classic captures: ingest-rti + reconstruct beside "
                           "relight-cli"),
    "height_peer": Benchmark("height_peer.py", "SynthRTI's given normals integrated: ltm maps "
                             "--height beside relight-normals (BNI, FFT)"),
    "iiif_tiles": Benchmark("iiif_tiles.py", "ltm view's IIIF tiles: the first relit tile and "
                            "bytes read, beside ltm relight of the whole image"),
    "rti_peer": Benchmark("rti_peer.py", "classic captures: time to a relightable store, to the "
                          "refined one, held-out PSNR of each beside relight-cli's bases"),
    "rti_scale": Benchmark("rti_scale.py", "classic captures resized to 1-24 MP: time, peak "
                           "memory"),
    "scale": Benchmark("scale_bench.py", "Toys or Notre Dame-b size out of core "
                       "(scale_CONFIG.json)"),
    "scale_compare": Benchmark("scale_compare.py", "two versions' scale runs side by side"),
    "factored": Benchmark("factored_bench.py", "ltm compact --form factored on a scale store"),
    "factored_compare": Benchmark("factored_compare.py", "dense and factored reconstruct, from "
                                  "scale runs"),
    "export_fidelity": Benchmark("export_fidelity.py", "each export format read back at the "
                                 "held-out lights, beside ltm relight"),
    "export_speed": Benchmark("export_speed.py", "the web export's whole command: time, "
                              "memory, held-out PSNR, beside older code"),
    "ingest_memory": Benchmark("ingest_memory.py", "ltm ingest-rti's peak memory and time on "
                               "classic captures of 1-24 MP, beside older code"),
    "relight_memory": Benchmark("relight_memory.py", "ltm relight's peak memory on classic "
                                "captures of 1-24 MP, beside reconstruct's"),
    "tiled_first_view": Benchmark("tiled_first_view.py", "a web export's first view in "
                                  "OpenLIME, whole planes against deepzoom tiles"),
    "relight_latency": Benchmark("relight_latency.py", "a point and an area light on a 0.25 MP "
                                 "store, bytes read"),
    "scale_4k": Benchmark("scale_4k.py", "a phone's 4K video, whole (scale_4k/scale_4k.json)"),
    "scale_4k_charts": Benchmark("scale_4k_charts.py", "every kept scale_4k run: codec and "
                                 "time-accuracy charts"),
    "cluster": Benchmark("cluster_bench.py", "ltm reconstruct on dask scheduler + workers, "
                         "every task timed"),
    "cluster_4k": Benchmark("cluster_4k.py", "the 4K reconstruct on dask scheduler + workers"),
    "scale_6d": Benchmark("bench_6d.py", "the paper's 6D configuration out of core"),
    "track": Benchmark("track_bench.py", "two phones on a board: calibration, tracking, sync"),
    "calibration_frames": Benchmark("calibration_frames.py", "ltm calibrate's lens model "
                                    "choice: frame SNR against the true lens"),
    "phone_effects": Benchmark("phone_effects.py", "the two-phone chain with phone effects"),
    "phone_effects_phone_size": Benchmark("phone_effects_phone_size.py", "the phone effects "
                                          "at camera B 720 px: product against oracle"),
    "openlime_fidelity": Benchmark("openlime_fidelity.py", "the web export drawn by OpenLIME "
                                   "at real captures' held-out lights"),
    "neural_web": Benchmark("neural_web.py", "OpenLIME's neural layer's network trained on a "
                            "store: held-out PSNR it could reach"),
    "codec_split": Benchmark("codec_split.py", "where camera B's H.264 loss lands: frame "
                             "error by type, LTM error on observed and filled cells"),
    "codec_bitrate": Benchmark("codec_bitrate.py", "camera B's H.264 by its bits per pixel: "
                               "LTM SNR_Y against the uncompressed video's"),
    "codec_noise": Benchmark("codec_noise.py", "camera B's H.264 error rearranged between "
                             "frames: shared within a second against scattered"),
    "capture_latency": Benchmark("capture_latency.py", "ltm capture: tracking time, frames per "
                                 "second"),
    "capture_screenshots": Benchmark("capture_screenshots.py", "the ltm capture pages in "
                                     "headless Chromium"),
    "placement": Benchmark("placement_bench.py", "the object placed from the data"),
    "near_normals": Benchmark("near_normals.py", "normal maps of simulated handheld captures"),
    "normals_baseline": Benchmark("normals_baseline.py", "SynthRTI normal maps against "
                                  "photometric stereo"),
    "view_latency": Benchmark("view_latency.py", "ltm view's round trip in headless Chromium"),
}


def command(name: str, args: list[str]) -> list[str]:
    """The command line that runs benchmark ``name`` with ``args``."""
    script = BENCHMARKS[name].script
    if not script:  # ltm bench, into the published results unless told otherwise
        return [sys.executable, "-c", "import sys; from ltmstore.cli import main; "
                "sys.exit(main(sys.argv[1:]))", "bench", "--out", "bench/results", *args]
    return [sys.executable, str(HERE / script), *args]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0],
                                     epilog="python -m bench list: the names")
    sub = parser.add_subparsers(dest="action", required=True, metavar="{list,run}")
    sub.add_parser("list", help="every benchmark with one line about it")
    run = sub.add_parser("run", help="run one benchmark: run NAME [ARGS ...]")
    run.add_argument("name", choices=BENCHMARKS, metavar="NAME")
    run.add_argument("args", nargs=argparse.REMAINDER, help="its own arguments (--help lists them)")
    a = parser.parse_args(argv)
    if a.action == "list":
        width = max(map(len, BENCHMARKS))
        for name, bench in BENCHMARKS.items():
            print(f"{name:<{width}}  {bench.about}")
        return 0
    return subprocess.call(command(a.name, a.args))


if __name__ == "__main__":
    sys.exit(main())
