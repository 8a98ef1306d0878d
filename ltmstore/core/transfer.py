"""Transfer functions between stored code values and linear light."""

from __future__ import annotations

import numpy as np

from ltmstore.core.errors import LtmError

TRANSFERS = ("srgb", "linear")


# Both curves work in float32 in place (one output array, no temporaries): they run on every
# pixel of every photograph of a capture.


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in ``[0, 1]`` (float32)."""
    v = np.asarray(v, dtype=np.float32)
    out = v + np.float32(0.055)
    out /= np.float32(1.055)
    np.power(out, np.float32(2.4), out=out)
    np.divide(v, np.float32(12.92), out=out, where=v <= 0.04045)
    return out


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values (clipped to ``[0, 1]``; float32)."""
    v = np.clip(np.asarray(v, dtype=np.float32), 0, 1)
    out = np.power(v, np.float32(1 / 2.4))
    out *= np.float32(1.055)
    out -= np.float32(0.055)
    np.multiply(v, np.float32(12.92), out=out, where=v <= 0.0031308)
    return out


def _check(transfer: str) -> None:
    if transfer not in TRANSFERS:
        raise LtmError(f"transfer {transfer!r} is unknown; expected one of {', '.join(TRANSFERS)}")


def decode(code: np.ndarray, transfer: str) -> np.ndarray:
    """8-bit code values to linear light in ``[0, 1]``."""
    _check(transfer)
    v = np.asarray(code, dtype=np.float32) / 255.0
    return srgb_to_linear(v) if transfer == "srgb" else v


def transfer_lut(transfer: str, bits: int = 8) -> np.ndarray:
    """Linear light of each code value of ``bits`` (8 or 16), as a ``(2**bits,)`` float32 table
    (see :func:`decode`)."""
    codes = np.arange(2**bits)
    return decode(codes if bits == 8 else codes * (255 / (2**bits - 1)), transfer)


def encode(linear: np.ndarray, transfer: str) -> np.ndarray:
    """Linear light to 8-bit code values (rounded, clipped)."""
    _check(transfer)
    v = linear_to_srgb(linear) if transfer == "srgb" else np.clip(linear, 0, 1)
    return np.round(np.asarray(v) * 255).astype(np.uint8)


def encode_images(images: np.ndarray, transfer: str) -> np.ndarray:
    """Linear RGB images ``(n, y, x, 3)`` to 8-bit, scaled so the brightest 0.5% clip."""
    scale = max(float(np.percentile(images, 99.5)), 1e-12)
    return encode(images / scale, transfer)
