"""The far-light models' images from the stored photographs, compiled (large stores:
:data:`ltmstore.stages.relight.COMPILED_WORK`).

A far-light model relights a pixel as a weighted sum of its photographs sRGB-encoded at the
capture's exposure. NumPy made that in passes over whole blocks, each with its temporaries: RGB
from Y, Cb, Cr, stacked, clipped, divided by the exposure, encoded, copied to float64 and summed
by BLAS, most of a classic store's relighting at 24 MP. Here :func:`linear` makes the clipped
linear RGB in one pass (for the surface blends, which NumPy encodes: its ``power`` is
vectorised, Numba's scalar ``powf`` took 3x as long), and for a few asked lights
:func:`encoded_sum` does it all in one pass from the photographs' Y, Cb and Cr, sRGB's power
by a table of the curve at every 8,192nd float32, interpolated (as close to the curve as
NumPy's float32 steps). A block of 47 photographs of 256 x 256 px in colour took 57-73 ms
against 134-153 ms when the linear values and their power each passed through memory; a 12 MP
store's ``ltm relight`` 24.4 against 29.2 s (``docs/benchmarks.md``).
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from ltmstore.core.dims import LUMA

_RED, _GREEN, _BLUE = (np.float32(w) for w in LUMA)
_CR_RED, _CB_BLUE = np.float32(1.402), np.float32(1.772)
_LOW = np.float32(0.0031308)  # sRGB's straight part up to this
_DROPPED = 13  # the float32 bits below sRGB's table (srgb_table): it keeps 10 of 23
_PART = (1 << _DROPPED) - 1


@njit(cache=True, nogil=True, error_model="numpy")
def linear(y, cb, cr, exposure, color, top, out):  # pragma: no cover - compiled
    """``out (n, p, 3)`` (``color``) or ``(n, p, 1)``: the linear RGB (or Y) of ``p`` pixels of
    ``n`` photographs, ``y``, ``cb``, ``cr`` ``(n, p)`` float32 (``cb``, ``cr`` ignored without
    ``color``), clipped at 0, divided by ``exposure (n,)`` float32 and clipped at ``top``
    (float32: 1 for the sRGB encoding, infinity for none), each step in float32 as
    :func:`ltmstore.core.dims.rgb_from_ycbcr`, ``np.clip`` and
    :func:`ltmstore.core.transfer.linear_to_srgb` take it (NaN stays NaN)."""
    n, p = y.shape
    value = np.empty(3, np.float32)
    for i in range(n):
        for j in range(p):
            _pixel(y[i, j], cb[i, j], cr[i, j], exposure[i], color, value)
            for c in range(out.shape[2]):
                out[i, j, c] = top if value[c] > top else value[c]


@njit(cache=True, inline="always", error_model="numpy")
def _pixel(y, cb, cr, exposure, color, value):  # pragma: no cover - compiled
    """``value (3,)``: one photograph's pixel as linear RGB (``color``; else its Y in
    ``value[0]``), clipped at 0 and divided by its ``exposure``, in float32 as
    :func:`ltmstore.core.dims.rgb_from_ycbcr` and ``np.clip`` take it (NaN stays NaN)."""
    zero = np.float32(0)
    if color:
        r = y + _CR_RED * cr
        b = y + _CB_BLUE * cb
        g = (y - _RED * r - _BLUE * b) / _GREEN
        value[0] = (zero if r < zero else r) / exposure
        value[1] = (zero if g < zero else g) / exposure
        value[2] = (zero if b < zero else b) / exposure
    else:
        v = y / exposure
        value[0] = zero if v < zero else v


@njit(cache=True, nogil=True, error_model="numpy")
def encoded_sum(y, cb, cr, exposure, color, weights, srgb, out):  # pragma: no cover
    """``out (d, p, c)``: ``weights (d, n)`` (float64) times the sRGB encoding of the linear RGB
    (``color``) or Y of ``p`` pixels of ``n`` photographs, their Y, Cb, Cr ``(n, p)`` float32
    (``cb``, ``cr`` ignored without ``color``), made as :func:`linear` makes it (clipped at
    0 and 1, divided by ``exposure (n,)``); encoded through ``srgb`` (:func:`srgb_table`) and
    summed in float64, a photograph at a time (each read in order)."""
    n, p = y.shape
    d, channels = weights.shape[0], out.shape[2]
    sums = np.zeros((d, p, channels))
    one = np.float32(1)
    value, bits = np.empty(3, np.float32), np.empty(1, np.float32)
    for i in range(n):
        for j in range(p):
            _pixel(y[i, j], cb[i, j], cr[i, j], exposure[i], color, value)
            for c in range(channels):
                v = _encode(one if value[c] > one else value[c], srgb, bits)
                for k in range(d):
                    sums[k, j, c] += weights[k, i] * v
    for k in range(d):
        for j in range(p):
            for c in range(channels):
                out[k, j, c] = sums[k, j, c]


@njit(cache=True, inline="always", error_model="numpy")
def _encode(v, srgb, bits):  # pragma: no cover - compiled
    """sRGB's encoding of a linear float32 ``v`` in ``[0, 1]`` (NaN stays NaN): its straight
    part exactly, its power by ``srgb`` (:func:`srgb_table`) at ``v``'s bits, interpolated;
    ``bits``: a float32 scratch of one value."""
    if v != v:
        return v
    if v <= _LOW:
        return v * np.float32(12.92)
    bits[0] = v
    code = bits.view(np.uint32)[0]
    at = code >> _DROPPED
    part = np.float32(code & _PART) * np.float32(1.0 / (_PART + 1))
    return srgb[at] + part * (srgb[at + 1] - srgb[at])


@functools.cache
def srgb_table() -> np.ndarray:
    """:func:`encoded_sum`'s table: sRGB's encoding (in float64, then float32) at every float32
    in ``[0, 1]`` whose last :data:`_DROPPED` bits are 0 (130,050 values). Interpolated, within
    1.2e-7 of the curve in float64, where :func:`ltmstore.core.transfer.linear_to_srgb`'s
    float32 steps are within 2.4e-7 (10 million values in ``[0, 1]``)."""
    top = int(np.array(1.0, np.float32).view(np.uint32)) >> _DROPPED
    v = (np.arange(top + 2, dtype=np.uint32) << _DROPPED).view(np.float32).astype(np.float64)
    srgb = np.where(v <= _LOW, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    return srgb.astype(np.float32)
