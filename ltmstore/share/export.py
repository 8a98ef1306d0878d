"""``ltm export``: a store as a file the RTI world opens (RTIViewer, Relight, OpenLIME).

PTM, HSH and the web format's ``ptm``/``hsh`` bases are fitted per pixel to the store's colours
at the lattice cells' light directions (:mod:`ltmstore.share.directions`,
:mod:`ltmstore.share.fit`), and quantised to bytes with one
scale and bias per term (:mod:`ltmstore.share.quantize`); the web format's ``bilinear`` basis
carries the store's own relighting (:mod:`ltmstore.share.pca_web`). Every format keeps the
capture's exposure (``white`` = 1.0, as ``ltm relight`` writes images). Outputs are written
atomically: complete or not at all. The report's ``fidelity`` says what the format loses at the
capture's held-out lights (:mod:`ltmstore.share.fidelity`).
"""

from __future__ import annotations

import os

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.share import bases, fidelity, fit, hsh_rti, pca_web, ptm, relight_web, tiles
from ltmstore.share.atomic import atomic_output, check_output
from ltmstore.share.directions import light_samples

FORMATS = ("ptm", "hsh", "relight")
WEB_BASES = ("bilinear", "ptm", "hsh")
COLORS = ("rgb", "lrgb")
HSH_ORDERS = (2, 3)
WEB_HSH_ORDER = 2  # the web readers evaluate 9 HSH terms
CAPTURE_WHITE = 1.0  # the exports keep the capture's exposure, as ltm relight writes it


def _check(fmt: str, order: int, basis: str, color: str, quality: int | None) -> None:
    if fmt not in FORMATS:
        raise LtmError(f"--format {fmt!r} is unknown; expected one of {', '.join(FORMATS)}")
    if order not in HSH_ORDERS:
        raise LtmError(f"--order {order!r} must be 2 (9 terms) or 3 (16 terms)")
    if basis not in WEB_BASES:
        raise LtmError(f"--basis {basis!r} must be one of {', '.join(WEB_BASES)}")
    if color not in COLORS:
        raise LtmError(f"--color {color!r} must be one of {', '.join(COLORS)}")
    if color == "lrgb" and fmt != "ptm":
        raise LtmError("--color lrgb is a PTM format; use it with --format ptm")
    if quality is not None and not 1 <= quality <= 100:
        raise LtmError(f"--quality {quality!r} must be a JPEG quality from 1 to 100")


def export(store: str | os.PathLike, out: str | os.PathLike, *, fmt: str, order: int = 3,
           basis: str = "bilinear", color: str = "rgb",
           quality: int | None = None, overwrite: bool = False,
           resolution: int | None = None,
           planes: int | None = None, score: bool = True,
           layout: str = "image", tile_size: int = tiles.TILE_SIZE,
           overlap: int = tiles.OVERLAP) -> dict:
    """Export a reconstructed store to an RTI format.

    Parameters
    ----------
    store : path-like
        A reconstructed store.
    out : path-like
        The ``.ptm`` or ``.rti`` file, or the folder of the web format; an existing one is
        replaced only with ``overwrite``, and never the store, a path inside it or a folder
        holding it (:func:`ltmstore.core.paths.check_output`).
    fmt : {"ptm", "hsh", "relight"}
        PTM 1.2, HSH ``.rti`` (RTIViewer), or Relight's web format (OpenLIME).
    order : {2, 3}
        HSH order for ``fmt="hsh"``: 9 or 16 terms.
    basis : {"bilinear", "ptm", "hsh"}
        Basis of the web format: ``bilinear`` carries the store's own relighting
        (:mod:`ltmstore.share.pca_web`: PCA planes over an octahedral grid of lights, at the
        capture's exposure), ``ptm`` and ``hsh`` (9 terms) are fitted to it.
    color : {"rgb", "lrgb"}
        PTM only: a polynomial per channel, or one luminance polynomial times a colour.
    quality : int, optional
        JPEG quality of the web format's planes; default: for ``bilinear``, the lowest whose
        JPEG costs at most 0.5 dB at the capture's held-out lights
        (:mod:`ltmstore.share.jpeg_quality`), else 95.
    overwrite : bool
    resolution : int, optional
        ``bilinear`` only: light grid nodes per side; default: the smallest whose grid costs at
        most 0.25 dB at the capture's held-out lights (:mod:`ltmstore.share.light_grid`).
    planes : int, optional
        ``bilinear`` only: PCA planes; default: the fewest whose PCA costs at most 0.25 dB at
        the capture's held-out lights (:func:`ltmstore.share.pca_web.choose_planes`), else 27.
    score : bool
        Also evaluate the written coefficients at the capture's held-out lights (or its own
        lights) against ``ltm relight`` and the photographs (:mod:`ltmstore.share.fidelity`).
    layout : {"image", "deepzoom"}
        The web format's planes: one JPEG each, or a DeepZoom pyramid each
        (:mod:`ltmstore.share.tiles`; ``fmt="relight"`` only).
    tile_size, overlap : int
        ``deepzoom``: tile side and overlap in pixels.

    Returns
    -------
    dict
        What was written: path, format, basis terms, size, number of light directions, the
        exposure ``white`` (the linear value shown as 1.0: the capture's, 1.0, as ``ltm
        relight`` writes it), ``layout`` (tiled: also ``levels``, ``tiles``, ``tile_size``,
        ``overlap``) and, with ``score``, ``fidelity`` (:func:`ltmstore.share.fidelity.summary`).
    """
    _check(fmt, order, basis, color, quality)
    tiles.check(layout, fmt, tile_size, overlap)
    if fmt == "relight" and basis == "bilinear":
        pca_web.check(resolution, planes)
    check_output(out, overwrite, inputs=(store,))
    samples = light_samples(store)  # refuses a store export cannot read
    if layout != "image":
        tiles.check_size(samples.shape[1], samples.shape[0], tile_size)
    check = fidelity.checkpoints(store) if score else None
    fixed = relight_web.DEFAULT_QUALITY if quality is None else quality
    pyramid = {"layout": layout, "tile_size": tile_size, "overlap": overlap, "quality": fixed}
    if fmt == "relight" and basis == "bilinear":
        return _export_bilinear(store, out, quality, overwrite, resolution, planes, check,
                                pyramid)
    white = CAPTURE_WHITE
    tiled = {"layout": layout}
    design = _design(fmt, basis, order, samples.directions)
    with atomic_output(out, overwrite=overwrite, folder=fmt == "relight",
                       inputs=(store,)) as tmp:
        if fmt == "ptm" and color == "lrgb":
            coef, colour = fit.fit_lrgb(samples, design, white)
            ptm.write_lrgb(tmp, 255 * coef, colour)
            coef = coef[..., None] * colour[:, :, None, :]  # rgb * L: linear in the terms
        else:
            coef = fit.fit_rgb(samples, design, white)
            if fmt == "ptm":
                ptm.write_rgb(tmp, 255 * coef)
            elif fmt == "hsh":
                hsh_rti.write(tmp, coef)
            else:
                relight_web.write(tmp, coef, basis, quality=fixed)
                tiled = tiles.tile_planes(tmp, **pyramid)
    report = {"path": os.fspath(out), "format": fmt,
              "basis": basis if fmt == "relight" else fmt, "color": color,
              "terms": int(design.shape[1]), "width": samples.shape[1],
              "height": samples.shape[0], "directions": int(len(samples.directions)),
              "white": white, **tiled}
    if check is not None:
        weights = _design(fmt, basis, order, check.directions)
        images = fidelity.banded(lambda rows: np.einsum("lb,yxbc->lyxc", weights, coef[rows]),
                                 coef.shape[:2], len(weights))
        report["fidelity"] = fidelity.summary(_label(fmt, basis, order), images, check)
    return report


def _label(fmt: str, basis: str, order: int) -> str:
    """The format's name in the fidelity line."""
    if fmt == "hsh":
        return f"hsh order {order}"
    return f"relight {basis}" if fmt == "relight" else fmt


def _export_bilinear(store, out, quality: int, overwrite: bool, resolution: int | None,
                     planes: int | None, check: fidelity.Checkpoints | None, pyramid: dict
                     ) -> dict:
    """The web format carrying the store's relighting (:mod:`ltmstore.share.pca_web`),
    its planes laid out as ``pyramid`` says (:func:`ltmstore.share.tiles.tile_planes`)."""
    with atomic_output(out, overwrite=overwrite, folder=True, inputs=(store,)) as tmp:
        info = pca_web.write(store, tmp, resolution=resolution, planes=planes, quality=quality,
                             checkpoints=check)
        tiled = tiles.tile_planes(tmp, **{**pyramid, "quality": info["quality"]})
    report = {"path": os.fspath(out), "format": "relight", "basis": "bilinear",
              "color": "rgb", "terms": info["planes"], "width": info["width"],
              "height": info["height"], "directions": info["directions"],
              "white": CAPTURE_WHITE, "quality": info["quality"], **tiled}
    for key in ("jpeg", "grid", "pca"):
        if key in info:
            report[key] = info[key]
    if check is not None:
        report["fidelity"] = fidelity.summary(
            "relight bilinear", info["images"], check)
    return report


def _design(fmt: str, basis: str, order: int, directions: np.ndarray) -> np.ndarray:
    """The basis matrix ``(M, terms)`` of the format, in its coefficient order."""
    if fmt == "ptm":
        return bases.ptm_terms(directions)
    if fmt == "hsh":
        return bases.hsh_terms(directions, order)
    if basis == "ptm":
        return bases.relight_ptm_terms(directions)
    return bases.hsh_terms(directions, WEB_HSH_ORDER)
