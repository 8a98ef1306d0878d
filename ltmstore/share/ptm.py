"""PTM 1.2 files (``.ptm``), uncompressed ``PTM_FORMAT_RGB`` and ``PTM_FORMAT_LRGB``.

Layout (HP Labs PtmFormat12; readers checked: RTIViewer ``RGBPtm``/``LRGBPtm::loadData``,
Relight ``LRti::loadPTM``/``decodeRAW``): text lines ``PTM_1.2``, the format, width, height,
six scales, six integer biases, then bytes; a coefficient byte ``c`` means
``a = (c - bias) * scale`` and ``L(u, v) = a0 u^2 + a1 v^2 + a2 uv + a3 u + a4 v + a5`` in
0-255 display units, ``(u, v)`` the light direction's x and y. Rows run from the bottom of the
image to the top.

* ``PTM_FORMAT_RGB``: all pixels' six red coefficients, then green, then blue.
* ``PTM_FORMAT_LRGB``: all pixels' six luminance coefficients, then all pixels' R, G, B bytes;
  a viewer shows ``rgb * L / 255``.
"""

from __future__ import annotations

import os

import numpy as np

from ltmstore.share.quantize import codes, ptm_scale_bias, term_range


def _header(fmt: str, width: int, height: int, scale: np.ndarray, bias: np.ndarray) -> bytes:
    lines = ["PTM_1.2", fmt, str(width), str(height),
             " ".join(f"{s:.9g}" for s in scale), " ".join(str(int(b)) for b in bias)]
    return ("\n".join(lines) + "\n").encode("ascii")


def _quantize(coef: np.ndarray, term_axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    scale, bias = ptm_scale_bias(*term_range(coef, term_axis))
    lo = -bias * scale
    return codes(coef, lo, scale, term_axis), scale, bias


def write_rgb(path: str | os.PathLike, coef: np.ndarray) -> None:
    """Write ``PTM_FORMAT_RGB`` from coefficients ``(y, x, 6, 3)`` in 0-255 units, rows top
    first (``y`` = 0 is the top row, as in the store)."""
    c, scale, bias = _quantize(coef, term_axis=2)
    height, width = coef.shape[:2]
    body = np.moveaxis(c[::-1], 3, 0)  # (channel, rows bottom-up, x, 6)
    with open(path, "wb") as f:
        f.write(_header("PTM_FORMAT_RGB", width, height, scale, bias))
        f.write(np.ascontiguousarray(body).tobytes())


def write_lrgb(path: str | os.PathLike, coef: np.ndarray, colour: np.ndarray) -> None:
    """Write ``PTM_FORMAT_LRGB`` from luminance coefficients ``(y, x, 6)`` in 0-255 units and
    a colour ``(y, x, 3)`` in ``[0, 1]``, rows top first."""
    c, scale, bias = _quantize(coef, term_axis=2)
    rgb = np.clip(np.round(colour * 255), 0, 255).astype(np.uint8)
    height, width = coef.shape[:2]
    with open(path, "wb") as f:
        f.write(_header("PTM_FORMAT_LRGB", width, height, scale, bias))
        f.write(np.ascontiguousarray(c[::-1]).tobytes())
        f.write(np.ascontiguousarray(rgb[::-1]).tobytes())
