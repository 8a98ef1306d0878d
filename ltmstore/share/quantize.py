"""8-bit coefficients with one scale and bias per basis term (shared by the colour channels).

The RTI formats store every coefficient as a byte ``c`` and one affine map per term back to its
value; only the form of that map differs:

* PTM 1.2: ``a = (c - bias) * scale`` with an integer ``bias`` in ``[0, 255]``;
* HSH ``.rti``: ``a = (c / 255) * scale + bias``;
* Relight web: ``a = (c / 255 - bias) * scale``.

Each term's full range over all pixels and channels maps onto ``[0, 255]``: nothing clips.
"""

from __future__ import annotations

import numpy as np


def term_range(coef: np.ndarray, term_axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum of each term (``coef`` moved so that terms lie along ``term_axis``)."""
    flat = np.moveaxis(coef, term_axis, 0).reshape(coef.shape[term_axis], -1)
    lo, hi = flat.min(axis=1).astype(np.float64), flat.max(axis=1).astype(np.float64)
    return lo, np.where(hi > lo, hi, lo + 1e-6)


def codes(coef: np.ndarray, lo: np.ndarray, step: np.ndarray, term_axis: int) -> np.ndarray:
    """``round((coef - lo) / step)`` as bytes; ``lo`` and ``step`` are per term."""
    shape = [1] * coef.ndim
    shape[term_axis] = -1
    c = (coef - lo.reshape(shape)) / step.reshape(shape)
    return np.clip(np.round(c), 0, 255).astype(np.uint8)


def ptm_scale_bias(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PTM's float ``scale`` and integer ``bias`` such that ``(c - bias) * scale`` covers
    ``[lo, hi]`` for ``c`` in ``[0, 255]``."""
    scale = (hi - lo) / 255
    bias = np.clip(np.round(-lo / scale), 0, 255)
    need_hi = np.where(bias < 255, hi / np.maximum(255 - bias, 1), 0)
    need_lo = np.where(bias > 0, -lo / np.maximum(bias, 1), 0)
    scale = np.maximum.reduce([scale, need_hi, need_lo])
    return scale, bias.astype(int)
