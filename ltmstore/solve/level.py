"""The frame's estimated map to the plane, refined until the surface it shows is level.

:func:`ltmstore.solve.placement.place_pixels` finds each pixel where its samples peak, with one
radial profile for the whole capture. Where a handheld path left part of the frame without a
light right above it, those pixels are placed from their profile's flanks, and a profile that is
not the surface's shading (no lobe, one exponent) pulls them towards the lights: a 720 px
canvas whose path never passed over its right fifth was estimated 30 mm narrower on that side and
turned by 3.6 degrees, and relit 0.9 dB below the true map.

The surface model (:func:`ltmstore.solve.physical.fit_surface`) fitted at a map's pixel positions
tilts each pixel's normal until its highlight lies where the samples have it, so a frame placed
off shows as normals tilted alike over whole regions, while a painting's own normals scatter
about the vertical. :func:`level_map` therefore moves each sampled pixel by the light's height
times its fitted slope and refits the map (:func:`ltmstore.solve.placement.fit_map`), while the
median slope of the frame's :data:`BLOCKS` x :data:`BLOCKS` regions falls (at most
:data:`LEVEL_STEPS` times); a step that does not lower it is halved. It assumes what the
profile assumed, a surface level on average, with the surface's own model instead of a
profile. Its cost does not grow with the image: a few fits of the pixels placed (the 4,096 that
:func:`ltmstore.stages.placement.read_pixels` reads; 1.4-2.8 s on 2 cores at 720 px); 1,024
of them left a 720 px canvas rendered with other physics 13 mm off, all of them 4 mm.
"""

from __future__ import annotations

import numpy as np

from ltmstore.solve import Geometry
from ltmstore.solve.physical import fit_surface
from ltmstore.solve.placement import MapFit, fit_map, pixel_map

BLOCKS = 4  # the frame's regions per side whose median slope is to be level
LEVEL_STEPS = 6  # refits of the map at most
HALVINGS = 3  # a step that does not level the frame is halved at most this many times


def _positions(corners: np.ndarray, rows: np.ndarray, cols: np.ndarray,
               image: tuple[int, int]) -> np.ndarray:
    """The plane positions ``(n, 2)`` of the pixels at ``rows``, ``cols`` under ``corners``."""
    origin, a = pixel_map(corners, image)
    return origin + np.column_stack([cols + 0.5, rows + 0.5]) @ a.T


def _slopes(samples: np.ndarray, geometry: Geometry, positions: np.ndarray) -> np.ndarray:
    """Each pixel's fitted normal as a slope ``(n, 2)``: ``(n_x / n_z, n_y / n_z)``."""
    surface, _, _ = fit_surface(samples, geometry.with_pixels(positions), share=False)
    normal = surface.normal
    return normal[:, :2] / np.maximum(normal[:, 2:], 1e-3)


def _tilt(slopes: np.ndarray, region: np.ndarray) -> float:
    """The RMS over the frame's regions of their median slope (both components)."""
    medians = [np.median(slopes[region == k], axis=0) for k in np.unique(region)]
    return float(np.sqrt(np.mean(np.square(medians))))


def level_map(samples: np.ndarray, rows: np.ndarray, cols: np.ndarray, image: tuple[int, int],
              start: MapFit, geometry: Geometry, *, seed: int = 0) -> tuple[MapFit, dict]:
    """The map ``start`` refined until the surface model's normals are level on average.

    Parameters
    ----------
    samples : ndarray of shape (n, R, S)
        The binned samples of ``n`` pixels (NaN where unobserved).
    rows, cols : ndarray of shape (n,)
        The pixels' row and column in the frame ``image (H, W)``.
    start : MapFit
        The map estimated from the radial profile (:func:`ltmstore.solve.placement.fit_map`).
    geometry : Geometry
        The lattice, the light plane's height, the LED's beam and where each cell's samples
        were taken (its ``pixels`` are ignored).
    seed : int
        Seed of :func:`~ltmstore.solve.placement.fit_map`'s bootstrap.

    Returns
    -------
    fit : MapFit
        The levelled map (``start`` where no step levelled the frame).
    record : dict
        ``tilt_before`` and ``tilt_after`` (the RMS of the regions' median slopes), ``steps``
        taken and ``moved`` (the largest distance a corner moved, plane units).
    """
    h, w = image
    region = (rows * BLOCKS // h) * BLOCKS + cols * BLOCKS // w
    fit, steps = start, 0
    positions = _positions(fit.corners, rows, cols, image)
    slopes = _slopes(samples, geometry, positions)
    tilt = before = _tilt(slopes, region)
    for _ in range(LEVEL_STEPS):
        for halving in range(HALVINGS + 1):
            moved = positions + 0.5**halving * geometry.height * slopes
            trial = fit_map(rows, cols, moved, image, seed=seed)
            trial_positions = _positions(trial.corners, rows, cols, image)
            trial_slopes = _slopes(samples, geometry, trial_positions)
            trial_tilt = _tilt(trial_slopes, region)
            if trial_tilt < tilt:
                break
        else:
            break
        fit, positions, slopes, tilt = trial, trial_positions, trial_slopes, trial_tilt
        steps += 1
    return fit, {"tilt_before": before, "tilt_after": tilt, "steps": steps,
                 "moved": float(np.linalg.norm(fit.corners - start.corners, axis=1).max())}
