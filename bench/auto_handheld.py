"""``auto`` against every single method on simulated handheld captures (SNR_Y against the truth).

Run: ``python bench/auto_handheld.py [--shading ggx|mismatched] [--out bench/results]``. The three
scenes of ``ltm bench`` at three path densities (K/M about 0.17-0.42 on the 32 x 32 lattice); on
each, 256 pixels (spread over the whole image) are reconstructed as ``ltm reconstruct`` does one
tile: ``auto`` (the method by held-out cells, :func:`ltmstore.solve.select.choose_method`, then
its regularisation) beside every single method with its regularisation chosen the same way:
``physical`` (the near-light reflectance model), ``lars`` (the paper's solver), ``cs``,
``cubic``, ``hsh`` (order 2 and 3), ``ptm``, ``rbf`` and ``kernel``.

``--shading mismatched`` renders with :data:`ltmstore.synthetic.render.MISMATCHED` (Beckmann
lobe, cos^2 LED, ambient floor, clear coat), physics that ``physical`` does not assume; ``ggx``
is the renderer's own model. Writes ``auto_handheld[_mismatched].json`` and ``.png`` (SNR_Y
against K/M per scene and the mean over scenes, the paper's Fig. 10) and prints Markdown tables;
the truth is only used to score.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ltmstore.judge.benchmark import SCENES, make_cases
from ltmstore.judge.evaluate import snr_db
from ltmstore.solve import Geometry, get_method
from ltmstore.solve.select import choose_method, choose_params
from ltmstore.synthetic.render import GGX, MISMATCHED

DENSITIES = (15.0, 27.0, 45.0)
SHADINGS = {"ggx": GGX, "mismatched": MISMATCHED}
SINGLE = {"physical": ("physical", {}), "lars": ("lars", {}), "cs": ("cs", {}),
          "cubic": ("cubic", {}), "hsh2": ("hsh", {"order": 2}), "hsh3": ("hsh", {"order": 3}),
          "ptm": ("ptm", {}), "rbf": ("rbf", {}), "kernel": ("kernel", {})}
PAPER = ("lars", "cubic")  # the paper's solver and its baseline: the bar of issue 15
CHART = ("auto", "physical", "lars", "cubic", "cs", "rbf")


def as_reconstruct(batch: np.ndarray, geometry: Geometry, method: str, params: dict):
    """One tile as ``ltm reconstruct`` solves it (``auto``: the method first), and its label."""
    label = method
    if method == "auto":
        picked = choose_method(batch, geometry)
        label, method, params = picked.label, picked.method, picked.params
    choice = choose_params(batch, geometry, method, params=params)
    return get_method(method)(batch, geometry, **choice.params), label


def measure(scene: str, density: float, shading: str, pixels: int) -> dict:
    """SNR_Y and seconds of ``auto`` and every single method on one simulated capture."""
    (case,) = make_cases(scene, density, (32,), size=32, seed=0, shading=SHADINGS[shading])
    rows = np.sort(np.random.default_rng(0).choice(len(case.samples), pixels, replace=False))
    batch, truth, geometry = case.samples[rows], case.truth[rows], case.geometry.take(rows)
    row = {"scene": scene, "path_density": density, "K/M": case.ratio, "seconds": {}}
    for name, (method, params) in {"auto": ("auto", {}), **SINGLE}.items():
        start = time.perf_counter()
        estimate, label = as_reconstruct(batch, geometry, method, params)
        row["seconds"][name] = time.perf_counter() - start
        row[name] = snr_db(truth, estimate)
        row["auto_chose"] = label if name == "auto" else row["auto_chose"]
    best = max(SINGLE, key=lambda m: row[m])
    row["best_single"], row["auto_minus_best_db"] = best, row["auto"] - row[best]
    row["best_paper"] = max(PAPER, key=lambda m: row[m])
    return row


def by_density(rows: list[dict]) -> list[dict]:
    """Mean over scenes at each density: K/M, every method, and ``auto`` minus the best of
    :data:`PAPER` (the better of the two means)."""
    out = []
    for density in DENSITIES:
        group = [r for r in rows if r["path_density"] == density]
        mean = {m: float(np.mean([r[m] for r in group])) for m in ("auto", *SINGLE)}
        paper = max(PAPER, key=mean.get)
        out.append({"path_density": density, "K/M": float(np.mean([r["K/M"] for r in group])),
                    **mean, "best_paper": paper, "auto_minus_paper_db": mean["auto"] - mean[paper]})
    return out


def chart(rows: list[dict], means: list[dict], path: Path, title: str) -> None:
    """SNR_Y against K/M, one panel per scene and one for the mean (the paper's Fig. 10)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(scene, [r for r in rows if r["scene"] == scene]) for scene in SCENES]
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(16, 4), sharey=True)
    for ax, (name, group) in zip(axes, [*panels, ("mean over scenes", means)], strict=True):
        for method in CHART:
            ax.plot([r["K/M"] for r in group], [r[method] for r in group], marker="o",
                    lw=2.5 if method == "auto" else 1.2, label=method)
        ax.set(title=name, xlabel="K/M (observed cells / cells)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("SNR_Y (dB)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    parser.add_argument("--pixels", default=256, type=int)
    parser.add_argument("--shading", default="mismatched", choices=sorted(SHADINGS))
    args = parser.parse_args()
    with threadpool_limits(1):
        rows = []
        for scene in SCENES:
            for density in DENSITIES:
                rows.append(measure(scene, density, args.shading, args.pixels))
                print(json.dumps(rows[-1]), flush=True)
    means = by_density(rows)
    stem = "auto_handheld" + ("" if args.shading == "ggx" else f"_{args.shading}")
    args.out.mkdir(parents=True, exist_ok=True)
    command = f"python bench/auto_handheld.py --shading {args.shading}"
    (args.out / f"{stem}.json").write_text(json.dumps(
        {"command": command, "shading": args.shading,
         "machine": {"platform": platform.platform(), "python": platform.python_version(),
                     "threads": 1},
         "rows": rows, "mean_over_scenes": means}, indent=1))
    chart(rows, means, args.out / f"{stem}.png",
          f"Handheld paths, {args.pixels} pixels per scene, {args.shading} shading")
    print("| scene | density | K/M | auto (chose) | physical | lars | cubic | best single "
          "| auto - best |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['scene']} | {r['path_density']:g} | {r['K/M']:.2f} | {r['auto']:.2f} "
              f"({r['auto_chose']}) | {r['physical']:.2f} | {r['lars']:.2f} | {r['cubic']:.2f} "
              f"| {r[r['best_single']]:.2f} ({r['best_single']}) | "
              f"{r['auto_minus_best_db']:+.2f} |")
    print("\n| K/M (mean) | auto | physical | lars | cubic | cs | rbf | auto - best of lars, "
          "cubic |\n| --- | --- | --- | --- | --- | --- | --- | --- |")
    for m in means:
        print(f"| {m['K/M']:.2f} | " + " | ".join(f"{m[k]:.2f}" for k in CHART)
              + f" | {m['auto_minus_paper_db']:+.2f} |")


if __name__ == "__main__":
    main()
