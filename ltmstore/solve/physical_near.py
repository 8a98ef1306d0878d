"""Compiled Levenberg-Marquardt of :mod:`ltmstore.solve.physical` for near lights.

A handheld capture lights each pixel from its own directions (the light's position on the plane
seen from the pixel) with its own fall-off ``g``. NumPy spent most of the fit building
``(pixels, cells)`` temporaries for the model, its Jacobian and the normal equations (3.2 s of a
4.4 s ``physical.solve`` of a 32 x 32 tile on a 50 x 50 lattice); this module fuses them into one
loop per pixel (Numba), the same model and steps as
:func:`ltmstore.solve.physical.levenberg_marquardt`: float32 model and Jacobian, float32 sums of
the normal equations, the damped system solved in float64, a step kept only where it lowers the
pixel's cost. The twin of :mod:`ltmstore.solve.physical_far` (one direction per cell for every
pixel, no fall-off). :func:`model` evaluates the fitted model (the robust weights, the
evidence of each lobe, the model over the whole lattice: six calls per fit) without NumPy's
temporaries: 3 ms against 22 ms for 1024 pixels on 2500 cells, the same float32 values.

The kernels compile on first use (a few seconds, once) and are cached on disk (``cache=True``).
``fastmath`` only reorders sums (no assumption that values are finite).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ltmstore.solve.physical_far import (  # one pixel's 6 x 6 step and bounds, shared
    FASTMATH,
    LOG_ALPHA,
    SLOPE_MAX,
    _clip,
    _trial,
)

# the bounds _clip keeps, the fit and the model values
__all__ = ["LOG_ALPHA", "SLOPE_MAX", "levenberg_marquardt", "lights", "model"]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _cost(theta, toward, half, g, y, w, i):  # pragma: no cover - compiled
    """Weighted squared error of pixel ``i``'s model at ``theta (6,)`` (float32 sums)."""
    f0, f1, pi = np.float32(0.0), np.float32(1.0), np.float32(np.pi)
    p, q = np.float32(theta[0]), np.float32(theta[1])
    rho, k = np.float32(theta[2]), np.float32(theta[3])
    a2, floor = np.float32(np.exp(2 * theta[4])), np.float32(theta[5])
    norm = np.float32(np.sqrt(1 + p * p + q * q))
    cost = f0
    for c in range(y.shape[1]):
        wc = w[i, c]
        ndotl = (toward[2, i, c] - p * toward[0, i, c] - q * toward[1, i, c]) / norm
        ndoth = min(max((half[2, i, c] - p * half[0, i, c] - q * half[1, i, c]) / norm, f0), f1)
        cos = ndotl if ndotl > f0 else f0
        inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
        lobe = a2 / pi * inv_u * inv_u * (norm / np.float32(4))
        r = g[i, c] * (rho * cos + k * lobe) + floor - y[i, c]
        cost += wc * r * r
    return cost


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _system(theta, toward, half, g, y, w, i, jtj, grad):  # pragma: no cover - compiled
    """Fill ``jtj (6, 6)`` and ``grad (6,)`` with ``J^T W J`` and ``J^T W r`` of pixel ``i``'s
    residuals ``r = model - y`` at ``theta (6,)`` (float32 sums, as NumPy's)."""
    f0, f1, pi = np.float32(0.0), np.float32(1.0), np.float32(np.pi)
    p, q = np.float32(theta[0]), np.float32(theta[1])
    rho, k = np.float32(theta[2]), np.float32(theta[3])
    a2, floor = np.float32(np.exp(2 * theta[4])), np.float32(theta[5])
    norm = np.float32(np.sqrt(1 + p * p + q * q))
    s00 = s10 = s11 = s20 = s21 = s22 = s30 = s31 = s32 = s33 = f0
    s40 = s41 = s42 = s43 = s44 = s50 = s51 = s52 = s53 = s54 = s55 = f0
    g0 = g1 = g2 = g3 = g4 = g5 = f0
    for c in range(y.shape[1]):
        wc = w[i, c]
        gc = g[i, c]
        ndotl = (toward[2, i, c] - p * toward[0, i, c] - q * toward[1, i, c]) / norm
        ndoth = min(max((half[2, i, c] - p * half[0, i, c] - q * half[1, i, c]) / norm, f0), f1)
        lit = ndotl > f0
        cos = ndotl if lit else f0
        inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
        dist = a2 / pi * inv_u * inv_u
        lobe = dist * (norm / np.float32(4))
        r = gc * (rho * cos + k * lobe) + floor - y[i, c]
        dd_dc = np.float32(-4) * (a2 - f1) * ndoth * inv_u * dist
        dcos = (-toward[0, i, c] - ndotl * p / norm) / norm if lit else f0
        dc = (-half[0, i, c] - ndoth * p / norm) / norm
        j0 = gc * (rho * dcos + k * ((dd_dc * dc * norm + dist * p / norm) / np.float32(4)))
        dcos = (-toward[1, i, c] - ndotl * q / norm) / norm if lit else f0
        dc = (-half[1, i, c] - ndoth * q / norm) / norm
        j1 = gc * (rho * dcos + k * ((dd_dc * dc * norm + dist * q / norm) / np.float32(4)))
        j2, j3 = gc * cos, gc * lobe
        j4 = gc * k * (np.float32(2) * dist * (f1 - np.float32(2) * a2 * ndoth * ndoth * inv_u)
                       ) * (norm / np.float32(4))
        w0, w1, w2, w3, w4 = wc * j0, wc * j1, wc * j2, wc * j3, wc * j4
        g0 += w0 * r
        g1 += w1 * r
        g2 += w2 * r
        g3 += w3 * r
        g4 += w4 * r
        g5 += wc * r
        s00 += w0 * j0
        s10 += w1 * j0
        s11 += w1 * j1
        s20 += w2 * j0
        s21 += w2 * j1
        s22 += w2 * j2
        s30 += w3 * j0
        s31 += w3 * j1
        s32 += w3 * j2
        s33 += w3 * j3
        s40 += w4 * j0
        s41 += w4 * j1
        s42 += w4 * j2
        s43 += w4 * j3
        s44 += w4 * j4
        s50 += w0
        s51 += w1
        s52 += w2
        s53 += w3
        s54 += w4
        s55 += wc
    jtj[0, 0], jtj[1, 1], jtj[2, 2], jtj[3, 3], jtj[4, 4], jtj[5, 5] = (
        s00, s11, s22, s33, s44, s55)
    jtj[1, 0] = jtj[0, 1] = s10
    jtj[2, 0] = jtj[0, 2] = s20
    jtj[2, 1] = jtj[1, 2] = s21
    jtj[3, 0] = jtj[0, 3] = s30
    jtj[3, 1] = jtj[1, 3] = s31
    jtj[3, 2] = jtj[2, 3] = s32
    jtj[4, 0] = jtj[0, 4] = s40
    jtj[4, 1] = jtj[1, 4] = s41
    jtj[4, 2] = jtj[2, 4] = s42
    jtj[4, 3] = jtj[3, 4] = s43
    jtj[5, 0] = jtj[0, 5] = s50
    jtj[5, 1] = jtj[1, 5] = s51
    jtj[5, 2] = jtj[2, 5] = s52
    jtj[5, 3] = jtj[3, 5] = s53
    jtj[5, 4] = jtj[4, 5] = s54
    grad[0], grad[1], grad[2], grad[3], grad[4], grad[5] = g0, g1, g2, g3, g4, g5


@njit(cache=True, nogil=True)
def levenberg_marquardt(theta, toward, half, g, y, w, n_iter):  # pragma: no cover - compiled
    """:func:`ltmstore.solve.physical.levenberg_marquardt` of pixels ``theta (n, 6)`` (float64,
    updated in place) at near lights ``toward``, ``half (3, n, K)`` and fall-off ``g (n, K)``
    (float32) with values and weights ``y``, ``w (n, K)`` (float32). Returns each pixel's final
    cost ``(n,)``."""
    costs = np.empty(len(theta))
    jtj, grad = np.empty((6, 6)), np.empty(6)
    system, rhs, step, trial = np.empty((6, 6)), np.empty(6), np.empty(6), np.empty(6)
    for i in range(len(theta)):
        _clip(theta[i])
        cost = _cost(theta[i], toward, half, g, y, w, i)
        lam = 1e-2
        moved = True  # the normal equations are those of theta[i] until it moves
        for _ in range(n_iter):
            if moved:
                _system(theta[i], toward, half, g, y, w, i, jtj, grad)
            finite = _trial(theta[i], jtj, grad, lam, system, rhs, step, trial)
            trial_cost = _cost(trial, toward, half, g, y, w, i)
            moved = finite and trial_cost < cost
            if moved:
                theta[i, :] = trial
                cost = trial_cost
                lam /= 3
            else:
                lam *= 4
        costs[i] = cost
    return costs


@njit(cache=True, nogil=True, error_model="numpy")
def model(theta, toward, half, g, out):  # pragma: no cover - compiled
    """Fill ``out (n, K)`` with the model of pixels ``theta (n, 6)`` at near lights ``toward``,
    ``half (3, n, K)``, ``g (n, K)``: the values of
    :func:`ltmstore.solve.physical._model` (float32, its operations in its order: no
    ``fastmath``, whose contractions move a sharp lobe's values by up to 0.05 %), one loop per
    pixel."""
    f0, f1, pi = np.float32(0.0), np.float32(1.0), np.float32(np.pi)
    for i in range(theta.shape[0]):
        p, q = np.float32(theta[i, 0]), np.float32(theta[i, 1])
        rho, k = np.float32(theta[i, 2]), np.float32(theta[i, 3])
        a2, floor = np.exp(np.float32(2) * np.float32(theta[i, 4])), np.float32(theta[i, 5])
        norm = np.sqrt(f1 + p * p + q * q)
        for c in range(out.shape[1]):
            ndotl = (toward[2, i, c] - p * toward[0, i, c] - q * toward[1, i, c]) / norm
            ndoth = min(max((half[2, i, c] - p * half[0, i, c] - q * half[1, i, c]) / norm, f0),
                        f1)
            cos = ndotl if ndotl > f0 else f0
            inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
            lobe = a2 / pi * inv_u * inv_u * (norm / np.float32(4))
            out[i, c] = g[i, c] * (rho * cos + k * lobe) + floor


@njit(cache=True, nogil=True, error_model="numpy")
def lights(rs, axis, pixels, height, exponent, toward, half, g):  # pragma: no cover - compiled
    """Fill ``toward``, ``half (3, n, M)`` and ``g (n, M)`` (float32) with the light of the
    cells at ``rs (M, 2)`` as seen from the pixels at ``pixels (n, 2)`` (float32, plane units)
    on a plane at ``height``, with the LED's ``cos^exponent`` emission about each cell's axis
    ``axis (M, 3)`` (unit; straight down ``(0, 0, -1)`` for a level LED): the values of
    :func:`ltmstore.solve.physical.near_lights` in its operations and order (no
    ``fastmath``), without its ``(3, n, M)`` temporaries (0.05 against 0.12 s for 1024 pixels
    on 2500 cells)."""
    f0, f1 = np.float32(0.0), np.float32(1.0)
    z = np.float32(height)
    for i in range(pixels.shape[0]):
        for c in range(rs.shape[0]):
            x, y = rs[c, 0] - pixels[i, 0], rs[c, 1] - pixels[i, 1]
            dist2 = x * x + y * y + z * z
            dist = np.sqrt(dist2)
            tx, ty, tz = x / dist, y / dist, z / dist
            hz = tz + f1
            norm = np.sqrt(tx * tx + ty * ty + hz * hz)
            toward[0, i, c], toward[1, i, c], toward[2, i, c] = tx, ty, tz
            half[0, i, c], half[1, i, c], half[2, i, c] = tx / norm, ty / norm, hz / norm
            emitted = -(tx * axis[c, 0] + ty * axis[c, 1] + tz * axis[c, 2])
            g[i, c] = max(emitted, f0) ** exponent / dist2
