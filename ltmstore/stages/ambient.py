"""The room light in camera B's frames: measured in the LED-off lead, or judged without one.

The ambient image is the per-pixel median of the lead's frames (robust to a person walking
through, a flicker), taken on the code values (the median commutes with the monotone transfer
curve) and then linearised.
"""

from __future__ import annotations

import numpy as np

FLOOR_PERCENTILE = 2.0


def ambient_image(frames: list[np.ndarray], lut: np.ndarray) -> np.ndarray:
    """Per-pixel median of uint8 RGB frames, as linear RGB ``(H, W, 3)`` float32.

    Parameters
    ----------
    frames : list of ndarray (H, W, 3) uint8
        The LED-off frames.
    lut : ndarray (256,)
        Code value to linear light.
    """
    median = np.median(np.stack(frames), axis=0)
    return np.interp(median, np.arange(len(lut)), lut).astype(np.float32)


def ambient_floor(blocks: np.ndarray, lit: np.ndarray) -> float | None:
    """How dark each block gets relative to its usual brightness, over the lit frames.

    Parameters
    ----------
    blocks : ndarray (n, B, 3)
        Mean linear RGB of image blocks per frame.
    lit : ndarray (n,) of bool
        Frames lit by the LED.

    Returns
    -------
    float or None
        Median over blocks of the :data:`FLOOR_PERCENTILE` percentile of a block's luminance
        over its median: near the LED's own fall-off over the plane without room light, higher
        with it. None without lit frames.
    """
    if not np.any(lit):
        return None
    y = blocks[lit].mean(axis=2)
    median = np.median(y, axis=0)
    keep = median > 0
    if not keep.any():
        return None
    low = np.percentile(y[:, keep], FLOOR_PERCENTILE, axis=0)
    return float(np.median(low / median[keep]))
