"""CPU cost of the parts of one handheld tile's solve, one thread, on a reconstructed store.

Runs what a tile task of ``ltm reconstruct`` runs (the choice between the image's finalists, the
residual weight, the surface fit, the expected-error fold) on a few tiles of the store's
``samples``, twice, and prints the medians of the second pass (the first loads the compiled
kernels and builds the cached RBF operator, as a worker's first tile does). Results are printed,
not written: it is the profiler's companion, for comparing two versions of the code on one store.

Run: ``OMP_NUM_THREADS=1 python bench/tile_cost.py STORE`` (a store after ``ltm reconstruct``
of a near-light capture, e.g. ``W/store.zarr`` of ``python bench/scale_bench.py --config toys
--work W``); the old code with ``PYTHONPATH`` on its ``git archive``. Glibc's allocator settings
matter: ``MALLOC_TRIM_THRESHOLD_=65536`` in the environment (what a Dask nanny sets) shows what a
worker under it pays.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from ltmstore.core import store as st
from ltmstore.core.dims import Lattice, object_pixels
from ltmstore.solve import Geometry, physical
from ltmstore.solve.confidence import expected_error
from ltmstore.solve.select import choose_params
from ltmstore.stages.plan import plan_tiles
from ltmstore.stages.reconstruct import choose_for_image

TILES = ((6, 6), (3, 9), (1, 2), (9, 4), (5, 5), (10, 10))


def tile_parts(batch: np.ndarray, geometry: Geometry, chosen, seed: int) -> list[tuple]:
    """Seconds of each part of one tile's solve, as ``_solve_tile`` runs them."""
    clock = [time.perf_counter()]

    def lap(name: str) -> tuple[str, float]:
        clock.append(time.perf_counter())
        return name, clock[-1] - clock[-2]

    _, method, params, _ = chosen.pick(batch, geometry, seed=seed)
    parts = [lap("pick")]
    choice = choose_params(batch, geometry, method, params=params, seed=seed)
    parts.append(lap("choose_params"))
    _, surface = physical.solve_surface(batch, geometry, **choice.params)
    parts.append(lap("solve_surface"))
    expected_error(batch, geometry, method, params=choice.params, folds=1,
                   per_pixel={"start": physical.parameters(surface)})
    return [*parts, lap("expected_error")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("--tile", type=int, default=32)
    args = parser.parse_args()
    group = st.open_group(args.store, mode="r")
    record = group.attrs["stages"]["reconstruct"]
    lattice = Lattice(bounds=tuple(map(tuple, record["lattice"]["bounds"])),
                      shape=tuple(record["lattice"]["shape"]))
    placement = record["placement"]
    extent = placement.get("estimate", placement)["extent"]
    geometry = Geometry(lattice=lattice, height=group.attrs["acquisition"]["plane"]["height"])
    samples = group["samples"]
    image = samples.shape[:2]
    plan = plan_tiles(image, lattice.shape, tile=args.tile)
    chosen = choose_for_image(samples, plan, geometry, extent)
    times: dict[str, list[float]] = {}
    for _ in range(2):
        times.clear()
        for ty, tx in TILES:
            rows, cols = (slice(t * args.tile, (t + 1) * args.tile) for t in (ty, tx))
            batch = np.asarray(samples[rows, cols]).reshape(-1, *lattice.shape)
            geo = geometry.with_pixels(object_pixels(extent, image, rows, cols))
            for name, seconds in tile_parts(batch, geo, chosen, rows.start * 65536 + cols.start):
                times.setdefault(name, []).append(seconds)
    medians = {k: round(statistics.median(v), 4) for k, v in times.items()}
    print(json.dumps({"store": args.store, "tiles": len(TILES), "seconds_median": medians,
                      "total_s": round(sum(medians.values()), 3)}))


if __name__ == "__main__":
    main()
