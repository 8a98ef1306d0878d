"""Compiled Levenberg-Marquardt of :mod:`ltmstore.solve.physical` for far lights, and the
model's images: :func:`render` (the model at every light) and :func:`blend` (a surface blend's
relit image in one pass per pixel: with the rest of that change a 24 MP relight 188 -> 48 s,
``docs/share.md``).

A classic RTI capture lights every pixel from the same directions, so each pixel's fit is a small
independent problem: six parameters, one value per light. NumPy spends most of that fit building
``(pixels, lights)`` temporaries for the model, its Jacobian and the normal equations; this module
fuses them into one loop per pixel (Numba), the same model and steps as
:func:`ltmstore.solve.physical.levenberg_marquardt`: float32 model and Jacobian, float32 sums of
the normal equations, the damped system solved in float64, a step kept only where it lowers the
pixel's cost. Measured on the coin (4096 pixels, 48 lights, one core, load 2): the
Levenberg-Marquardt steps 4x faster, a whole ``surface.fit_pixels`` 0.14 s against 0.35 s;
parameters equal to float32 rounding, held-out PSNR within 0.002 dB. The lobe is GGX's or
Beckmann's (:func:`_beckmann`, a flag of every call): GGX's fit of 4096 pixels of the coin took
as long with the flag as without (medians of 7: 0.229 and 0.272 s against 0.232 and 0.263 s,
load 4), its parameters equal but for float32 rounding (6e-7 in log alpha at the median).

The kernels compile on first use (about 5 s, once) and are cached on disk (``cache=True``);
loading them and Numba costs a far-light ``ltm reconstruct`` about 1-1.5 s of CPU, which
:func:`warm_up` lets a thread pay beside the work that needs no kernel. ``fastmath`` only
reorders sums (no assumption that values are finite). ``error_model="numpy"``: a division by
zero gives infinity or NaN instead of a check and a branch per division, which is what lets
LLVM vectorise the loop over lights of :func:`_system` (float32 SIMD lanes; 2.2x less CPU per
pixel and iteration on the coin, 48 lights: 0.31 against 0.69 us; the whole Levenberg-Marquardt
1.6x) and of :func:`_cost` (on an AMD EPYC with AVX2: 0.09 against 0.26 us on the coin's 40
lights, 0.21 against 1.19 us on loewenkopf's 200; an older CPU had found it slower, 0.21 against
0.16 us).

:func:`fit_colour` is the whole colour fit of :func:`ltmstore.solve.physical.fit_colour` (both
starts, the better one continued, the robust refit, each channel's linear terms) pixel by pixel,
without NumPy's ``(pixels, lights)`` temporaries between the steps: with the vectorised cost,
``ltm reconstruct``'s refinement 8-10 % faster on the coin, the icon, loewenkopf and a 1 MP
SynthRTI capture (``docs/benchmarks.md``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Reassociation only: NaN and infinity keep their meaning in comparisons, and the kernels give
# the same values compiled afresh as loaded from Numba's cache. With "contract" (or "nsz" or
# "arcp" beside "reassoc") a freshly compiled kernel's fit differed from the cached one's in
# almost every pixel (up to 2e-3 of a parameter), so a store depended on whether the cache was
# warm (tests/solve/test_physical_far.py). The kernel costs 1.5x the CPU of all four flags.
FASTMATH = {"reassoc"}
LOG_ALPHA = (float(np.log(0.02)), 0.0)  # physical.ALPHA_RANGE, as the bounds of log alpha
SLOPE_MAX = 3.0  # physical.SLOPE_MAX
DAMPING_MAX = 1e6  # a pixel whose damping grows past this has converged (its steps vanish)
COS_MIN = 1e-3  # physical.COS_MIN


@njit(cache=True, fastmath=FASTMATH, inline="always")
def _beckmann(ndoth, a2):  # pragma: no cover - compiled
    """Beckmann's ``D(n.H)`` and its derivatives in ``n.H`` and ``log alpha`` (float32)."""
    f1 = np.float32(1.0)
    c = max(ndoth, np.float32(COS_MIN))
    c2 = c * c
    tan2 = (f1 - c2) / c2
    dist = np.exp(-tan2 / a2) / (np.float32(np.pi) * a2 * c2 * c2)
    dd_dc = dist * (np.float32(2) / (c2 * c * a2) - np.float32(4) / c)
    return dist, dd_dc, dist * (np.float32(2) * tan2 / a2 - np.float32(2))


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _cost(theta, toward, half, y, w, beckmann):  # pragma: no cover - compiled
    """Weighted squared error of one pixel's model at ``theta (6,)`` (float32 sums), its lobe
    GGX or ``beckmann``."""
    f0, f1, pi = np.float32(0.0), np.float32(1.0), np.float32(np.pi)
    p, q = np.float32(theta[0]), np.float32(theta[1])
    rho, k = np.float32(theta[2]), np.float32(theta[3])
    a2, floor = np.float32(np.exp(2 * theta[4])), np.float32(theta[5])
    norm = np.float32(np.sqrt(1 + p * p + q * q))
    cost = f0
    for c in range(y.shape[0]):
        ndotl = (toward[2, c] - p * toward[0, c] - q * toward[1, c]) / norm
        ndoth = min(max((half[2, c] - p * half[0, c] - q * half[1, c]) / norm, f0), f1)
        cos = ndotl if ndotl > f0 else f0
        if beckmann:
            dist = _beckmann(ndoth, a2)[0]
        else:
            inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
            dist = a2 / pi * inv_u * inv_u
        lobe = dist * (norm / np.float32(4))
        r = rho * cos + k * lobe + floor - y[c]
        cost += w[c] * r * r
    return cost


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _system(theta, toward, half, y, w, beckmann, jtj, grad):  # pragma: no cover - compiled
    """Fill ``jtj (6, 6)`` and ``grad (6,)`` with ``J^T W J`` and ``J^T W r`` of one pixel's
    residuals ``r = model - y`` at ``theta (6,)`` (float32 sums, as NumPy's)."""
    f0, f1, pi = np.float32(0.0), np.float32(1.0), np.float32(np.pi)
    p, q = np.float32(theta[0]), np.float32(theta[1])
    rho, k = np.float32(theta[2]), np.float32(theta[3])
    a2, floor = np.float32(np.exp(2 * theta[4])), np.float32(theta[5])
    norm = np.float32(np.sqrt(1 + p * p + q * q))
    s00 = s10 = s11 = s20 = s21 = s22 = s30 = s31 = s32 = s33 = f0
    s40 = s41 = s42 = s43 = s44 = s50 = s51 = s52 = s53 = s54 = s55 = f0
    g0 = g1 = g2 = g3 = g4 = g5 = f0
    for c in range(y.shape[0]):
        ndotl = (toward[2, c] - p * toward[0, c] - q * toward[1, c]) / norm
        ndoth = min(max((half[2, c] - p * half[0, c] - q * half[1, c]) / norm, f0), f1)
        lit = ndotl > f0
        cos = ndotl if lit else f0
        if beckmann:
            dist, dd_dc, dd_dl = _beckmann(ndoth, a2)
        else:
            inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
            dist = a2 / pi * inv_u * inv_u
            dd_dc = np.float32(-4) * (a2 - f1) * ndoth * inv_u * dist
            dd_dl = np.float32(2) * dist * (f1 - np.float32(2) * a2 * ndoth * ndoth * inv_u)
        lobe = dist * (norm / np.float32(4))
        r = rho * cos + k * lobe + floor - y[c]
        wc = w[c]
        dcos = (-toward[0, c] - ndotl * p / norm) / norm if lit else f0
        dc = (-half[0, c] - ndoth * p / norm) / norm
        j0 = rho * dcos + k * ((dd_dc * dc * norm + dist * p / norm) / np.float32(4))
        dcos = (-toward[1, c] - ndotl * q / norm) / norm if lit else f0
        dc = (-half[1, c] - ndoth * q / norm) / norm
        j1 = rho * dcos + k * ((dd_dc * dc * norm + dist * q / norm) / np.float32(4))
        j4 = k * dd_dl * (norm / np.float32(4))
        w0, w1, w2, w3, w4 = wc * j0, wc * j1, wc * cos, wc * lobe, wc * j4
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
        s22 += w2 * cos
        s30 += w3 * j0
        s31 += w3 * j1
        s32 += w3 * cos
        s33 += w3 * lobe
        s40 += w4 * j0
        s41 += w4 * j1
        s42 += w4 * cos
        s43 += w4 * lobe
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


@njit(cache=True, error_model="numpy")
def _solve(a, b, out):  # pragma: no cover - compiled
    """``out = a^-1 b`` for one step's ``(6, 6)`` system (:func:`_gauss`)."""
    _gauss(a, b, out, 6)


@njit(cache=True, inline="always", error_model="numpy")
def _gauss(a, b, out, n):  # pragma: no cover - compiled
    """``out = a^-1 b`` for one ``(n, n)`` system: Gaussian elimination, partial pivoting (``a``
    and ``b`` are overwritten). A zero pivot gives NaN, a step no pixel keeps. Inlined where
    ``n`` is a constant, whose loops then unroll (a 6 x 6 solve 25 % faster)."""
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, n):
            factor = a[row, col] / a[col, col]
            for j in range(col, n):
                a[row, j] -= factor * a[col, j]
            b[row] -= factor * b[col]
    for row in range(n - 1, -1, -1):
        total = b[row]
        for j in range(row + 1, n):
            total -= a[row, j] * out[j]
        out[row] = total / a[row, row]


@njit(cache=True)
def _clip(theta):  # pragma: no cover - compiled
    """:func:`ltmstore.solve.physical._clip` of one pixel's parameters, in place."""
    for i in range(2):
        theta[i] = min(max(theta[i], -SLOPE_MAX), SLOPE_MAX)
    theta[2] = max(theta[2], 0.0)
    theta[3] = max(theta[3], 0.0)
    theta[4] = min(max(theta[4], LOG_ALPHA[0]), LOG_ALPHA[1])
    theta[5] = max(theta[5], 0.0)


@njit(cache=True, nogil=True)  # nogil: surface.fit_image runs blocks on threads
def levenberg_marquardt(theta, toward, half, y, w, beckmann, n_iter,
                        tol):  # pragma: no cover - compiled
    """:func:`ltmstore.solve.physical.levenberg_marquardt` of pixels ``theta (n, 6)`` (float64,
    updated in place) at far lights ``toward``, ``half (3, M)`` (float32) with values and
    weights ``y``, ``w (n, M)`` (float32), the lobe GGX or ``beckmann`` (bool): at most
    ``n_iter`` steps, fewer where a step lowers the pixel's cost by at most ``tol`` times it or
    the damping passes :data:`DAMPING_MAX`. Returns each pixel's final cost ``(n,)``."""
    costs = np.empty(len(theta))
    work = _scratch()
    for i in range(len(theta)):
        costs[i] = _steps(theta[i], toward, half, y[i], w[i], beckmann, n_iter, tol, work)
    return costs


@njit(cache=True)
def _scratch():  # pragma: no cover - compiled
    """One pixel's scratch arrays of :func:`_steps`: ``J^T W J``, ``J^T W r``, the damped system,
    its right-hand side, the step and the trial parameters."""
    return (np.empty((6, 6)), np.empty(6), np.empty((6, 6)), np.empty(6), np.empty(6),
            np.empty(6))


@njit(cache=True, nogil=True)
def _steps(theta, toward, half, y, w, beckmann, n_iter, tol, work):  # pragma: no cover
    """:func:`levenberg_marquardt` of one pixel's ``theta (6,)`` (in place), values and weights
    ``y``, ``w (M,)``, with the scratch arrays ``work`` (:func:`_scratch`); its final cost."""
    jtj, grad, system, rhs, step, trial = work
    _clip(theta)
    cost = _cost(theta, toward, half, y, w, beckmann)
    lam = 1e-2
    moved = True  # the normal equations are those of theta until it moves
    for _ in range(n_iter):
        if moved:
            _system(theta, toward, half, y, w, beckmann, jtj, grad)
        finite = _trial(theta, jtj, grad, lam, system, rhs, step, trial)
        trial_cost = _cost(trial, toward, half, y, w, beckmann)
        moved = finite and trial_cost < cost
        if moved:
            theta[:] = trial
            done = cost - trial_cost <= tol * cost
            cost = trial_cost
            lam /= 3
            if done:
                break
        else:
            lam *= 4
            if lam > DAMPING_MAX:
                break
    return cost


@njit(cache=True, inline="always")
def _trial(theta, jtj, grad, lam, system, rhs, step, trial):  # pragma: no cover - compiled
    """``trial (6,)``: ``theta`` plus the step of the normal equations ``jtj``, ``grad`` damped
    by ``lam`` (Marquardt's scaling), within the bounds; whether the step is finite."""
    for a in range(6):
        for b in range(6):
            system[a, b] = jtj[a, b]
        system[a, a] += lam * (jtj[a, a] + 1e-12)
        rhs[a] = -grad[a]
    _solve(system, rhs, step)
    finite = True
    for a in range(6):
        trial[a] = theta[a] + step[a]
        finite = finite and np.isfinite(step[a])
    _clip(trial)
    return finite


@njit(cache=True, nogil=True, error_model="numpy")
def fit_colour(rgb, toward, half, beckmann, luma, log_starts, start_iter, n_iter, robust_iter,
               tol, robust_scale, out):  # pragma: no cover - compiled
    """:func:`ltmstore.solve.physical.fit_colour` of pixels ``rgb (n, M, 3)`` (float32, linear)
    at far lights ``toward``, ``half (3, M)`` (float32), into ``out (n, 3, 6)`` (float64), one
    pixel at a time with no ``(n, M)`` temporaries: the luminance (weights ``luma``), its fit
    from the flat and the mirror start (``log_starts``: their log alpha) ``start_iter`` steps
    each, ``n_iter`` more from the better, Cauchy weights of scale ``robust_scale`` robust
    standard deviations and ``robust_iter`` steps with them; then each channel's ``rho, k, a``
    at that geometry by weighted least squares. The same operations as NumPy's, their sums in
    another order (float32 rounding)."""
    m = rgb.shape[1]
    lum = np.empty(m)
    y, w, ones = np.empty(m, np.float32), np.empty(m, np.float32), np.ones(m, np.float32)
    cos, lobe, res = np.empty(m, np.float32), np.empty(m, np.float32), np.empty(m)
    work = _scratch()
    starts, costs = np.zeros((2, 6)), np.empty(2)
    for i in range(rgb.shape[0]):
        for c in range(m):
            lum[c] = luma[0] * rgb[i, c, 0] + luma[1] * rgb[i, c, 1] + luma[2] * rgb[i, c, 2]
            y[c] = lum[c]
        brightest = np.argmax(lum)
        starts[:] = 0.0
        starts[1, 0] = -half[0, brightest] / half[2, brightest]
        starts[1, 1] = -half[1, brightest] / half[2, brightest]
        for s in range(2):
            starts[s, 4] = log_starts[s]
            _clip(starts[s])
            _geometry(starts[s], toward, half, beckmann, cos, lobe)
            _linear(starts[s], cos, lobe, y, ones, starts[s])
            costs[s] = _steps(starts[s], toward, half, y, ones, beckmann, start_iter, tol, work)
        theta = starts[1] if costs[1] < costs[0] else starts[0]  # the mirror where strictly better
        _steps(theta, toward, half, y, ones, beckmann, n_iter, tol, work)
        _robust(theta, toward, half, beckmann, lum, robust_scale, cos, lobe, res, w)
        _steps(theta, toward, half, y, w, beckmann, robust_iter, tol, work)
        _geometry(theta, toward, half, beckmann, cos, lobe)  # the same for the three channels
        if not beckmann and theta[4] >= LOG_ALPHA[1]:
            lobe[:] = 0.0  # GGX's lobe as flat as the floor (physical.fit_colour)
        for c in range(3):
            for k in range(m):
                y[k] = rgb[i, k, c]
            _linear(theta, cos, lobe, y, w, out[i, c])


@njit(cache=True, inline="always", error_model="numpy")
def _geometry(theta, toward, half, beckmann, cos, lobe):  # pragma: no cover - compiled
    """:func:`_shading` of ``theta (6,)``'s normal and roughness, the values cast to float32
    and ``alpha^2`` by float32's ``exp`` (as NumPy's :func:`ltmstore.solve.physical._basis`)."""
    p, q = np.float32(theta[0]), np.float32(theta[1])
    a2 = np.exp(np.float32(2) * np.float32(theta[4]))
    _shading(p, q, a2, toward, half, beckmann, cos, lobe)


@njit(cache=True, error_model="numpy")
def _linear(theta, cos, lobe, y, w, out):  # pragma: no cover - compiled
    """``out (6,)``: ``theta`` with ``rho, k, a`` replaced by their non-negative weighted least
    squares on the shading ``cos``, ``lobe (M,)`` of its normal and roughness (:func:`_geometry`;
    float32 sums, the 3 x 3 system in float64), as
    :func:`ltmstore.solve.physical._linear_terms`."""
    f0 = np.float32(0.0)
    s00 = s10 = s11 = s20 = s21 = s22 = b0 = b1 = b2 = f0
    for c in range(len(y)):
        w0, w1, w2 = w[c] * cos[c], w[c] * lobe[c], w[c]
        s00 += w0 * cos[c]
        s10 += w1 * cos[c]
        s11 += w1 * lobe[c]
        s20 += w0
        s21 += w1
        s22 += w2
        b0 += w0 * y[c]
        b1 += w1 * y[c]
        b2 += w2 * y[c]
    a = np.array([[s00 + 1e-12, s10, s20], [s10, s11 + 1e-12, s21], [s20, s21, s22 + 1e-12]])
    coef = np.empty(3)
    _gauss(a, np.array([b0, b1, b2], dtype=np.float64), coef, 3)
    out[:] = theta
    out[2], out[3], out[5] = max(coef[0], 0.0), max(coef[1], 0.0), max(coef[2], 0.0)


@njit(cache=True, error_model="numpy")
def _robust(theta, toward, half, beckmann, lum, scale, cos, lobe, res,
            w):  # pragma: no cover - compiled
    """Cauchy weights ``w (M,)`` of one pixel's residuals against its luminance ``lum (M,)``
    over ``scale`` of their robust standard deviation, as
    :func:`ltmstore.solve.physical._robust_weights` with every light observed."""
    _geometry(theta, toward, half, beckmann, cos, lobe)
    rho, k, floor = np.float32(theta[2]), np.float32(theta[3]), np.float32(theta[5])
    top = 0.0
    for c in range(len(lum)):
        res[c] = (rho * cos[c] + k * lobe[c] + floor) - lum[c]
        top = max(top, abs(lum[c]))
    spread = scale * 1.4826 * np.median(np.abs(res)) + max(1e-9 * top, 1e-30)
    for c in range(len(lum)):
        r = res[c] / spread
        w[c] = 1.0 / (1.0 + r * r)


@njit(cache=True, nogil=True, error_model="numpy")
def render(p, q, a2, linear, toward, half, gain, beckmann, out):  # pragma: no cover - compiled
    """The model of pixels ``(n,)`` at far lights ``toward``, ``half (3, M)`` (float32), into
    ``out (n, M, C)`` (float32): per channel ``c`` the slopes ``p``, ``q``, the roughness
    ``a2 = alpha^2`` ``(n, C)`` and ``rho, k, a = linear (n, C, 3)``, the lights' gain ``(n,
    M)`` (their shadows; ones for none), the lobe GGX or ``beckmann``. The same float32
    operations in the same order as :func:`ltmstore.solve.physical._model` (GGX's values equal
    NumPy's bit for bit; Beckmann's ``exp`` may differ in its last bit), without its ``(n, M)``
    temporaries; a channel of the same geometry as the one before reuses its shading."""
    cos = np.empty(toward.shape[1], np.float32)
    lobe = np.empty(toward.shape[1], np.float32)
    for i in range(len(p)):
        for c in range(p.shape[1]):
            if c == 0 or p[i, c] != p[i, c - 1] or q[i, c] != q[i, c - 1] or (
                    a2[i, c] != a2[i, c - 1]):
                _shading(p[i, c], q[i, c], a2[i, c], toward, half, beckmann, cos, lobe)
            rho, k, floor = linear[i, c, 0], linear[i, c, 1], linear[i, c, 2]
            for m in range(toward.shape[1]):
                out[i, m, c] = gain[i, m] * (rho * cos[m] + k * lobe[m]) + floor


@njit(cache=True, inline="always", error_model="numpy")
def _shading(p, q, a2, toward, half, beckmann, cos, lobe):  # pragma: no cover - compiled
    """``max(n.l, 0)`` and ``D(n.H) / (4 n.v)`` of one geometry at every light, into ``cos``
    and ``lobe (M,)``, as :func:`ltmstore.solve.physical._model` computes them."""
    f0, f1, pi, four = np.float32(0.0), np.float32(1.0), np.float32(np.pi), np.float32(4.0)
    norm = np.sqrt(f1 + p * p + q * q)
    quarter = norm / four
    for m in range(toward.shape[1]):
        ndotl = (toward[2, m] - p * toward[0, m] - q * toward[1, m]) / norm
        ndoth = (half[2, m] - p * half[0, m] - q * half[1, m]) / norm
        if ndoth < f0:  # np.clip's: NaN stays NaN
            ndoth = f0
        elif ndoth > f1:
            ndoth = f1
        cos[m] = ndotl if ndotl > f0 else f0
        if beckmann:
            dist = _beckmann(ndoth, a2)[0]
        else:
            inv_u = f1 / (ndoth * ndoth * (a2 - f1) + f1)
            dist = a2 / pi * inv_u * inv_u
        lobe[m] = dist * quarter


@njit(cache=True, nogil=True, error_model="numpy")
def blend(frames, frame_weights, p, q, a2, linear, train, train_half, train_gain, model_weights,
          query, query_half, query_gain, weight, beckmann, out):  # pragma: no cover - compiled
    """A blend's encoded image at the lights ``query`` of pixels ``(P,)``, into ``out (d, P,
    C)`` (float32): ``frame_weights.T @ frames (n, P, C) + model_weights.T @ srgb(M(train)) +
    weight srgb(M(query))`` (the weights ``(n, d)``, float64), its sums in float64 pixel by
    pixel (the same in every block), the model ``M`` of :func:`render` (its arguments alike;
    ``train``, ``query``: the lights' ``toward``, with ``train_half``, ``query_half``; a gain
    of shape ``(0, 0)``: no shadows) clipped at 0 and sRGB-encoded as
    :func:`ltmstore.core.transfer.linear_to_srgb`. Neither the model's images at the
    photographs' lights nor their float64 copies are held."""
    n, d = train.shape[1], query.shape[1]
    cos_t, lobe_t = np.empty(n, np.float32), np.empty(n, np.float32)
    cos_q, lobe_q = np.empty(d, np.float32), np.empty(d, np.float32)
    total = np.empty(d)
    weight = np.float32(weight)
    for i in range(len(p)):
        for c in range(p.shape[1]):
            if c == 0 or p[i, c] != p[i, c - 1] or q[i, c] != q[i, c - 1] or (
                    a2[i, c] != a2[i, c - 1]):
                _shading(p[i, c], q[i, c], a2[i, c], train, train_half, beckmann, cos_t,
                         lobe_t)
                _shading(p[i, c], q[i, c], a2[i, c], query, query_half, beckmann, cos_q,
                         lobe_q)
            rho, k, floor = linear[i, c, 0], linear[i, c, 1], linear[i, c, 2]
            total[:] = 0.0
            for m in range(n):
                shade = rho * cos_t[m] + k * lobe_t[m]
                if train_gain.shape[0]:
                    shade *= train_gain[i, m]
                model = _encode(shade + floor)
                frame = frames[m, i, c]
                for j in range(d):
                    total[j] += frame_weights[m, j] * frame + model_weights[m, j] * model
            for j in range(d):
                shade = rho * cos_q[j] + k * lobe_q[j]
                if query_gain.shape[0]:
                    shade *= query_gain[i, j]
                out[j, i, c] = np.float32(total[j]) + weight * _encode(shade + floor)


@njit(cache=True, inline="always", error_model="numpy")
def _encode(v):  # pragma: no cover - compiled
    """:func:`ltmstore.core.transfer.linear_to_srgb` of one float32 value (NaN stays NaN)."""
    if v < np.float32(0.0):
        v = np.float32(0.0)
    elif v > np.float32(1.0):
        v = np.float32(1.0)
    if v <= np.float32(0.0031308):
        return v * np.float32(12.92)
    return v ** np.float32(1 / 2.4) * np.float32(1.055) - np.float32(0.055)


def warm_up() -> None:
    """Load the compiled kernels (from Numba's cache, or compile them) with a fit of one pixel,
    so that the first real fit finds them ready; :mod:`ltmstore.stages.reconstruct_far` calls
    it on a thread (Numba's import and first dispatch hold the GIL most of the time, and overlap
    with what releases it: reading and decoding the frames, BLAS)."""
    theta = np.zeros((1, 6))
    lights = np.ones((3, 2), dtype=np.float32)
    lights.flags.writeable = False  # as physical.far_lights' (broadcast) rows: one signature
    values = np.ones((1, 2), dtype=np.float32)
    levenberg_marquardt(theta, lights, lights, values, values, False, 1, 0.0)
    fit_colour(np.ones((1, 2, 3), dtype=np.float32), lights, lights, False, np.ones(3),
               np.zeros(2), 1, 1, 1, 0.0, 1.0, np.empty((1, 3, 6)))
