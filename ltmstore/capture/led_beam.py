"""The exponent of the LED's ``cos^k`` beam, from how its wobble moves light across camera B's
frame.

When a hand tilts phone A by a few degrees, the LED's beam leans to one side: blocks of the
painting on that side brighten and those on the other darken, by ``k`` times the change of the
log of the beam's cosine towards each. That difference *across the frame* is what this module
fits, per colour channel:

    log F[i, b] = f_b(r_i, s_i, z_i) + c_i + k * beam[i, b]

with ``f_b`` each block's brightness as a function of the light's position (the position basis
of :mod:`ltmstore.capture.drift`, eliminated by a projection), ``c_i`` a term common to all
blocks of frame ``i`` (eliminated by taking each frame's mean over the blocks off) and
``beam[i, b]`` the log of the beam's cosine towards block ``b`` relative to that of the LED held
level. The common term takes up whatever changes the whole frame at once: camera B's exposure
and white balance, and the codec's errors shared by a frame's blocks. The mean over the blocks
that the drift's model uses (``k`` jointly with the gain's knots, or alone) keeps only the
beam's second-order part and all of those: on simulated 720 px captures with every effect
(H.264 at a phone's bitrate, room light, lens, ``cos^2`` beam, camera B locked) it measured
``k`` 0.3-1.4 (standard error 0.2), and a beam-free capture coded at a phone's bitrate
-0.4 to -1.1; fitted across the frame, 1.8-2.1 +- 0.1 and 0.6-0.8 +- 0.2.

Where each block lies on the plane is not known at ingest (the placement is estimated by the
reconstruction): the blocks are spread over the object's guess in each of the eight ways camera
B's frame may lie on the plane (either axis reversed, the two swapped), and the way that fits
best with ``k >= 0`` is kept (a half turn changes the sign of ``k`` and fits as well).
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.linalg

from ltmstore.capture.drift import (
    MIN_BLOCK_FRACTION,
    MIN_DOF,
    MIN_FRAMES,
    beam_log_ratios,
    position_basis,
)
from ltmstore.core.dims import Plane

MIN_COS = 1e-3  # the beam's cosine ratio towards a block the LED points away from
MIN_RELATIVE = 0.01  # a block's value is floored at this fraction of its median
# (reverse the frame's x, reverse its y, swap them): the eight ways the frame may lie on the plane
ORIENTATIONS = tuple(itertools.product((False, True), repeat=3))


def estimate_beam(blocks: np.ndarray, r: np.ndarray, s: np.ndarray, z: np.ndarray,
                  axis: np.ndarray, lit: np.ndarray, plane: Plane,
                  extent: tuple[tuple[float, float], tuple[float, float]]
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """The beam's exponent per colour channel ``(C,)`` and its standard error ``(C,)``.

    Parameters
    ----------
    blocks : ndarray (n, G * G, C)
        Mean linear RGB (or luminance, ``C = 1``) of a ``G x G`` grid of camera B's blocks
        per frame (rows from the frame's top), the room light taken off; blocks darker than
        :data:`~ltmstore.capture.drift.MIN_BLOCK_FRACTION` of the brightest are left out.
    r, s, z : ndarray (n,)
        Light position per frame.
    axis : ndarray (n, 3)
        The LED's axis per frame (unit, plane coordinates; NaN where unknown).
    lit : ndarray (n,) of bool
        Frames lit by the LED at a known position.
    plane : Plane
        The illumination plane (the position basis spans it).
    extent : ((r0, r1), (s0, s1))
        Where the frame's blocks are taken to lie on the object plane.

    Returns
    -------
    (exponent, stderr) or None
        None where fewer than :data:`~ltmstore.capture.drift.MIN_FRAMES` frames are usable, the
        model leaves fewer than :data:`~ltmstore.capture.drift.MIN_DOF` degrees of freedom, or
        fewer than two blocks are bright enough.
        The standard error treats each frame's blocks as one draw (their errors, the codec's
        included, may be shared).
    """
    use = (np.asarray(lit, dtype=bool) & np.isfinite(r) & np.isfinite(s) & np.isfinite(z)
           & np.isfinite(axis).all(axis=1))
    if use.sum() < MIN_FRAMES:
        return None
    q = scipy.linalg.orth(position_basis(r[use], s[use], z[use], plane))
    if int(use.sum()) - q.shape[1] - 1 < MIN_DOF:
        return None
    lit_blocks = blocks[use]
    keep = _bright_blocks(lit_blocks)
    if keep.sum() < 2:  # a frame's mean over one block takes all of it
        return None
    lit_blocks = lit_blocks[:, keep]
    floor = MIN_RELATIVE * np.median(lit_blocks, axis=0)  # the room light's noise taken off
    logs = [_centred(np.log(np.maximum(lit_blocks[..., c], floor[:, c])), q)
            for c in range(blocks.shape[2])]
    grid = int(round(np.sqrt(blocks.shape[1])))
    fits = []
    for orientation in ORIENTATIONS:
        pr, ps = _block_positions(grid, extent, orientation)
        beam = beam_log_ratios(r[use], s[use], z[use], axis[use], pr[keep], ps[keep])
        beam = np.where(np.isfinite(beam), beam, np.log(MIN_COS))  # the LED pointing away
        fits.append(_fit(logs, _centred(beam, q)))
    upright = [f for f in fits if np.mean(f[0]) >= 0] or fits
    exponent, stderr, _ = min(upright, key=lambda f: f[2])
    return exponent, stderr


def object_guess(plane: Plane) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where camera B's blocks are taken to lie before the object is placed: the plane's
    central half in each direction (the simulator's 20 cm painting under its 40 cm plane)."""
    def half(lo: float, hi: float) -> tuple[float, float]:
        return (0.75 * lo + 0.25 * hi, 0.25 * lo + 0.75 * hi)
    return (half(*plane.r), half(*plane.s))


def _block_positions(grid: int, extent: tuple[tuple[float, float], tuple[float, float]],
                     orientation: tuple[bool, bool, bool]) -> tuple[np.ndarray, np.ndarray]:
    """The plane positions ``(r, s)`` of a ``grid x grid`` of blocks (row-major, rows from the
    frame's top) spread over ``extent``, the frame lying on the plane as ``orientation`` says:
    upright, its x along ``r`` and its top at high ``s``, unless reversed or swapped."""
    flip_x, flip_y, swap = orientation
    u = (np.arange(grid) + 0.5) / grid
    x, y = np.meshgrid(u[::-1] if flip_x else u, u[::-1] if flip_y else u)
    if swap:
        x, y = y, x
    (r0, r1), (s0, s1) = extent
    return (r0 + (r1 - r0) * x).ravel(), (s1 - (s1 - s0) * y).ravel()


def _bright_blocks(blocks: np.ndarray) -> np.ndarray:
    """The blocks ``(B,)`` whose median in every channel is above :data:`MIN_BLOCK_FRACTION` of
    that channel's brightest."""
    level = np.median(blocks, axis=0)  # (B, 3)
    return np.all(level > MIN_BLOCK_FRACTION * np.maximum(level.max(axis=0), 1e-30), axis=1)


def _centred(values: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``values (n, B)`` less their projection on the position basis ``q`` (each block's
    function of the light's position), then less each frame's mean over the blocks (the
    frame's common term)."""
    v = values - q @ (q.T @ values)
    return v - v.mean(axis=1, keepdims=True)


def _fit(logs: list[np.ndarray], beam: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Per channel, the least-squares ``k`` of ``logs[c] ~ k * beam``, its standard error
    (each frame's blocks one cluster) and the residual sum of squares of all channels."""
    exponent, stderr, rss = np.zeros(len(logs)), np.zeros(len(logs)), 0.0
    norm = max(float(np.sum(beam * beam)), 1e-300)
    for c, y in enumerate(logs):
        exponent[c] = float(np.sum(beam * y)) / norm
        e = y - exponent[c] * beam
        stderr[c] = float(np.sqrt(np.sum(np.sum(beam * e, axis=1) ** 2))) / norm
        rss += float(np.sum(e * e))
    return exponent, stderr, rss
