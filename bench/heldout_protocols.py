"""Can a better held-out protocol make ``auto`` choose the far-light surface only where it pays?

Run: ``python bench/heldout_protocols.py [--data ../shared/data] [--cache DIR] [--table
bench/results/heldout_table.json] [--out bench/results] [NAME ...]`` (names as in
``bench/heldout_table.py``; default: every capture and render of that table).

``auto`` decides between the image's classic fit and the surface variants (the surface model
plus its residual, raw or exposure-corrected, mixed with the classic fit at
:data:`ltmstore.stages.surface.WEIGHTS`) by their held-out error at the capture's own lights
(:func:`ltmstore.stages.surface.cross_validated`). On 7 of the held-out table's 49 captures (all
renders of a Beckmann or mismatched shading, before the Beckmann lobe) the variant it takes was
0.36-2.85 dB below the best classic fit at the test lights. This bench asks whether another
protocol or criterion would have chosen better. For each capture it records every variant's
PSNR at the test lights and each training light's held-out squared error (luminance, 4096
pixels) by three protocols:

* ``every_4th``: every 4th light in turn (what ``auto`` does);
* ``rings``: alternate rings of a dome (:func:`ring_folds`; domes only);
* ``buffered``: every 8th light in turn, its two nearest lights left out of the fit too (a gap
  like that between a dome's rings, for any layout of lights);

scored by three criteria: the summed error (``auto``'s), the mean of each light's log error (the
table's mean PSNR is a mean of logs) and the summed error with each third of the lights'
elevation range weighted equally. ``choose_surface``'s rule then picks a variant from each; the
gap of its test PSNR to the table's best classic fit is the result, beside the ``oracle`` (the
variant best at the test lights). The variants are those of the GGX lobe. Writes
``heldout_protocols.json`` (per capture: test PSNR and each rule's choice; the per-light errors
stay in ``--cache``) and
``heldout_protocols.png`` (mean and worst gap and count below -0.2 dB per rule).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from heldout_table import captures, render

from ltmstore.core.dims import LUMA
from ltmstore.core.transfer import linear_to_srgb, srgb_to_linear
from ltmstore.judge.photos import load_photos, score
from ltmstore.solve.lightfit import Model, choose
from ltmstore.stages import surface as sf

SAMPLE = 4096  # pixels scored at the training lights (as auto's choice)
BANDS = 3  # equal parts of the training lights' elevation range (criterion "bands")
RING_GAP = 3.0  # degrees of elevation: a larger gap between sorted lights starts a new ring


def split(data: Path, name: str):
    """Training directions and 8-bit photographs, test directions and photographs: every 6th
    light hidden on a real capture, ``dome/`` against ``test/`` on SynthRTI."""
    if name.startswith("synthrti/"):
        return (*load_photos(data / name / "dome" / "dirs.lp"),
                *load_photos(data / name / "test" / "dirs.lp"))
    directions, photos = load_photos(data / name / "dirs.lp")
    hidden = np.arange(len(directions)) % 6 == 5
    return directions[~hidden], photos[~hidden], directions[hidden], photos[hidden]


def ring_folds(train: np.ndarray) -> list[np.ndarray] | None:
    """Alternate rings of a dome (at least four rings, each narrower than the narrowest gap
    between them), or None."""
    elevation = np.degrees(np.arcsin(np.clip(train[:, 2], -1, 1)))
    order = np.argsort(elevation)
    gaps = np.diff(elevation[order])
    ring = np.empty(len(train), dtype=int)
    ring[order] = np.concatenate([[0], np.cumsum(gaps > RING_GAP)])
    widths = [np.ptp(elevation[ring == r]) for r in range(ring.max() + 1)]
    if ring.max() < 3 or max(widths) >= gaps[gaps > RING_GAP].min():
        return None
    return [np.flatnonzero(ring % 2 == parity) for parity in (0, 1)]


def chosen(cv: dict[str, float]) -> str:
    """The variant :func:`ltmstore.stages.surface.choose_surface` takes by these scores."""
    keys = {k: (k.startswith("exposure"), float(k.split()[1])) for k in cv if k != "classic"}
    choice = sf.choose_surface({None: cv["classic"], **{keys[k]: cv[k] for k in keys}})
    return "classic" if choice is None else next(k for k, v in keys.items() if v == choice)


def predictions(rgb: np.ndarray, train: np.ndarray, query: np.ndarray, classic: Model, *,
                color: bool) -> dict[str, np.ndarray]:
    """Every variant's sRGB-encoded images at ``query`` from linear ``rgb (n, p, 3)``: the
    classic fit, and the surface model plus its smoothed residual fitted to the photographs as
    they are (``raw W``) or divided by each one's exposure (``exposure W``), mixed with the
    classic fit at weight ``W``."""
    out = {}
    for kind in ("raw", "exposure"):
        x = rgb / sf.exposures(rgb, train)[:, None, None] if kind == "exposure" else rgb
        _, theta, smoother = sf.fitted(x, train)
        values = linear_to_srgb((x if color else x @ LUMA).astype(np.float32))
        ours = (np.tensordot(smoother.weights(train, query), values, axes=1)
                + sf.correction(theta, train, query, smoother, color=color))
        theirs = np.tensordot(classic.weights(train, query), values, axes=1)
        out.update({f"{kind} {w:g}": w * ours + (1 - w) * theirs for w in sf.WEIGHTS})
    out["classic"] = np.tensordot(classic.weights(train, query), linear_to_srgb(
        (rgb if color else rgb @ LUMA).astype(np.float32)), axes=1)
    return out


def buffered_folds(train: np.ndarray, every: int = 8, neighbours: int = 2
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(scored, left out of the fit): every ``every``-th light in turn, with its
    ``neighbours`` nearest lights also left out."""
    order = np.argsort(-(train @ train.T), axis=1)[:, 1:1 + neighbours]
    return [(test := np.arange(fold, len(train), every), np.union1d(test, order[test].ravel()))
            for fold in range(every)]


def per_light_errors(rgb: np.ndarray, train: np.ndarray, classic: Model,
                     folds: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each variant's squared error (encoded luminance, summed over pixels) at each training
    light, predicted by the fit that left it out."""
    truth = linear_to_srgb((rgb @ LUMA).astype(np.float32))
    errors: dict[str, np.ndarray] = {}
    for test, out in folds:
        fit = np.setdiff1d(np.arange(len(train)), out)
        for key, value in predictions(rgb[fit], train[fit], train[test], classic,
                                      color=False).items():
            errors.setdefault(key, np.full(len(train), np.nan))[test] = np.sum(
                (value - truth[test]) ** 2, axis=1)
    return errors


def elevation(directions: np.ndarray) -> np.ndarray:
    """Degrees above the horizon."""
    return np.degrees(np.arcsin(np.clip(directions[:, 2], -1, 1)))


def criteria(errors: dict[str, np.ndarray], train: np.ndarray) -> dict[str, dict[str, float]]:
    """Each variant's score relative to ``classic`` (1) by each criterion, over the lights
    that were scored."""
    scored = np.isfinite(errors["classic"])
    e = elevation(train)[scored]
    edges = np.linspace(e.min(), e.max() + 1e-9, BANDS + 1)
    band = np.clip(np.searchsorted(edges, e, side="right") - 1, 0, BANDS - 1)
    weight = 1 / np.bincount(band, minlength=BANDS)[band]
    out: dict[str, dict[str, float]] = {"sum": {}, "log": {}, "bands": {}}
    for key, value in errors.items():
        v, c = value[scored], errors["classic"][scored]
        out["sum"][key] = float(v.sum() / c.sum())
        out["log"][key] = float(np.exp(np.mean(np.log(v + 1e-12) - np.log(c + 1e-12))))
        out["bands"][key] = float((weight * v).sum() / (weight * c).sum())
    return out


def measure(name: str, lp: Path, kwargs: dict, data: Path) -> dict:
    """Test PSNR of every variant, per-light held-out errors and each rule's choice."""
    if name.startswith("render/"):
        render(lp.parents[1], name.split("/", 1)[1])
        train, photos = load_photos(lp)
        query, truth = load_photos(kwargs["test_lp"])
    else:
        train, photos, query, truth = split(data, name)
    rgb = srgb_to_linear(photos.astype(np.float32) / 255).reshape(len(photos), -1, 3)
    encoded = linear_to_srgb((rgb @ LUMA).astype(np.float32))
    classic, _ = choose(encoded[:, ::max(1, rgb.shape[1] // 20000)], train)
    sample = np.sort(np.random.default_rng(0).permutation(rgb.shape[1])[:SAMPLE])
    folds = {"every_4th": [(t, t) for t in (np.arange(f, len(train), sf.FOLDS)
                                            for f in range(sf.FOLDS))],
             "buffered": buffered_folds(train)}
    if (rings := ring_folds(train)) is not None:
        folds["rings"] = [(t, t) for t in rings]
    errors = {p: per_light_errors(rgb[:, sample], train, classic, f) for p, f in folds.items()}
    images = predictions(rgb, train, query, classic, color=True)
    psnr = {key: float(np.mean([score(srgb_to_linear(x.clip(0, 1)).reshape(t.shape), t)[0]
                                for x, t in zip(value, truth, strict=True)]))
            for key, value in images.items()}
    choices = {f"{p}/{c}": chosen(s) for p, e in errors.items()
               for c, s in criteria(e, train).items()}
    return {"classic": classic.name, "test_psnr": psnr, "choices": choices,
            "train": train.round(5).tolist(),
            "errors": {p: {k: v.tolist() for k, v in e.items()} for p, e in errors.items()}}


def gaps(results: dict[str, dict], table: dict[str, dict]) -> dict[str, dict[str, float]]:
    """Per rule (and ``auto`` as the table has it, and the ``oracle``: the best variant at the
    test lights): test PSNR minus the best classic fit's, per capture."""
    out: dict[str, dict[str, float]] = {}
    for name, r in results.items():
        methods = table[name]["methods"]
        best = max(m["mean_psnr"] for key, m in methods.items() if key != "default")
        rows = {"auto (table)": methods["default"]["mean_psnr"],
                "oracle": max(r["test_psnr"].values())}
        rules = {rule: r["test_psnr"][variant] for rule, variant in r["choices"].items()}
        # a dome without rings has no ring protocol: it falls back to every_4th's choice
        for rule in {f"rings/{c}" for c in ("sum", "log", "bands")} - rules.keys():
            rules[rule] = rules["every_4th/" + rule.split("/")[1]]
        for rule, value in {**rows, **rules}.items():
            out.setdefault(rule, {})[name] = value - best
    return out


def summary(gap: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
    return {rule: {"mean_db": float(np.mean(list(v.values()))),
                   "worst_db": float(min(v.values())),
                   "below_0.2_db": int(sum(x < -0.2 for x in v.values()))}
            for rule, v in gap.items()}


def chart(stats: dict[str, dict[str, float]], path: Path, n: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rules = list(stats)
    fig, axes = plt.subplots(1, 3, figsize=(13, 0.32 * len(rules) + 1.5), sharey=True)
    for ax, (key, label) in zip(axes, (("mean_db", "mean gap (dB)"),
                                       ("worst_db", "worst gap (dB)"),
                                       ("below_0.2_db", "captures > 0.2 dB below")),
                                strict=True):
        ax.barh(rules, [stats[r][key] for r in rules], color="tab:blue")
        ax.axvline(0, color="k", lw=0.8)
        ax.set_xlabel(label)
    axes[0].invert_yaxis()
    fig.suptitle(f"Held-out PSNR at the test lights minus the best classic fit, {n} captures")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="captures (default: every one of the table)")
    parser.add_argument("--data", default=Path("../shared/data"), type=Path)
    parser.add_argument("--cache", default=Path(tempfile.gettempdir()) / "ltm-heldout-table",
                        type=Path, help="where heldout_table.py makes its renders")
    parser.add_argument("--table", default=Path("bench/results/heldout_table.json"), type=Path)
    parser.add_argument("--out", default=Path("bench/results"), type=Path)
    args = parser.parse_args()
    table = json.loads(args.table.read_text())["results"]
    found = captures(args.data, args.cache)
    names = args.names or [n for n in found if n in table]
    results_dir = args.cache / "protocols"
    results_dir.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in names:
        path = results_dir / (name.replace("/", "__") + ".json")
        if not path.is_file():
            start = time.perf_counter()
            report = measure(name, *found[name], args.data)
            report["seconds"] = time.perf_counter() - start
            path.write_text(json.dumps(report))
        results[name] = json.loads(path.read_text())
        print(name, results[name]["choices"]["every_4th/sum"], flush=True)
    gap = gaps(results, table)
    stats = summary(gap)
    for rule, s in stats.items():
        print(f"{rule:22s} mean {s['mean_db']:+.2f}  worst {s['worst_db']:+.2f}  "
              f"below -0.2: {s['below_0.2_db']}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "heldout_protocols.json").write_text(json.dumps({
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "command": "python bench/heldout_protocols.py", "summary": stats, "gap_db": gap,
        "results": {name: {k: v for k, v in r.items() if k not in ("errors", "train")}
                    for name, r in results.items()}}, indent=1))
    chart(stats, args.out / "heldout_protocols.png", len(results))


if __name__ == "__main__":
    main()
