"""Object placement from the data: the default without ``object`` against the default with it.

Run: ``python bench/placement_bench.py [--size 64] [--scenes canvas relief] [--densities 14 38]
[--classic] [--work DIR] [--out bench/results]`` (K/M 0.17 and 0.40; the results in
``bench/results`` were made with ``--classic``: 17 minutes on 2 busy cores).

For every scene and path density one ``ltm simulate`` capture (seed 0, the 32 x 32 truth
lattice) is ingested twice: as written (the true extent declared in ``acquisition.json``) and
with the ``object`` field removed. Both are reconstructed by the default (``auto``, near light)
on the truth's 32 x 32 lattice and scored against ``truth.zarr`` (SNR_Y over the whole LTM).
Without the field the reconstruct stage estimates the extent from the samples
(:mod:`ltmstore.stages.placement`); its error against the true extent is reported per edge in
plane units and pixels, beside the estimate's own uncertainty. ``--classic`` adds the default
as it was before the estimate (no extent: the classic methods only). Writes ``placement.json``
and ``placement.png`` under ``--out``; prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

CHART_VARIANTS = ("declared", "estimated", "classic")


def capture(work: Path, scene: str, density: float, size: int) -> tuple[Path, Path, dict]:
    """A simulated capture, and a copy of it without the ``object`` field."""
    from ltmstore.synthetic.simulate import simulate_acquisition

    folder = work / f"{scene}_{density:g}"
    info = simulate_acquisition(folder, scene=scene, size=size, seed=0, path_density=density,
                                progress=False, overwrite=True)
    bare = work / f"{scene}_{density:g}_noobject"
    shutil.rmtree(bare, ignore_errors=True)
    shutil.copytree(folder, bare, ignore=shutil.ignore_patterns("truth.zarr"))
    meta = json.loads((bare / "acquisition.json").read_text())
    truth_extent = meta.pop("object")
    (bare / "acquisition.json").write_text(json.dumps(meta, indent=1))
    return folder, bare, {"info": info, "object": truth_extent}


def run(folder: Path, store: Path, client, *, classic: bool = False) -> dict:
    """Ingest and reconstruct (default method, 32 x 32) one capture; its stage record."""
    import ltmstore.stages.placement as placement
    from ltmstore.stages.ingest import ingest
    from ltmstore.stages.reconstruct import reconstruct

    ingest(folder, store, progress=False, overwrite=True)
    original = placement.place_object
    if classic:  # the default as it was: no extent declared, none estimated
        placement.place_object = lambda *a, **k: (None, {"source": "none", "extent": None})
    try:
        start = time.perf_counter()
        info = reconstruct(store, client=client, lattice=(32, 32), progress=False)
        info["wall_s"] = time.perf_counter() - start
    finally:
        placement.place_object = original
    return info


def edge_errors(estimate: dict, truth: dict, pitch: float) -> dict:
    """Per-edge error (left, right, bottom, top) in plane units and pixels, and the largest."""
    est = np.array(estimate["x"] + estimate["y"])
    err = est - np.array(truth["x"] + truth["y"])
    return {"edges_plane": err.tolist(), "edges_px": (err / pitch).tolist(),
            "max_plane": float(np.abs(err).max()), "max_px": float(np.abs(err).max() / pitch),
            "width_ratio": float((est[1] - est[0]) / (truth["x"][1] - truth["x"][0]))}


def measure(work: Path, scene: str, density: float, size: int, client, classic: bool) -> dict:
    """SNR_Y of the default with the true extent, with the estimated one (and the classic
    fallback), and the estimate's error."""
    from ltmstore.judge.evaluate import compare_stores

    folder, bare, meta = capture(work, scene, density, size)
    truth = folder / "truth.zarr"
    row = {"scene": scene, "path_density": density, "size": size,
           "K/M": meta["info"]["sampling_ratio"], "snr_y_db": {}, "methods": {}, "seconds": {}}
    variants = {"declared": (folder, False), "estimated": (bare, False)}
    if classic:
        variants["classic"] = (bare, True)
    for name, (source, old) in variants.items():
        store = work / f"{scene}_{density:g}_{name}.zarr"
        info = run(source, store, client, classic=old)
        row["snr_y_db"][name] = compare_stores(store, truth)["snr_y_db"]
        row["methods"][name] = info["methods_per_tile"]
        row["seconds"][name] = {"placement_s": info["timings"].get("placement_s"),
                                "solve_s": info["timings"]["solve_s"], "wall_s": info["wall_s"]}
        if name == "estimated":
            placed = info["placement"]
            pitch = (meta["object"]["x"][1] - meta["object"]["x"][0]) / size
            row["placement"] = {"source": placed["source"], "estimate": placed["estimate"],
                                "truth": meta["object"],
                                **edge_errors(placed["estimate"]["extent"], meta["object"],
                                              pitch)}
        if name == "declared":
            row["declared_check"] = info["placement"].get("disagreement")
        shutil.rmtree(store, ignore_errors=True)
    row["estimated_minus_declared_db"] = row["snr_y_db"]["estimated"] - row["snr_y_db"]["declared"]
    return row


def chart(rows: list[dict], path: Path) -> None:
    """SNR_Y per capture and variant, and the estimate's largest edge error in pixels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['scene']}\nK/M {r['K/M']:.2f}" for r in rows]
    x = np.arange(len(rows))
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.2))
    variants = [v for v in CHART_VARIANTS if v in rows[0]["snr_y_db"]]
    for i, name in enumerate(variants):
        ax.bar(x + (i - (len(variants) - 1) / 2) * 0.25, [r["snr_y_db"][name] for r in rows],
               0.25, label={"declared": "object declared (true extent)",
                            "estimated": "object estimated from the capture",
                            "classic": "no object (before: classic methods)"}[name])
    ax.set(xticks=x, xticklabels=labels, ylabel="SNR_Y (dB)", title="Default reconstruction")
    ax.set_ylim(bottom=min(min(r["snr_y_db"].values()) for r in rows) - 3)
    ax.legend(fontsize=8)
    for i, (label, get) in enumerate([
            ("largest edge error", lambda r: r["placement"]["max_px"]),
            ("bootstrap sigma", lambda r: r["placement"]["estimate"]["sigma_pixels"]),
            ("uncertainty (with the systematic term)",
             lambda r: r["placement"]["estimate"]["uncertainty_pixels"])]):
        bx.bar(x + (i - 1) * 0.27, [get(r) for r in rows], 0.27, label=label)
    bx.set(xticks=x, xticklabels=labels, ylabel="pixels", title="Estimated extent")
    bx.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--work", default=None, type=Path, help="scratch folder (default: temp)")
    parser.add_argument("--size", default=64, type=int)
    parser.add_argument("--scenes", nargs="+", default=["canvas", "relief"])
    parser.add_argument("--densities", nargs="+", type=float, default=[14.0, 38.0])
    parser.add_argument("--classic", action="store_true")
    args = parser.parse_args()
    from distributed import Client, LocalCluster

    from ltmstore.core.cluster import WORKER_ENV

    work = args.work or Path(tempfile.mkdtemp(prefix="ltm-placement-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    start = time.perf_counter()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address="127.0.0.1:0", env=WORKER_ENV) as cluster, \
            Client(cluster) as client:
        for scene in args.scenes:
            for density in args.densities:
                rows.append(measure(work, scene, density, args.size, client, args.classic))
                print(json.dumps(rows[-1]), flush=True)
    command = ("python bench/placement_bench.py --size {} --scenes {} --densities {}{}".format(
        args.size, " ".join(args.scenes), " ".join(f"{d:g}" for d in args.densities),
        " --classic" if args.classic else ""))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "placement.json").write_text(json.dumps(
        {"command": command, "seconds": time.perf_counter() - start,
         "machine": {"platform": platform.platform(), "python": platform.python_version()},
         "rows": rows}, indent=1))
    chart(rows, args.out / "placement.png")
    print("| scene | K/M | declared | estimated | est. - decl. | classic | largest edge error "
          "| bootstrap sigma | uncertainty | placement / solve |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        p, snr, sec = r["placement"], r["snr_y_db"], r["seconds"]["estimated"]
        classic = f"{snr['classic']:.2f}" if "classic" in snr else "-"
        print(f"| {r['scene']} | {r['K/M']:.2f} | {snr['declared']:.2f} | {snr['estimated']:.2f} "
              f"| {r['estimated_minus_declared_db']:+.2f} | {classic} | "
              f"{p['max_plane'] * 1000:.1f} mm ({p['max_px']:.2f} px) | "
              f"{p['estimate']['sigma_max'] * 1000:.2f} mm ({p['estimate']['sigma_pixels']:.2f} px)"
              f" | {max(p['estimate']['uncertainty']) * 1000:.1f} mm "
              f"({p['estimate']['uncertainty_pixels']:.2f} px) | "
              f"{sec['placement_s']:.2f} s / {sec['solve_s']:.1f} s |")


if __name__ == "__main__":
    main()
