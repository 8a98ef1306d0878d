"""Normal maps of near-light (handheld) captures against the simulated scenes' true normals.

Run: ``python bench/near_normals.py [--size 96] [--out bench/results]``. Each scene is simulated
(GGX, the renderer's own physics: the model's family, so this checks the pipeline more than the
model), ingested and reconstructed with the default ``auto``; the ``normal`` map of the tiles
that chose ``physical`` is compared with ``Scene.normals()``. A constant normal ``(0, 0, 1)`` is
the baseline. Writes ``near_normals.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
from pathlib import Path

import numpy as np

from ltmstore.core.store import open_store
from ltmstore.stages.ingest import ingest
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.synthetic.scenes import SCENES, make_scene
from ltmstore.synthetic.simulate import simulate_acquisition


def angles(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Angles (degrees) between unit normals ``(n, 3)``; NaN where no estimate."""
    return np.degrees(np.arccos(np.clip((estimate * truth).sum(axis=1), -1, 1)))


def scene_row(work: Path, scene: str, size: int) -> dict:
    simulate_acquisition(work / scene, scene=scene, size=size, seed=0, truth=False,
                         progress=False)
    store = work / f"{scene}.zarr"
    ingest(work / scene, store, progress=False)
    reconstruct(store, progress=False)
    ds = open_store(store)
    truth = np.moveaxis(make_scene(scene, size=size, seed=0).normals(), 0, -1).reshape(-1, 3)
    error = angles(ds["normal"].values.reshape(-1, 3), truth)
    flat = np.degrees(np.arccos(truth[:, 2]))
    return {"scene": scene, "size": size,
            "methods_per_tile": ds.attrs["stages"]["reconstruct"]["methods_per_tile"],
            "mapped_fraction": float(np.isfinite(error).mean()),
            "mean_deg": float(np.nanmean(error)), "median_deg": float(np.nanmedian(error)),
            "p95_deg": float(np.nanpercentile(error, 95)), "flat_mean_deg": float(flat.mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [scene_row(Path(tmp), scene, args.size) for scene in sorted(SCENES)]
    for r in rows:
        print(f"{r['scene']:7s} mean {r['mean_deg']:.2f} median {r['median_deg']:.2f} "
              f"p95 {r['p95_deg']:.2f} deg (constant normal {r['flat_mean_deg']:.2f}); "
              f"{r['methods_per_tile']}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "near_normals.json").write_text(json.dumps({
        "command": f"python bench/near_normals.py --size {args.size}",
        "machine": {"platform": platform.platform()}, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
