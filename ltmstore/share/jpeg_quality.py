"""The web planes' JPEG quality, chosen by what it costs the relit images.

A web export's planes are JPEG images: the lower the quality, the smaller the files and the
further the relit images move from ``ltm relight``'s. The cost is not the same on every capture
(measured against ``ltm relight`` at the held-out lights, 27 planes; ``--quality`` 95 / 97 / 98
/ 100, dB lost to the JPEG against the planes' 8-bit values): coin 1.28 / 0.68 / 0.41 / 0.11,
icon 0.99 / 0.55 / 0.38 / 0.15, loewenkopf 0.92 / 0.41 / 0.21 / 0.04, SynthRTI's
``multi-obj1-material1`` 0.13 / 0.09 / 0.07 / 0.07. ``ltm export`` therefore takes the lowest
quality of :data:`QUALITIES` whose JPEG costs at most :data:`MAX_LOSS_DB` there, judged on a
central window of the planes (at most :data:`WINDOW` pixels a side, aligned with the JPEG's
blocks), so that the choice costs the same at 24 MP as at 1 MP.
"""

from __future__ import annotations

import io
from collections.abc import Callable

import numpy as np
from PIL import Image

from ltmstore.share.fidelity import central_window, psnr

QUALITIES = (95, 97, 98, 100)  # tried in this order
MAX_LOSS_DB = 0.5  # the most the planes' JPEG may cost the relit images
WINDOW = 1024  # side of the window the choice is made on, in pixels at most
BLOCK = 16  # the window starts on a multiple of this (JPEG's macroblocks)


def encode(rgb: np.ndarray, quality: int) -> bytes:
    """Three planes ``rgb (y, x, 3)`` (uint8) as the export writes them: JPEG at ``quality``,
    no chroma subsampling (each channel is another plane)."""
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buffer, format="JPEG",
                                                    quality=int(quality), subsampling=0)
    return buffer.getvalue()


def decode(data: bytes) -> np.ndarray:
    """A JPEG's ``(y, x, 3)`` uint8 as a viewer decodes it."""
    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("RGB"))


def round_trip(codes: np.ndarray, quality: int) -> np.ndarray:
    """The planes ``codes (y, x, 3 j)`` (uint8) as a viewer decodes them after :func:`encode`
    at ``quality``, three planes an image."""
    out = np.empty_like(codes)
    for j in range(0, codes.shape[2], 3):
        out[:, :, j:j + 3] = decode(encode(codes[:, :, j:j + 3], quality))
    return out


def window(shape: tuple[int, int]) -> tuple[slice, slice]:
    """Rows and columns of the central window of an image of ``shape (y, x)``."""
    return central_window(shape, WINDOW, BLOCK)


def choose(codes: np.ndarray, images: Callable[[np.ndarray], np.ndarray],
           store: np.ndarray) -> tuple[int, dict]:
    """The lowest of :data:`QUALITIES` whose JPEG costs at most :data:`MAX_LOSS_DB`.

    Parameters
    ----------
    codes : ndarray of uint8, shape (y, x, planes)
        The planes' bytes (a window of them).
    images : callable
        8-bit images ``(n, y, x, 3)`` relit from planes of ``codes``'s shape.
    store : ndarray of uint8, shape (n, y, x, 3)
        ``ltm relight``'s images at the same lights, on the same window.

    Returns
    -------
    quality : int
        The quality chosen (the highest where none is within the bound).
    record : dict
        ``quality``, ``max_loss_db`` and ``loss_db``: each quality tried and what its JPEG
        cost, in dB against ``ltm relight``, beside the planes' 8-bit values.
    """
    exact = psnr(images(codes), store)
    losses: dict[int, float] = {}
    for quality in QUALITIES:
        losses[quality] = round(exact - psnr(images(round_trip(codes, quality)), store), 3)
        if losses[quality] <= MAX_LOSS_DB:
            break
    return quality, {"quality": quality, "max_loss_db": MAX_LOSS_DB, "loss_db": losses}
