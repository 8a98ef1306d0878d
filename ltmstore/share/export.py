"""``ltm export``: a store as a file the RTI world opens (RTIViewer, Relight, OpenLIME).

The chosen basis is fitted per pixel to the store's colours at the lattice cells' light
directions (:mod:`ltmstore.share.directions`, :mod:`ltmstore.share.fit`), quantised to bytes
with one scale and bias per term (:mod:`ltmstore.share.quantize`) and written atomically: the
output appears complete or not at all.
"""

from __future__ import annotations

import os

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.share import bases, fit, hsh_rti, ptm, relight_web
from ltmstore.share.atomic import atomic_output, check_output
from ltmstore.share.directions import light_samples

FORMATS = ("ptm", "hsh", "relight")
WEB_BASES = ("ptm", "hsh")
COLORS = ("rgb", "lrgb")
HSH_ORDERS = (2, 3)
WEB_HSH_ORDER = 2  # the web readers evaluate 9 HSH terms


def _check(fmt: str, order: int, basis: str, color: str, quality: int) -> None:
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
    if not 1 <= quality <= 100:
        raise LtmError(f"--quality {quality!r} must be a JPEG quality from 1 to 100")


def export(store: str | os.PathLike, out: str | os.PathLike, *, fmt: str, order: int = 3,
           basis: str = "ptm", color: str = "rgb", quality: int = relight_web.DEFAULT_QUALITY,
           overwrite: bool = False) -> dict:
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
    basis : {"ptm", "hsh"}
        Basis of the web format (its HSH has 9 terms).
    color : {"rgb", "lrgb"}
        PTM only: a polynomial per channel, or one luminance polynomial times a colour.
    quality : int
        JPEG quality of the web format's planes.
    overwrite : bool

    Returns
    -------
    dict
        What was written: path, format, basis terms, size, number of light directions and the
        exposure ``white`` (the linear value shown as 1.0).
    """
    _check(fmt, order, basis, color, quality)
    check_output(out, overwrite, inputs=(store,))
    samples = light_samples(store)
    white = fit.exposure(samples)
    design = _design(fmt, basis, order, samples.directions)
    with atomic_output(out, overwrite=overwrite, folder=fmt == "relight",
                       inputs=(store,)) as tmp:
        if fmt == "ptm" and color == "lrgb":
            coef, colour = fit.fit_lrgb(samples, design, white)
            ptm.write_lrgb(tmp, 255 * coef, colour)
        elif fmt == "ptm":
            ptm.write_rgb(tmp, 255 * fit.fit_rgb(samples, design, white))
        elif fmt == "hsh":
            hsh_rti.write(tmp, fit.fit_rgb(samples, design, white))
        else:
            relight_web.write(tmp, fit.fit_rgb(samples, design, white), basis, quality=quality)
    return {"path": os.fspath(out), "format": fmt, "basis": basis if fmt == "relight" else fmt,
            "color": color, "terms": int(design.shape[1]), "width": samples.shape[1],
            "height": samples.shape[0], "directions": int(len(samples.directions)),
            "white": white}


def _design(fmt: str, basis: str, order: int, directions: np.ndarray) -> np.ndarray:
    """The basis matrix ``(M, terms)`` of the format, in its coefficient order."""
    if fmt == "ptm":
        return bases.ptm_terms(directions)
    if fmt == "hsh":
        return bases.hsh_terms(directions, order)
    if basis == "ptm":
        return bases.relight_ptm_terms(directions)
    return bases.hsh_terms(directions, WEB_HSH_ORDER)
