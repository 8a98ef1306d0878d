"""Held-out photographs: the RTI literature's honest test of a relighting method on real data.

Fit on some photographs of a classic capture, relight at the lights of the others, and compare
with those photographs: PSNR ``10 log10(255^2 / MSE)`` over every pixel and all three channels of
the 8-bit sRGB images (no mask), and SSIM (:func:`skimage.metrics.structural_similarity`) of the
same images, per held-out light and averaged. Two protocols:

* ``every = k``: hide every k-th light of one ``.lp`` (lights ``k-1, 2k-1, ...``), fit on the
  rest;
* ``test_lp``: fit on every light of the capture, score at the lights of another ``.lp`` of the
  same object (SynthRTI: fit on ``dome/``, score on ``test/``).

Scored side by side on the same lights: ``default`` (the project's pipeline: ``ingest_rti`` of
the training lights, ``reconstruct`` with its defaults, ``relight`` at the held-out directions)
and the classic fits done here on the same training photographs, per RGB channel on the
sRGB-encoded values (as the RTI world's fitters do), at the exact light directions: ``ptm``,
``hsh2``, ``hsh3``, ``rbf`` (Gaussian width and smoothing chosen by leave-one-out over the
whole image, :mod:`ltmstore.solve.lightfit`) and ``hsh3+rbf`` (HSH order 3 plus an RBF of its
residual, the RBF chosen the same way).
"""

from __future__ import annotations

import os
import tempfile
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from ltmstore.capture.lp import LpWarning, hidden_lights, read_lp
from ltmstore.capture.photographs import decode_image, image_orientation, warn_orientations
from ltmstore.core.dims import LUMA
from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import encode, srgb_to_linear
from ltmstore.solve.lightfit import HSH_RBF, Model, choose, hsh_rbf_models, rbf_models, relit
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.stages.relight import relight

CLASSIC = ("ptm", "hsh2", "hsh3", "rbf", HSH_RBF)
METHODS = ("default", *CLASSIC)
RBF_CHOICE_PIXELS = 20000  # pixels whose leave-one-out error picks the RBF width and smoothing


def load_photos(lp: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The light directions ``(n, 3)`` and 8-bit sRGB photographs ``(n, H, W, 3)`` of an
    ``.lp`` capture (16-bit images are rounded to 8 bits, as scored)."""
    lp = Path(lp)
    names, directions = read_lp(lp)
    images, tagged = [], {}
    for name in names:
        data = (lp.parent / name).read_bytes()
        images.append(decode_image(data, name))
        if (orientation := image_orientation(data, name)) != 1:
            tagged[name] = orientation
    warn_orientations(tagged, len(names))
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise LtmError(f"the images of {str(lp)} differ in size: {sorted(shapes)}")
    return directions, np.stack([to_8bit(im) for im in images])


def to_8bit(image: np.ndarray) -> np.ndarray:
    """An 8- or 16-bit image as 8-bit (16-bit values rounded to the nearest 8-bit level)."""
    if image.dtype == np.uint8:
        return image
    return np.round(image.astype(np.float32) / 257).astype(np.uint8)


def score(relit_linear: np.ndarray, photo8: np.ndarray) -> tuple[float, float]:
    """PSNR (dB) and SSIM of one relit image (linear RGB, written as 8-bit sRGB) against a
    photograph (8-bit sRGB), over every pixel and channel."""
    pred = encode(np.nan_to_num(relit_linear), "srgb")
    psnr = peak_signal_noise_ratio(photo8, pred, data_range=255)
    side = min(photo8.shape[:2])
    window = min(7, side if side % 2 else side - 1)  # skimage's default, or a tiny image's side
    ssim = structural_similarity(photo8, pred, channel_axis=-1, data_range=255, win_size=window)
    return float(psnr), float(ssim)


def classic_relit(train8: np.ndarray, train_dirs: np.ndarray, query: np.ndarray,
                  method: str) -> tuple[np.ndarray, str]:
    """A classic fit of 8-bit sRGB photographs ``train8 (n, H, W, 3)`` at ``train_dirs``,
    relit at ``query (q, 3)``: ``(q, H, W, 3)`` linear RGB and the model's full name."""
    train = train8.astype(np.float32) / 255
    if method in ("rbf", HSH_RBF):
        luminance = (train @ LUMA.astype(np.float32)).reshape(len(train), -1)
        step = max(1, luminance.shape[1] // RBF_CHOICE_PIXELS)
        family = rbf_models() if method == "rbf" else hsh_rbf_models()
        model, _ = choose(luminance[:, ::step], train_dirs, family)
    elif method in CLASSIC:
        model = Model(method)
    else:
        raise LtmError(f"unknown classic method {method!r}; expected one of {', '.join(CLASSIC)}")
    return srgb_to_linear(relit(train, train_dirs, query, model)), model.name


def default_relit(lp: str | os.PathLike, train: Sequence[int] | None, query: np.ndarray,
                  workdir: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """The project's pipeline on the training lights of ``lp`` (all when ``train`` is None),
    relit at ``query (q, 3)``: ``(q, H, W, 3)`` linear RGB and the reconstruct record."""
    store = Path(workdir) / "heldout.zarr"
    with warnings.catch_warnings():  # load_photos has said what reading the capture found
        warnings.simplefilter("ignore", LpWarning)
        ingest_rti(lp, store, lights=train, progress=False, overwrite=True)
    info = reconstruct(store, progress=False)
    images = relight(store, directions=query).values
    return images, info


def heldout_photos(lp: str | os.PathLike, *, every: int | None = 6,
                   test_lp: str | os.PathLike | None = None,
                   methods: Sequence[str] = METHODS, keep: int | None = None) -> dict:
    """Score ``methods`` on held-out photographs of a classic capture.

    Parameters
    ----------
    lp : path-like
        The capture's ``.lp`` file.
    every : int, optional
        Hide every ``every``-th light and fit on the rest (ignored with ``test_lp``).
    test_lp : path-like, optional
        Fit on every light of ``lp``; score at the lights and photographs of this ``.lp``.
    methods : sequence of str
        Among :data:`METHODS`.
    keep : int, optional
        Also return the photograph and every method's 8-bit relit image of held-out light
        ``keep`` (under ``images``: arrays, not JSON).

    Returns
    -------
    dict
        ``capture``, ``protocol``, ``n_train``, ``held_out`` (directions), and per method
        ``psnr``, ``ssim`` (per held-out light), ``mean_psnr``, ``mean_ssim``, ``model``,
        ``seconds``; ``best_classic`` and ``default_minus_best_classic_db`` when both are scored.
    """
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise LtmError(f"unknown methods {unknown}; expected some of {', '.join(METHODS)}")
    directions, photos = load_photos(lp)
    if test_lp is not None:
        train_idx = None
        train_dirs, train8 = directions, photos
        query, truth = load_photos(test_lp)
        if truth.shape[1:] != photos.shape[1:]:
            raise LtmError(f"test photographs {truth.shape[1:3]} differ in size from the "
                           f"capture's {photos.shape[1:3]}")
        protocol = f"fit on {Path(lp).parent.name}/, score on {Path(test_lp).parent.name}/"
    else:
        hidden = hidden_lights(len(directions), every)
        train_idx = np.flatnonzero(~hidden).tolist()
        train_dirs, train8 = directions[~hidden], photos[~hidden]
        query, truth = directions[hidden], photos[hidden]
        protocol = f"hide every {every}th light"
    report = {"capture": str(lp), "protocol": protocol, "n_train": len(train_dirs),
              "held_out": query.round(4).tolist(), "methods": {}}
    if keep is not None:
        report["images"] = {"photograph": truth[keep]}
    for method in methods:
        start = time.perf_counter()
        if method == "default":
            with tempfile.TemporaryDirectory(prefix="ltm-heldout-") as tmp:
                images, info = default_relit(lp, train_idx, query, tmp)
            name = info["chosen_per_tile"]
        else:
            images, name = classic_relit(train8, train_dirs, query, method)
        scores = np.array([score(im, ph) for im, ph in zip(images, truth, strict=True)])
        if keep is not None:
            report["images"][method] = encode(images[keep], "srgb")
        report["methods"][method] = {
            "psnr": scores[:, 0].round(3).tolist(), "ssim": scores[:, 1].round(4).tolist(),
            "mean_psnr": float(scores[:, 0].mean()), "mean_ssim": float(scores[:, 1].mean()),
            "model": name, "seconds": time.perf_counter() - start}
    return _compare(report)


def _compare(report: dict) -> dict:
    scored = report["methods"]
    classic = [m for m in CLASSIC if m in scored]
    if classic:
        best = max(classic, key=lambda m: scored[m]["mean_psnr"])
        report["best_classic"] = best
        if "default" in scored:
            report["default_minus_best_classic_db"] = (scored["default"]["mean_psnr"]
                                                       - scored[best]["mean_psnr"])
    return report
