"""One point light's relighting time on an existing store: cold (median of 5, the store opened
anew each time) and warm (median of 10 on a store opened once, after a first light), as
``bench/scale_4k.py`` records it, for this code and, alternating in the same run, an older one.

Run: ``python bench/relight_warm.py STORE [--old TREE] [--repeats 2] [--out JSON]``. ``TREE`` is
a copy of an earlier commit (``git archive C | tar -x -C TREE``), run with ``PYTHONPATH=TREE``.
Each measure is its own process (nothing cached between them but the operating system's
page cache); the load average is recorded with each.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

MEASURE = """
import json, os, sys
import ltmstore
from ltmstore.judge.benchmark import random_lights, relight_cost, warm_relight_cost
from ltmstore.synthetic.simulate import PLANE
cold = relight_cost(sys.argv[1], random_lights(PLANE.to_json(), 5))
warm = warm_relight_cost(sys.argv[1], random_lights(PLANE.to_json(), 11))
print(json.dumps({"code": ltmstore.__file__, "load_average_1min": os.getloadavg()[0],
                  "cold": cold, "warm": warm}))
"""


def measure(store: Path, tree: Path | None) -> dict:
    """One process's cold and warm relighting cost, with the code of ``tree`` (or this one)."""
    env = dict(os.environ) if tree is None else {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", MEASURE, str(store.resolve())], env=env,
                          cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store", type=Path)
    parser.add_argument("--old", type=Path, help="a copy of an earlier commit to run beside")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("relight_warm.json"))
    args = parser.parse_args()
    runs: dict[str, list] = {"new": [], "old": []}
    for _ in range(args.repeats):
        runs["new"].append(measure(args.store, None))
        if args.old is not None:
            runs["old"].append(measure(args.store, args.old))
    summary = {name: {kind: statistics.median(r[kind]["seconds_median"] for r in rs)
                      for kind in ("cold", "warm")} for name, rs in runs.items() if rs}
    result = {"command": " ".join(sys.argv), "store": str(args.store), "cpus": os.cpu_count(),
              "summary_seconds": summary, "runs": runs}
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
