"""Two extensions of the far-light surface model that did not become the default, measured.

Run: ``python bench/heldout_variants.py [--data ../shared/data] [--out bench/results]
[CAPTURE ...]``.

For each capture (the splits of ``bench/heldout_photos.py``: every 6th light hidden on the real
captures, ``dome/`` against ``test/`` on SynthRTI), the held-out PSNR of 8-bit sRGB images of:

* ``classic``: the pipeline's classic model (PTM, HSH or RBF chosen by leave-one-out);
* ``raw W`` / ``exposure W``: the surface model plus its smoothed residual
  (:mod:`ltmstore.stages.surface`, the default where it wins), mixed with ``classic`` at weight
  ``W`` (``W (surface) + (1 - W) classic``), fitted to the photographs as they are or divided
  by each one's exposure (its luminance over what the others predict there, leave-one-out: a
  hand-held flash does not fire with the same energy twice);
* ``oracle``: ``raw 1`` with each relit image scaled by the gain that best matches its hidden
  photograph: what is left when the held-out photographs' own exposure is known.

Beside each, the held-out MSE over the training lights (luminance, 4096 pixels, relative to
``classic``) by two protocols: ``every_4th`` light in turn (what ``auto`` chooses by,
:func:`ltmstore.stages.surface.cross_validated`), and on a dome (lights on at least four rings of
elevation) alternate ``rings``, closer to SynthRTI's test lights between the rings. The variant
each protocol's rule would choose (:func:`ltmstore.stages.surface.choose_surface`) is recorded
with its test PSNR: whether a choice carries over to the test lights is the question. Writes
``heldout_variants.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np

from ltmstore.core.dims import LUMA
from ltmstore.core.transfer import linear_to_srgb, srgb_to_linear
from ltmstore.judge.photos import load_photos, score
from ltmstore.solve.lightfit import Model, choose
from ltmstore.stages import surface as sf

REAL = ("loewenkopf", "realrti-item9-coin", "realrti-item3-icon")
WEIGHTS = sf.WEIGHTS
FOLDS = sf.FOLDS
RING_GAP = 3.0  # degrees of elevation: a larger gap between sorted lights starts a new ring


def split(data: Path, name: str):
    """Training directions and 8-bit photographs, test directions and photographs."""
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
    """Every variant's sRGB-encoded images at ``query`` from linear ``rgb (n, p, 3)``."""
    out = {}
    for kind in ("raw", "exposure"):
        x = rgb / sf.exposures(rgb, train)[:, None, None] if kind == "exposure" else rgb
        _, theta, smoother = sf.fitted(x, train)
        values = linear_to_srgb((x if color else x @ LUMA).astype(np.float32))
        ours = (np.tensordot(smoother.weights(train, query), values, axes=1)
                + sf.correction(theta, train, query, smoother, color=color))
        theirs = np.tensordot(classic.weights(train, query), values, axes=1)
        out.update({f"{kind} {w:g}": w * ours + (1 - w) * theirs for w in WEIGHTS})
    out["classic"] = np.tensordot(classic.weights(train, query), linear_to_srgb(
        (rgb if color else rgb @ LUMA).astype(np.float32)), axes=1)
    return out


def heldout_mse(rgb: np.ndarray, train: np.ndarray, classic: Model,
                folds: list[np.ndarray]) -> dict[str, float]:
    """Held-out MSE of every variant (encoded luminance) over ``folds`` (the lights held out in
    turn), relative to ``classic``."""
    truth = linear_to_srgb((rgb @ LUMA).astype(np.float32))
    total: dict[str, float] = {}
    for test in folds:
        fit = np.setdiff1d(np.arange(len(train)), test)
        for key, value in predictions(rgb[fit], train[fit], train[test], classic,
                                      color=False).items():
            total[key] = total.get(key, 0.0) + float(np.sum((value - truth[test]) ** 2))
    return {key: value / total["classic"] for key, value in total.items()}


def measure(data: Path, name: str) -> dict:
    train, photos, query, truth = split(data, name)
    rgb = srgb_to_linear(photos.astype(np.float32) / 255).reshape(len(photos), -1, 3)
    classic, _ = choose(linear_to_srgb((rgb @ LUMA).astype(np.float32))[:, ::max(
        1, rgb.shape[1] // 20000)], train)
    sample = np.sort(np.random.default_rng(0).permutation(rgb.shape[1])[:4096])
    every = [np.arange(fold, len(train), FOLDS) for fold in range(FOLDS)]
    cv = {"every_4th": heldout_mse(rgb[:, sample], train, classic, every)}
    rings = ring_folds(train)
    if rings is not None:
        cv["rings"] = heldout_mse(rgb[:, sample], train, classic, rings)
    images = {key: srgb_to_linear(value.clip(0, 1)).reshape(truth.shape)
              for key, value in predictions(rgb, train, query, classic, color=True).items()}
    raw = images["raw 1"]
    gain = [float((r * srgb_to_linear(t / 255)).sum() / (r * r).sum())
            for r, t in zip(raw, truth, strict=True)]
    images["oracle"] = raw * np.array(gain, dtype=np.float32)[:, None, None, None]
    psnr = {key: float(np.mean([score(x, t)[0] for x, t in zip(value, truth, strict=True)]))
            for key, value in images.items()}
    return {"classic": classic.name, "test_psnr": psnr, "heldout_mse_vs_classic": cv,
            "chosen": {protocol: chosen(scores) for protocol, scores in cv.items()},
            "exposure_spread": float(np.std(sf.exposures(rgb, train)))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("captures", nargs="*", help="default: every capture of --data")
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    args = parser.parse_args()
    results = {}
    scenes = sorted(f"synthrti/{d.name}" for d in (args.data / "synthrti").glob("*/"))
    for name in args.captures or [*REAL, *scenes]:
        r = results[name] = measure(args.data, name)
        p = r["test_psnr"]
        best = max((k for k in p if k != "oracle"), key=p.get)
        picks = "  ".join(f"{protocol} chooses {k} {p[k]:.2f}" for protocol, k in
                          r["chosen"].items())
        print(f"{name}: classic {p['classic']:.2f}  raw 1 {p['raw 1']:.2f}  "
              f"exposure 1 {p['exposure 1']:.2f}  {picks}  best {best} {p[best]:.2f}  "
              f"oracle {p['oracle']:.2f}  exposure spread {r['exposure_spread']:.3f}",
              flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    report = {"machine": {"platform": platform.platform(), "python": platform.python_version()},
              "command": "python bench/heldout_variants.py", "results": results}
    (args.out / "heldout_variants.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
