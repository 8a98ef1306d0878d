"""The sRGB curves in float32 (their powers as ``exp(p log v)``) against IEC 61966-2-1 in
float64."""

from __future__ import annotations

import numpy as np

from ltmstore.core.transfer import half_to_srgb, linear_to_srgb, power, srgb_to_linear

V = np.linspace(0, 1, 1_000_001)


def test_the_curves_are_within_float32_rounding_of_the_standard():
    decoded = np.where(V <= 0.04045, V / 12.92, ((V + 0.055) / 1.055) ** 2.4)
    encoded = np.where(V <= 0.0031308, V * 12.92, 1.055 * V ** (1 / 2.4) - 0.055)
    # measured 3.5e-7 and 2.4e-7 (NumPy's float32 power: 1.0e-7)
    assert np.abs(srgb_to_linear(V.astype(np.float32)) - decoded).max() < 5e-7
    assert np.abs(linear_to_srgb(V.astype(np.float32)) - encoded).max() < 4e-7


def test_every_8_bit_code_comes_back():
    codes = np.arange(256)
    back = linear_to_srgb(srgb_to_linear((codes / 255).astype(np.float32)))
    np.testing.assert_array_equal(np.round(255 * back), codes)


def test_power_at_the_edges():
    got = power(np.float32([0, 1, 4, -1]), 2.4)
    np.testing.assert_allclose(got[:3], [0, 1, 4**2.4], rtol=1e-6)
    assert np.isnan(got[3])
    out = np.float32([0.25, 0.5])
    assert power(out, 0.5, out=out) is out
    np.testing.assert_allclose(out, [0.5, 0.5**0.5], rtol=1e-6)


def test_the_float16_table_is_the_curve_bit_for_bit():
    """Every float16 (negative, subnormal, above 1, infinite, NaN) encodes as the curve does,
    whatever the array's shape and strides."""
    every = np.arange(2**16, dtype=np.uint16).view(np.float16)
    np.testing.assert_array_equal(half_to_srgb(every), linear_to_srgb(every.astype(np.float32)))
    tile = every.reshape(256, 256)[::3, 1::2]
    assert half_to_srgb(tile).shape == tile.shape
    np.testing.assert_array_equal(half_to_srgb(tile), linear_to_srgb(tile.astype(np.float32)))
