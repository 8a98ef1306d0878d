"""Cast shadows of far lights from a height map.

A far light at direction ``(lx, ly, lz)`` reaches a pixel unless the surface rises above the
light's elevation somewhere along the light's azimuth: the pixel's **horizon** there is the
steepest slope ``(h(p + t u) - h(p)) / t`` over the distances ``t`` of :data:`STEPS` (pixels,
``u`` the azimuth's unit step in the image: column ``+lx``, row ``-ly``), and the light is
visible by how far its elevation stands above that horizon, softened over ``softness`` degrees
(a logistic step: the light's size, the height's errors)::

    visible = 1 / (1 + exp(-(elevation - horizon) / softness))

The height is the surface's normals integrated (:func:`ltmstore.solve.height.integrate`), in
pixels, times a scale (:data:`SCALES`): an integrated height is right in its shape but not
always in its amplitude, and the scale and softness are chosen by held-out error where the
surface model is fitted (:func:`ltmstore.stages.surface.choose_shadows`). Pixels beyond the
image's edge take the edge's height. Measured on the relief renders of
``bench/heldout_table.py`` (blocks casting hard shadows, 96 px): the luminance's held-out PSNR
of the surface plus its residual rose 2.2-2.6 dB with the shadows (scale 1, softness 1-2
degrees); on the real captures and SynthRTI scenes the leave-one-light-out error stayed within
4 % of the surface's without them, and they are left out (issue 61).
"""

from __future__ import annotations

import numpy as np

# distances (pixels) at which the horizon is looked for: every pixel up to 4, then about
# geometric to 96 (a relief's shadow longer than that is rare at a dome's lowest ring, 10
# degrees, only behind a rise of 17 pixels)
STEPS = np.unique(np.round(np.geomspace(1, 96, 24))).astype(int)
SCALES = (1.0, 1.4)  # the integrated height's amplitude, tried
SOFTNESS = (1.0, 2.0, 4.0)  # degrees over which a light fades behind the horizon, tried


def visibility(height: np.ndarray, rows: np.ndarray, cols: np.ndarray, directions: np.ndarray,
               softness: float) -> np.ndarray:
    """How much of each far light reaches each pixel, ``(p, d)`` float32 in [0, 1].

    Parameters
    ----------
    height : ndarray, shape (H, W)
        The surface's height in pixels (any part of the image that holds the pixels and
        the distances of :data:`STEPS` around them; beyond it, its edge's height).
    rows, cols : ndarray of int, shape (p,)
        The pixels, indices into ``height``.
    directions : ndarray, shape (d, 3)
        Unit directions towards the lights (x right, y up, z towards the camera).
    softness : float
        Degrees over which a light fades behind the horizon.
    """
    height = np.asarray(height, dtype=np.float32)
    rows, cols = np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)
    here = height[rows, cols]
    out = np.empty((len(rows), len(directions)), dtype=np.float32)
    for i, (lx, ly, lz) in enumerate(np.asarray(directions, dtype=np.float64)):
        out[:, i] = _visible(height, rows, cols, here, lx, ly, lz, softness)
    return out


def _visible(height: np.ndarray, rows: np.ndarray, cols: np.ndarray, here: np.ndarray,
             lx: float, ly: float, lz: float, softness: float) -> np.ndarray:
    """:func:`visibility` of one light."""
    across = float(np.hypot(lx, ly))
    horizon = np.full(len(rows), -np.inf, dtype=np.float32)
    if across > 1e-6:
        seen = set()
        for t in STEPS:
            dr, dc = int(round(-t * ly / across)), int(round(t * lx / across))
            if (dr, dc) in seen or (dr, dc) == (0, 0):
                continue
            seen.add((dr, dc))
            r = np.clip(rows + dr, 0, height.shape[0] - 1)
            c = np.clip(cols + dc, 0, height.shape[1] - 1)
            np.maximum(horizon, (height[r, c] - here) / np.hypot(dr, dc), out=horizon)
    above = np.arctan2(lz, across) - np.arctan(horizon)
    return 1 / (1 + np.exp(-np.degrees(above) / softness))


def reach() -> int:
    """How far (pixels) beyond a region its pixels' horizons look."""
    return int(STEPS[-1])
