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
always in its amplitude (a wall steeper than the normals the fit can see is integrated too
low), and the scale and softness are chosen by held-out error where the surface model is
fitted (:func:`ltmstore.stages.surface.choose_shadows`). Pixels beyond the image's edge take
the edge's height. Measured on the relief renders of ``bench/heldout_table.py`` (blocks casting
hard shadows, 96 px): held-out PSNR up 1.3-5.0 dB with the shadows (scale 1, softness 1-4
degrees); at 512 px the same relief's walls rise 20 pixels in one or two and took scale 2.8
(``bench/cast_shadows.py``). On the real captures and SynthRTI scenes the leave-one-light-out
error stayed within 4 % of the surface's without them, and they are left out (issue 61).
"""

from __future__ import annotations

import numpy as np

# distances (pixels) at which the horizon is looked for: every pixel up to 4, then about
# geometric to 96 (a relief's shadow longer than that is rare at a dome's lowest ring, 10
# degrees, only behind a rise of 17 pixels)
STEPS = np.unique(np.round(np.geomspace(1, 96, 24))).astype(int)
SCALES = (1.0, 1.4, 2.0, 2.8)  # the integrated height's amplitude, tried
SOFTNESS = (1.0, 2.0, 4.0)  # degrees over which a light fades behind the horizon, tried


def horizons(height: np.ndarray, rows: np.ndarray, cols: np.ndarray, directions: np.ndarray
             ) -> np.ndarray:
    """The horizon of each of some pixels toward each far light, as a slope (height over
    distance; ``-inf`` for a light straight above), ``(p, d)`` float32; a height scaled by
    ``s`` has horizons scaled by ``s``. :func:`region_horizons` for a rectangle, faster.

    Parameters
    ----------
    height : ndarray, shape (H, W)
        The surface's height in pixels; beyond it, its edge's height.
    rows, cols : ndarray of int, shape (p,)
        The pixels, indices into ``height``.
    directions : ndarray, shape (d, 3)
        Unit directions towards the lights (x right, y up, z towards the camera).
    """
    height = np.asarray(height, dtype=np.float32)
    rows, cols = np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)
    here = height[rows, cols]
    out = np.full((len(rows), len(directions)), -np.inf, dtype=np.float32)
    for i, direction in enumerate(np.asarray(directions, dtype=np.float64)):
        for dr, dc in _offsets(direction):
            r = np.clip(rows + dr, 0, height.shape[0] - 1)
            c = np.clip(cols + dc, 0, height.shape[1] - 1)
            np.maximum(out[:, i], (height[r, c] - here) / np.hypot(dr, dc), out=out[:, i])
    return out


def region_horizons(height, rows: slice, cols: slice, directions: np.ndarray, *,
                    spacing: int = 1) -> np.ndarray:
    """:func:`horizons` of the pixels of ``height[rows, cols]`` (row-major), ``(p, d)``;
    ``height`` any 2-D array that slices (NumPy, Zarr, xarray): only the rectangle and the
    :func:`reach` around it are read. ``spacing``: the image's pixels between two of
    ``height``'s (a height taken at every n-th pixel, as a preview strides the store: the
    horizon then looks as far in the image, on the samples it has)."""
    bounds = ((rows.start, rows.stop), (cols.start, cols.stop))
    pad = -(-reach() // spacing)
    cut = [(max(a - pad, 0), min(b + pad, n)) for (a, b), n in
           zip(bounds, height.shape, strict=True)]
    window = np.asarray(height[cut[0][0]:cut[0][1], cut[1][0]:cut[1][1]], dtype=np.float32)
    # beyond the image, its edge's height: padded to the reach on every side
    window = np.pad(window, [(pad - (a - lo), pad - (hi - b)) for (a, b), (lo, hi) in
                             zip(bounds, cut, strict=True)], mode="edge")
    h, w = (b - a for a, b in bounds)
    here = window[pad:pad + h, pad:pad + w]
    out = np.full((h * w, len(directions)), -np.inf, dtype=np.float32)
    for i, direction in enumerate(np.asarray(directions, dtype=np.float64)):
        horizon = out[:, i].reshape(h, w).copy()
        for dr, dc in _offsets(direction, spacing):
            shifted = window[pad + dr:pad + dr + h, pad + dc:pad + dc + w]
            distance = np.float32(spacing * np.hypot(dr, dc))
            np.maximum(horizon, (shifted - here) / distance, out=horizon)
        out[:, i] = horizon.ravel()
    return out


def visible(directions: np.ndarray, horizon: np.ndarray, softness: float) -> np.ndarray:
    """How much of each far light at ``directions (d, 3)`` reaches each pixel, ``(p, d)``
    float32 in [0, 1], from their ``horizon (p, d)`` (:func:`horizons`): the logistic of the
    light's elevation above it over ``softness`` degrees."""
    directions = np.asarray(directions, dtype=np.float64)
    elevation = np.arctan2(directions[:, 2], np.hypot(directions[:, 0], directions[:, 1]))
    above = np.degrees(elevation.astype(np.float32) - np.arctan(horizon))
    return (1 / (1 + np.exp(-above / np.float32(softness)))).astype(np.float32)


def _offsets(direction: np.ndarray, spacing: int = 1) -> list[tuple[int, int]]:
    """The steps ``(rows, columns)`` toward a light, one per distance of :data:`STEPS` (in
    the image's pixels, ``spacing`` of them between two samples; repeats dropped); none for a
    light straight above."""
    lx, ly, _ = direction
    across = float(np.hypot(lx, ly)) * spacing
    if across <= 1e-6:
        return []
    steps = [(int(round(-t * ly / across)), int(round(t * lx / across))) for t in STEPS]
    return [s for s in dict.fromkeys(steps) if s != (0, 0)]


def reach() -> int:
    """How far (pixels) beyond a region its pixels' horizons look."""
    return int(STEPS[-1])
