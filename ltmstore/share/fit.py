"""Per-pixel least-squares fits of a light basis to a store's display-referred colours.

RTIViewer, Relight and OpenLIME show the evaluated coefficients as they are: the coefficients
must fit display (sRGB-encoded) values in ``[0, 1]``, as a camera's JPEGs would give them. The
store's linear RGB is divided by one exposure for the whole export (``white``; ``ltm export``
passes 1.0, the capture's exposure, as ``ltm relight`` writes it by default: a viewer then shows
what the photographs showed; :func:`exposure` is the 99.5th-percentile rule), clipped and
sRGB-encoded. All pixels share the lights, so one regularised pseudo-inverse of the basis matrix
fits them all; the store is read in blocks of rows. The lattice directions are weighted
alike: weighting them by the density of the capture's lights (a Gaussian of the cells' spacing,
floor 0.05) was measured at the held-out lights and dropped: PTM +0.2 / +0.3 / -2.3 dB and HSH
order 3 -0.2 / -0.15 / -0.7 dB on loewenkopf / coin / icon.

The fit is ridge regression with a penalty ``RIDGE`` times the basis matrix's largest singular
value. Lights on a plane cover only a cap of the hemisphere, where the HSH terms are nearly
collinear: the plain least-squares coefficients are large and cancel, and 8 bits cannot hold
them (on the small relief store, HSH order 3 relit at held-out lights: 40.6 dB in floating
point but 29.8 dB once quantised; with the ridge 39.0 and 38.9 dB; PTM loses 0.1 dB).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ltmstore.core.transfer import linear_to_srgb
from ltmstore.share.directions import LightSamples

WHITE_PERCENTILE = 99.5
RIDGE = 0.01
BLOCK_BYTES = 64 * 2**20  # float32 values read at once
SAMPLE_VALUES = 2 * 10**7  # at most this many values for the exposure


def _blocks(samples: LightSamples) -> Iterator[tuple[slice, np.ndarray]]:
    """``(row slice, linear RGB (rows, x, M, 3))`` in blocks of about ``BLOCK_BYTES``."""
    ny, nx = samples.shape
    step = max(1, BLOCK_BYTES // (4 * 3 * nx * len(samples.directions)))
    for y0 in range(0, ny, step):
        rows = slice(y0, min(y0 + step, ny))
        yield rows, samples.rows(rows)


def exposure(samples: LightSamples) -> float:
    """The linear value shown as white: the 99.5th percentile of the RGB over pixels and
    lights (on a regular subsample of at most ``SAMPLE_VALUES`` values)."""
    size = 3 * np.prod(samples.shape) * len(samples.directions)
    stride = max(1, int(np.ceil(np.sqrt(size / SAMPLE_VALUES))))
    sample = samples.rows(slice(None, None, stride), slice(None, None, stride))
    return max(float(np.percentile(sample, WHITE_PERCENTILE)), 1e-12)


def display(linear: np.ndarray, white: float) -> np.ndarray:
    """Linear RGB to display-referred sRGB in ``[0, 1]`` at exposure ``white``."""
    return linear_to_srgb(linear / white)


def solver(basis: np.ndarray) -> np.ndarray:
    """``(B, M)``: the ridge-regularised pseudo-inverse of ``basis (M, B)``."""
    lam = RIDGE * np.linalg.norm(basis, 2)
    gram = basis.T @ basis + lam ** 2 * np.eye(basis.shape[1])
    return np.linalg.solve(gram, basis.T).astype(np.float32)


def fit_rgb(samples: LightSamples, basis: np.ndarray, white: float) -> np.ndarray:
    """Coefficients of ``basis (M, B)`` fitted to each pixel's and channel's display values.

    Returns
    -------
    ndarray of float32, shape ``(y, x, B, 3)``, in display units (``[0, 1]`` scale).
    """
    inverse = solver(basis)
    out = np.empty((*samples.shape, basis.shape[1], 3), np.float32)
    for rows, block in _blocks(samples):
        out[rows] = np.einsum("bm,yxmc->yxbc", inverse, display(block, white), optimize=True)
    return out


def fit_lrgb(samples: LightSamples, basis: np.ndarray,
             white: float) -> tuple[np.ndarray, np.ndarray]:
    """Luminance coefficients and one colour per pixel (the PTM LRGB model ``rgb * L``).

    The colour ``n`` is the pixel's mean display colour over the lights, scaled so that its
    largest channel is 1; the luminance at each light is the least-squares factor of the display
    colour along ``n`` (``D . n / n . n``), and ``basis`` is fitted to it.

    Returns
    -------
    coefficients : ndarray of float32, shape ``(y, x, B)``, display units.
    colour : ndarray of float32, shape ``(y, x, 3)``, in ``[0, 1]``.
    """
    inverse = solver(basis)
    coef = np.empty((*samples.shape, basis.shape[1]), np.float32)
    colour = np.empty((*samples.shape, 3), np.float32)
    for rows, block in _blocks(samples):
        d = display(block, white)
        mean = d.mean(axis=2)
        peak = mean.max(axis=-1, keepdims=True)
        n = np.where(peak > 0, mean / np.where(peak > 0, peak, 1), 1.0)
        lum = np.einsum("yxmc,yxc->yxm", d, n, optimize=True) / np.sum(n * n, axis=-1)[..., None]
        coef[rows] = np.einsum("bm,yxm->yxb", inverse, lum, optimize=True)
        colour[rows] = n
    return coef, colour
