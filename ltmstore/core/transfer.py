"""Transfer functions between stored code values and linear light."""

from __future__ import annotations

import functools

import numpy as np

from ltmstore.core.errors import LtmError

TRANSFERS = ("srgb", "linear")
CAPTURE, AUTO = "capture", "auto"
EXPOSURES = (CAPTURE, AUTO)  # how linear light is put on 8-bit images (see encode_images)
EV_LIMIT = 20.0  # stops: beyond this either way every image is black or white
FLOAT = "float"
DEPTHS = (8, 16, FLOAT)  # what encode_images writes: uint8, uint16 code values, float32 light


# Both curves work in float32 in place (one output array, no temporaries): they run on every
# pixel of every photograph of a capture.


def power(v: np.ndarray, exponent: float, out: np.ndarray | None = None) -> np.ndarray:
    """``v ** exponent`` of float32 values ``v >= 0`` as ``exp(exponent * log(v))``, in ``out``
    where given (it may be ``v``): NumPy vectorises float32 ``exp`` and ``log`` with AVX2 but
    ``power`` only with AVX-512 (2.1x on an AVX2 EPYC; within 7e-7 relative of ``power``, 0 at
    0). A negative value gives NaN, as ``power`` does."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.log(v, out=out)
        out *= np.float32(exponent)
        return np.exp(out, out=out)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in ``[0, 1]`` (float32)."""
    v = np.asarray(v, dtype=np.float32)
    out = v + np.float32(0.055)
    out /= np.float32(1.055)
    power(out, 2.4, out=out)
    np.divide(v, np.float32(12.92), out=out, where=v <= 0.04045)
    return out


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values (clipped to ``[0, 1]``; float32)."""
    out = np.clip(np.asarray(v, dtype=np.float32), 0, 1)
    low = out <= 0.0031308
    dark = out[low] * np.float32(12.92)  # few values: the rest are encoded in place
    power(out, 1 / 2.4, out=out)
    out *= np.float32(1.055)
    out -= np.float32(0.055)
    out[low] = dark
    return out


def half_to_srgb(v: np.ndarray) -> np.ndarray:
    """:func:`linear_to_srgb` of float16 values (stored frames) by a table of every float16:
    the same values bit for bit, about 8x faster than the curve on a capture's tiles."""
    return _half_srgb()[np.asarray(v, dtype=np.float16).view(np.uint16)]


@functools.cache
def _half_srgb() -> np.ndarray:
    """:func:`linear_to_srgb` of each of the 65,536 float16 bit patterns (float32)."""
    return linear_to_srgb(np.arange(2**16, dtype=np.uint16).view(np.float16))


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


def linearise(code: np.ndarray, lut: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``lut[code]``: the linear light of an image's code values by a :func:`transfer_lut`
    (float32; into ``out`` where given, of the image's shape). 8-bit images of up to four
    channels go through OpenCV's table lookup, about 2x NumPy's gather on a 4K frame; other
    integer images through NumPy. A floating-point image holds linear light already (a float
    TIFF or EXR is linear by convention; a reader that is told otherwise decodes it first):
    returned as float32, the table unused."""
    code = np.asarray(code)
    if np.issubdtype(code.dtype, np.floating):
        values = code.astype(np.float32, copy=False)
    elif code.dtype == np.uint8 and lut.shape == (256,) and code.size and (
            code.ndim == 2 or (code.ndim == 3 and code.shape[2] <= 4)):
        import cv2

        return cv2.LUT(code, lut.astype(np.float32, copy=False).reshape(1, 256), dst=out)
    else:
        values = lut[code]
    if out is None:
        return values
    out[...] = values
    return out


def check_depth(depth: int | str) -> int | str:
    """``depth`` as one of :data:`DEPTHS` (``8``, ``16`` or ``"float"``; ``"8"`` and ``"16"``
    as given on a command line are taken too).

    Raises
    ------
    LtmError
        For anything else, naming it.
    """
    if not isinstance(depth, bool):
        for known in DEPTHS:
            if depth == known or (isinstance(depth, str) and depth.strip().lower() == str(known)):
                return known
    raise LtmError(f"depth {depth!r} is unknown; expected one of "
                   f"{', '.join(str(d) for d in DEPTHS)}")


def encode(linear: np.ndarray, transfer: str, depth: int | str = 8) -> np.ndarray:
    """Linear light to code values (rounded, clipped) of ``depth`` bits: ``uint8`` (8) or
    ``uint16`` (16); ``"float"``: the linear values themselves as float32 (no transfer, no
    clipping: light beyond white is kept)."""
    _check(transfer)
    depth = check_depth(depth)
    if depth == FLOAT:
        return np.asarray(linear, dtype=np.float32)
    v = linear_to_srgb(linear) if transfer == "srgb" else np.clip(linear, 0, 1)
    if depth == 16:
        return np.round(np.asarray(v, dtype=np.float64) * 65535).astype(np.uint16)
    return np.round(np.asarray(v) * 255).astype(np.uint8)


def check_exposure(exposure: str, ev: float = 0.0) -> tuple[str, float]:
    """``(exposure, ev)`` checked: ``exposure`` one of :data:`EXPOSURES`, ``ev`` a finite
    number of stops within ``[-EV_LIMIT, EV_LIMIT]`` (as a float)."""
    if exposure not in EXPOSURES:
        raise LtmError(f"exposure {exposure!r} is unknown; expected one of "
                       f"{', '.join(EXPOSURES)}")
    try:
        stops = float(ev)
    except (TypeError, ValueError):
        stops = float("nan")
    if not (np.isfinite(stops) and abs(stops) <= EV_LIMIT):
        raise LtmError(f"ev {ev!r} must be a finite number of stops from {-EV_LIMIT:g} to "
                       f"{EV_LIMIT:g}")
    return exposure, stops


def exposure_gain(images: np.ndarray, exposure: str = CAPTURE, ev: float = 0.0) -> float:
    """The factor on linear values that puts ``images`` at ``exposure``, ``ev`` stops brighter:
    ``2**ev`` at the capture's exposure, ``2**ev / p`` for ``auto`` (``p`` the images' 99.5th
    percentile: the brightest 0.5 % clip)."""
    exposure, stops = check_exposure(exposure, ev)
    gain = 2.0 ** stops
    if exposure == AUTO:
        gain /= max(float(np.percentile(images, 99.5)), 1e-12)
    return gain


def encode_images(images: np.ndarray, transfer: str, *, exposure: str = CAPTURE,
                  ev: float = 0.0, depth: int | str = 8) -> np.ndarray:
    """Linear RGB images ``(n, y, x, 3)`` (or any shape) to code values of ``depth``.

    Parameters
    ----------
    images : numpy.ndarray
        Linear light, as :func:`ltmstore.relight` returns it.
    transfer : str
        The capture's transfer function (one of :data:`TRANSFERS`).
    exposure : {"capture", "auto"}
        ``capture`` (default, photometric): the linear values as they are, so that an image
        relit at a light of the capture has that photograph's (or video frame's) brightness, a
        dimmer light gives a dimmer image and light beyond white clips, as in a camera.
        ``auto``: all ``images`` scaled by one factor so that their brightest 0.5 % clip.
    ev : float
        Stops added to that exposure (linear values times ``2**ev``), at most
        :data:`EV_LIMIT` either way.
    depth : {8, 16, "float"}
        8 (default): ``uint8`` code values in ``transfer``; 16: ``uint16`` code values in
        ``transfer`` (``round(v * 65535)`` where 8 bits hold ``round(v * 255)``); ``"float"``:
        ``float32`` linear light times the exposure's gain, no transfer and no clipping (for
        a float TIFF: :func:`ltmstore.core.imagefile.write_image`).

    Returns
    -------
    numpy.ndarray
        ``uint8``, ``uint16`` or ``float32`` values, the shape of ``images``.
    """
    depth = check_depth(depth)
    return encode(np.asarray(images) * np.float32(exposure_gain(images, exposure, ev)),
                  transfer, depth)
