"""Occluded frames: the phone that holds the light passes between camera B and the painting.

Such a frame is far darker than the light's position predicts. The mean brightness of a frame is a
smooth function of the light position (the painting's reflectance summed over its pixels, with
the inverse-square fall-off), so a low-order polynomial in ``(r, s, z)`` models it. The model is
fitted robustly (frames far from it are left out and it is fitted again) and a valid frame darker
than :data:`OCCLUSION_RATIO` times the model is occluded: it is rejected, never binned as if lit.
"""

from __future__ import annotations

import numpy as np

OCCLUSION_RATIO = 0.5  # a frame below half the brightness its light position predicts
MIN_FRAMES = 64  # fewer valid frames cannot pin the model down: nothing is flagged
DEGREE = 3  # of the polynomial in the normalised light position
MAX_ROUNDS = 10


def occluded_frames(brightness: np.ndarray, r: np.ndarray, s: np.ndarray, z: np.ndarray,
                    valid: np.ndarray) -> np.ndarray:
    """Which frames are occluded.

    Parameters
    ----------
    brightness : ndarray, shape (n,)
        Mean linear luminance of each frame.
    r, s, z : ndarray, shape (n,)
        Light position of each frame.
    valid : ndarray of bool, shape (n,)
        The frames to judge (the others are never flagged).

    Returns
    -------
    ndarray of bool, shape (n,)
        True for valid frames darker than :data:`OCCLUSION_RATIO` times the model; all False
        when fewer than :data:`MIN_FRAMES` frames are valid.
    """
    out = np.zeros(len(brightness), dtype=bool)
    idx = np.flatnonzero(valid & np.isfinite(brightness))
    if len(idx) < MIN_FRAMES:
        return out
    basis = _basis(r[idx], s[idx], z[idx])
    b = brightness[idx]
    keep = np.ones(len(idx), dtype=bool)
    for _ in range(MAX_ROUNDS):
        coef, *_ = np.linalg.lstsq(basis[keep], b[keep], rcond=None)
        model = np.maximum(basis @ coef, 0)
        fits = (b >= OCCLUSION_RATIO * model) & (OCCLUSION_RATIO * b <= model)
        if np.array_equal(fits, keep):
            break
        keep = fits
    out[idx] = b < OCCLUSION_RATIO * model
    return out


def _basis(r: np.ndarray, s: np.ndarray, z: np.ndarray) -> np.ndarray:
    def norm(v: np.ndarray) -> np.ndarray:
        spread = np.ptp(v)
        return (v - v.mean()) / spread if spread > 0 else np.zeros_like(v)

    u, v, w = norm(r), norm(s), norm(z)
    cols = [u**i * v**j for i in range(DEGREE + 1) for j in range(DEGREE + 1 - i)]
    return np.column_stack([*cols, w])
