"""The factored stored form at the Toys size: ``ltm compact --form factored`` on a reconstructed
scale-bench store, its bytes, SNR (against the dense LTM and the rendered truth) and the cost of
relighting one point light, beside the dense store.

Run after ``python bench/scale_bench.py --config toys --work W --reuse`` (which keeps the store):
``python bench/factored_bench.py --work W``. The store is compacted on a hard-linked copy.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path

from scale_bench import CONFIGS, SNR_STEP, truth_subset

from ltmstore.core.store import open_store
from ltmstore.judge.benchmark import random_lights, relight_cost
from ltmstore.judge.evaluate import snr_db
from ltmstore.stages.compact import store_bytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--work", required=True, type=Path, help="scale_bench.py's --work")
    parser.add_argument("--precision", default="float16", choices=("float16", "float32"))
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    args = parser.parse_args()
    cfg, scene = CONFIGS["toys"], args.work / "toys"
    src = scene / "store.zarr"
    truth = truth_subset(cfg, json.loads((scene / "simulate.json").read_text())["exposure"])
    sub = slice(SNR_STEP // 2, None, SNR_STEP)
    lights = random_lights(cfg["plane"].to_json(), 5)
    dense = open_store(src)["ltm"][sub, sub].values
    result = {"dense": {"snr_truth_db": snr_db(truth, dense), "relight": relight_cost(src, lights),
                        "ltm_bytes": sum(store_bytes(src / n) for n in ("ltm", "ltm_by_light"))}}
    dst = args.work / f"toys_factored_{args.precision}.zarr"
    shutil.rmtree(dst, ignore_errors=True)
    subprocess.run(["cp", "-al", str(src), str(dst)], check=True)
    start = time.perf_counter()
    printed = subprocess.run(["ltm", "compact", str(dst), "--form", "factored", "--precision",
                              args.precision], capture_output=True, text=True, check=True)
    seconds = time.perf_counter() - start
    factored = open_store(dst)["ltm"][sub, sub].values
    result[args.precision] = {
        "compact_s": seconds, "printed": printed.stdout.strip(),
        "snr_truth_db": snr_db(truth, factored), "snr_vs_dense_db": snr_db(dense, factored),
        "relight": relight_cost(dst, lights), "store_bytes": store_bytes(dst),
        "factor_bytes": sum(store_bytes(dst / n)
                            for n in ("ltm_weights", "ltm_basis", "ltm_ranks"))}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "compact_toys_factored.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
