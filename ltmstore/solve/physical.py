"""A physical reflectance model per pixel, plus the interpolated residual of what it misses.

Every pixel is a surface point ``P = (X, Y, 0)`` (``geometry.pixels``) with a unit normal ``n``, a
diffuse albedo ``rho``, a specular lobe of strength ``k`` and roughness ``alpha`` (GGX; far
lights also Beckmann, ``Lights.lobe``), and an ambient floor ``a``; the light of lattice cell
``c`` sits at ``L = (r, s, h)``. With ``l`` the unit vector towards the light, ``d = |L - P|``
and the half vector ``H`` of ``l`` and the view
``v = (0, 0, 1)``::

    t(c) = g(c) (rho max(n.l, 0) + k D_GGX(n.H; alpha) / (4 n.v)) + a,   g = (h / d)^m / d^2

``g`` is the near light's inverse-square fall-off times the LED's ``cos^m`` emission about its
axis (``led_exponent``, one value per capture). The five parameters of each pixel are fitted to
its observed cells by batched Levenberg-Marquardt with an analytic Jacobian (every pixel of the
tile at once), from a few starts (a flat normal; the normal that mirrors the brightest
observation into the camera), keeping each pixel's best; a robust (Cauchy) reweighting keeps
cast shadows and interreflections out of the fit. The model and its Jacobian are evaluated in
float32, the normal equations solved in float64: 40 % less CPU per tile than all float64, the
same SNR (a 32 x 32 pixel tile of the relief: 0.6 s against 1.1 s, 37.37 dB both).

A cell's sample is the mean of frames lit anywhere inside it, not at its centre: where
``geometry.sampled`` gives each cell's mean light position, the model is fitted there (and
the residual taken there), and evaluated at the centres, where the LTM lives. On the 720 px
simulated canvas (16 x 16 lattice, 2.5 cm cells at 30 cm) fitting at the centres had cost 2.7
dB of SNR_Y, 4.0 dB under the LED's ``cos^2`` beam, whose steeper fall-off the offsets weigh
more.

The model is what fills the holes: a handheld path leaves the same cells unobserved for every
pixel, but a pixel's normal and albedo are seen in its diffuse shading everywhere, and the model
puts its highlight where the geometry says it is. Two more things make it a prior rather than a
straitjacket:

* **Shared lobes.** A pixel whose highlight falls in a hole has no evidence of its lobe (the
  share of the lobe's energy on observed cells is low); it takes the roughness and the
  specular-to-diffuse ratio of the pixels of the tile that did see theirs (weighted towards its
  own estimate by its evidence): one pixel's hole is filled by another's observations.
* **Residual.** What the model misses at the observed cells (cast shadows, interreflections, a
  lobe of another shape) is interpolated over the lattice (thin-plate RBF, one system for a
  shared mask) and damped with the distance from the nearest observation, so that far from the
  data the model speaks alone and at the data the result interpolates it.

Where it fails: without ``geometry.pixels`` (an acquisition that does not declare the object's
extent, and a capture that cannot place it, :mod:`ltmstore.stages.placement`) the near light's
direction is unknown: the method refuses. Anisotropic or layered
materials, and strongly non-planar objects (the light is computed for ``z = 0``), leave more in
the residual; ``--method auto`` then prefers another method by held-out error.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.solve.cache import Recent

if TYPE_CHECKING:
    from ltmstore.solve import Geometry

ALPHA_RANGE = (0.02, 1.0)  # roughness (the lobe's alpha) kept within these bounds
LOBES = ("ggx", "beckmann")  # microfacet distributions of the lobe (far lights: either)
COS_MIN = 1e-3  # n.H kept above this in Beckmann's distribution (its 1 / cos^4 at grazing)
SLOPE_MAX = 3.0  # |dh/dX|, |dh/dY| of a normal kept within this (72 degrees of tilt)
START_ITER = 5  # Levenberg-Marquardt iterations from each start ...
N_ITER = 10  # ... and from the better of them, per pixel
# ... or from a given start (a fit of the same pixels on more cells: a held-out fold,
# ltmstore.solve.confidence.expected_error), before the robust refit
WARM_ITER = 5
START_ALPHAS = (0.3, 0.1)  # roughness of the flat and of the mirror start (_starts)
ROBUST = 3.0  # Cauchy scale, in robust standard deviations of a pixel's residuals
DAMP_CELLS = 2.0  # the residual's weight falls as exp(-(distance / DAMP_CELLS cells)^2)
# --method auto chooses the residual's weight by held-out error (ltmstore.solve.select): on
# noise-free data the residual adds 6 dB, on noisy data the model alone is better by up to 10 dB
# (it does not interpolate the noise of the observed cells).
AUTO_GRID = {"residual": (0.0, 0.5, 1.0)}
# ... keeping the solver's 0.5 unless another weight predicts held-out cells clearly better,
# except on a path revisited beside most of its cells (Geometry.segment given): there the model
# alone is kept unless a weight predicts the hidden seconds clearly better. On the 720 px
# simulated canvas filmed 20 s (K/M 0.63), 20 tiles, the samples' noise hid the model's misfit
# (held-out errors of the three weights within 2 %): the model alone 45.5 dB against the truth
# (lossless) and 36.7 (H.264, 0.27 bits per pixel), 0.5 kept 45.0 and 35.5; on the tests' 32 px
# relief (revisited 0.55: single cells hidden) 0.5 kept 42.92, the model alone 42.22.
REVISITED_DEFAULT = {"residual": 0.0}
COMPILED = True  # near lights through the compiled kernel (False: the NumPy steps, for tests)
SHARE_EVIDENCE = 0.5  # a pixel that saw less of its highlight's peak takes the tile's roughness
# A far-light pixel stops iterating once a step lowers its cost by less than this fraction (or
# its damping passes physical_far.DAMPING_MAX): on the icon 20 % less time in the surface fit,
# held-out PSNR equal to 0.001 dB on five captures (the model moves by 7e-5 sRGB RMS)
CONVERGED = 1e-4


@dataclass(frozen=True, eq=False)
class Surface:
    """Per-pixel parameters of the reflectance model, each ``(n,)`` (``normal``: ``(n, 3)``).

    Attributes
    ----------
    normal : ndarray
        Unit surface normal, object-plane axes (``z`` towards the camera).
    albedo : ndarray
        Diffuse albedo times the light's intensity (the sample's units at unit distance).
    specular : ndarray
        Strength of the GGX lobe, same units.
    roughness : ndarray
        GGX ``alpha``.
    ambient : ndarray
        Constant floor (ambient light), the sample's units.
    evidence : ndarray
        Share of the lobe's energy over the lattice that falls on observed cells.
    """

    normal: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    ambient: np.ndarray
    evidence: np.ndarray


@dataclass(frozen=True, eq=False)
class Lights:
    """Unit vectors towards the light ``toward (3, n, M)``, half vectors ``half (3, n, M)`` (of
    those and the view ``(0, 0, 1)``) and the fall-off ``g (n, M)`` of every (pixel, cell);
    components first, so that each is a contiguous ``(n, M)`` array. ``lobe``: the microfacet
    distribution the model takes at these lights (one of :data:`LOBES`; near lights: GGX)."""

    toward: np.ndarray
    half: np.ndarray
    g: np.ndarray
    far: bool = False  # the same directions for every pixel, no fall-off (:func:`far_lights`)
    lobe: str = "ggx"

    def take(self, cells: np.ndarray) -> Lights:
        """The lights of the cells ``cells`` only."""
        return replace(self, toward=np.take(self.toward, cells, axis=-1),
                       half=np.take(self.half, cells, axis=-1),
                       g=np.take(self.g, cells, axis=-1))  # C-contiguous

    def rows(self, rows: np.ndarray) -> Lights:
        """The lights as seen from the pixels ``rows`` only."""
        return replace(self, toward=self.toward[:, rows], half=self.half[:, rows],
                       g=self.g[rows])


def near_lights(geometry: Geometry, *, led_exponent: float | None = None,
                sampled: bool = False) -> Lights:
    """The light of every lattice cell as seen from every pixel of ``geometry.pixels``
    (read-only arrays: the last :data:`CACHED_LIGHTS` are kept, since a tile's held-out fold
    and its fit see the same pixels); the LED's ``cos^led_exponent`` beam (None: the
    geometry's ``led_exponent``); ``sampled``: as each cell's samples were taken, at their
    mean light position (:meth:`Geometry.sample_positions`) with the beam about their mean
    LED axis (:attr:`Geometry.led_axis`), not at the centre with the LED held level."""
    if led_exponent is None:
        led_exponent = geometry.led_exponent
    if geometry.pixels is None:
        raise LtmError("method 'physical' needs each pixel's position on the object plane: "
                       "declare the object's extent in acquisition.json ('object')")
    cells = geometry.sample_positions() if sampled else geometry.positions()
    rs = np.ascontiguousarray(cells[:, :2], dtype=np.float32)
    axis = _led_axes(geometry if sampled else None, len(rs))
    pixels = np.ascontiguousarray(geometry.pixels, dtype=np.float32)
    if COMPILED:  # the same values without NumPy's temporaries
        from ltmstore.solve import physical_near

        key = (hashlib.sha1(rs.tobytes() + axis.tobytes() + pixels.tobytes()).hexdigest(),
               rs.shape, pixels.shape, float(geometry.height), float(led_exponent))
        found = _LIGHTS.get(key)
        if found is not None:
            return found
        shape = (len(pixels), len(rs))
        toward = np.empty((3, *shape), dtype=np.float32)
        half = np.empty((3, *shape), dtype=np.float32)
        g = np.empty(shape, dtype=np.float32)
        physical_near.lights(rs, axis, pixels, np.float32(geometry.height),
                             np.float32(led_exponent), toward, half, g)
        for array in (toward, half, g):
            array.flags.writeable = False
        found = Lights(toward, half, g)
        _LIGHTS.put(key, found)
        return found
    vec = np.empty((3, len(pixels), len(rs)), dtype=np.float32)
    vec[:2] = rs.T[:, None, :] - pixels.T[:, :, None]
    vec[2] = geometry.height
    dist2 = (vec**2).sum(axis=0)
    toward = vec / np.sqrt(dist2)
    half = toward.copy()
    half[2] += 1
    half /= np.sqrt((half**2).sum(axis=0))
    emitted = -np.einsum("jnc,cj->nc", toward, axis)  # cos of the angle off the LED's axis
    return Lights(toward, half, np.maximum(emitted, 0) ** np.float32(led_exponent) / dist2)


def _led_axes(geometry: Geometry | None, cells: int) -> np.ndarray:
    """The LED's axis at each cell ``(M, 3)`` float32: ``geometry``'s :attr:`~Geometry.led_axis`
    where known, straight down elsewhere (and everywhere for None)."""
    down = np.zeros((cells, 3), dtype=np.float32)
    down[:, 2] = -1
    if geometry is None or geometry.led_axis is None:
        return down
    axis = np.asarray(geometry.led_axis, dtype=np.float32)
    return np.ascontiguousarray(np.where(np.isfinite(axis).all(axis=1, keepdims=True), axis,
                                         down))


def unit_normal(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Unit normals ``(n, 3)`` of the slopes ``(p, q)`` (``n ~ (-p, -q, 1)``)."""
    return np.stack([-p, -q, np.ones_like(p)], axis=-1) / np.sqrt(1 + p * p + q * q)[:, None]


def _dot(vectors: np.ndarray, p: np.ndarray, q: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """``n . x`` for ``n = (-p, -q, 1) / norm`` and the vectors ``x (3, n, K)``."""
    return (vectors[2] - p * vectors[0] - q * vectors[1]) / norm


def _model(theta: np.ndarray, lights: Lights, jacobian: bool = False):
    """Model values ``(n, K)`` at parameters ``theta = (p, q, rho, k, log alpha, a)`` ``(n, 6)``,
    and with ``jacobian`` their derivatives ``(n, 6, K)``."""
    if COMPILED and not jacobian and not lights.far and lights.lobe == "ggx" and len(theta) and (
            lights.g.dtype == np.float32):  # the kernel computes GGX in float32, as NumPy does
        return _near_model(theta, lights)
    p, q, rho, k, log_alpha, floor = (c[:, None].astype(lights.g.dtype) for c in theta.T)
    norm = np.sqrt(1 + p * p + q * q)
    a2 = np.exp(2 * log_alpha)
    ndotl = _dot(lights.toward, p, q, norm)
    ndoth = np.clip(_dot(lights.half, p, q, norm), 0.0, 1.0)
    lit = ndotl > 0
    cos = np.where(lit, ndotl, 0.0)
    if not jacobian:
        dist = _distribution(ndoth, a2, lights.lobe)
        return lights.g * (rho * cos + k * (dist * (norm / 4))) + floor  # D / (4 n.v)
    dist, dd_dc, dd_dlog_alpha = _distribution(ndoth, a2, lights.lobe, jacobian=True)
    lobe = dist * (norm / 4)  # D / (4 n.v), n.v = 1 / norm
    g = lights.g
    value = g * (rho * cos + k * lobe) + floor
    jac = np.empty((len(theta), 6, value.shape[1]), dtype=value.dtype)
    for axis, slope in ((0, p), (1, q)):  # d(n.x)/dp = (-x_p - (n.x) p / norm) / norm
        dcos = np.where(lit, (-lights.toward[axis] - ndotl * slope / norm) / norm, 0.0)
        dc = (-lights.half[axis] - ndoth * slope / norm) / norm
        dlobe = (dd_dc * dc * norm + dist * slope / norm) / 4
        jac[:, axis] = g * (rho * dcos + k * dlobe)
    jac[:, 2] = g * cos
    jac[:, 3] = g * lobe
    jac[:, 4] = g * k * dd_dlog_alpha * (norm / 4)
    jac[:, 5] = 1.0
    return value, jac


def _distribution(ndoth: np.ndarray, a2: np.ndarray, lobe: str, *, jacobian: bool = False):
    """The lobe's ``D(n.H)`` (``lobe``: GGX or Beckmann, roughness ``alpha^2 = a2``), and with
    ``jacobian`` its derivatives in ``n.H`` and ``log alpha`` too."""
    if lobe == "beckmann":  # exp(-tan^2 / a2) / (pi a2 cos^4), as physical_far._beckmann
        c = np.maximum(ndoth, np.asarray(COS_MIN, dtype=ndoth.dtype))
        c2 = c * c
        tan2 = (1 - c2) / c2
        dist = np.exp(-tan2 / a2) / (np.pi * a2 * c2 * c2)
        if not jacobian:
            return dist
        return dist, dist * (2 / (c2 * c * a2) - 4 / c), dist * (2 * tan2 / a2 - 2)
    inv_u = 1 / (ndoth * ndoth * (a2 - 1) + 1)
    dist = a2 / np.pi * inv_u * inv_u  # GGX
    if not jacobian:
        return dist
    return (dist, -4 * (a2 - 1) * ndoth * inv_u * dist,
            2 * dist * (1 - 2 * a2 * ndoth * ndoth * inv_u))


def _near_model(theta: np.ndarray, lights: Lights) -> np.ndarray:
    """:func:`_model`'s values at near lights through
    :func:`ltmstore.solve.physical_near.model` (no ``(n, K)`` temporaries)."""
    from ltmstore.solve import physical_near

    out = np.empty(lights.g.shape, dtype=lights.g.dtype)
    toward, half, g = (np.ascontiguousarray(v) for v in (lights.toward, lights.half, lights.g))
    physical_near.model(np.ascontiguousarray(theta, dtype=np.float64), toward, half, g, out)
    return out


def _normal_equations(jac: np.ndarray, w: np.ndarray,
                      y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J^T W J (n, P, P)`` and ``J^T W y (n, P)`` of Jacobians ``(n, P, K)``, batched BLAS."""
    weighted = jac * w[:, None, :].astype(jac.dtype, copy=False)
    jtj = (weighted @ jac.transpose(0, 2, 1)).astype(np.float64)
    return jtj, (weighted @ y[..., None].astype(jac.dtype, copy=False))[..., 0].astype(np.float64)


def _basis(theta: np.ndarray, lights: Lights) -> np.ndarray:
    """``(n, 3, K)``: the model's derivatives in ``rho, k, a`` (it is linear in them), the same
    values as :func:`_model`'s Jacobian there without the rest of it."""
    p, q, log_alpha = (c[:, None].astype(lights.g.dtype) for c in theta[:, [0, 1, 4]].T)
    norm = np.sqrt(1 + p * p + q * q)
    a2 = np.exp(2 * log_alpha)
    ndotl = _dot(lights.toward, p, q, norm)
    ndoth = np.clip(_dot(lights.half, p, q, norm), 0.0, 1.0)
    basis = np.empty((len(theta), 3, lights.g.shape[1]), dtype=lights.g.dtype)
    basis[:, 0] = lights.g * np.where(ndotl > 0, ndotl, 0.0)
    basis[:, 1] = lights.g * (_distribution(ndoth, a2, lights.lobe) * (norm / 4))
    basis[:, 2] = 1.0
    return basis


def _linear_terms(theta: np.ndarray, lights: Lights, y: np.ndarray, w: np.ndarray, *,
                  basis: np.ndarray | None = None) -> np.ndarray:
    """``theta`` with ``rho, k, a`` replaced by their weighted least-squares values for its
    normal and roughness (non-negative; the variable-projection start of each fit);
    ``basis``: :func:`_basis` of ``theta`` where it is already at hand."""
    basis = _basis(theta, lights) if basis is None else basis  # linear in rho, k, a
    ata, atb = _normal_equations(basis, w, y)
    coef = np.maximum(np.linalg.solve(ata + 1e-12 * np.eye(3), atb[..., None])[..., 0], 0.0)
    out = theta.copy()
    out[:, [2, 3, 5]] = coef
    return out


def _clip(theta: np.ndarray) -> np.ndarray:
    theta[:, :2] = np.clip(theta[:, :2], -SLOPE_MAX, SLOPE_MAX)
    theta[:, 2:4] = np.maximum(theta[:, 2:4], 0.0)
    theta[:, 4] = np.clip(theta[:, 4], *np.log(ALPHA_RANGE))
    theta[:, 5] = np.maximum(theta[:, 5], 0.0)
    return theta


def _cost(theta, lights, y, w) -> np.ndarray:
    return (w * (_model(theta, lights) - y) ** 2).sum(axis=1)


def levenberg_marquardt(theta: np.ndarray, lights: Lights, y: np.ndarray, w: np.ndarray, *,
                        n_iter: int = N_ITER) -> tuple[np.ndarray, np.ndarray]:
    """Minimise each pixel's weighted squared error over ``theta (n, 6)``, all pixels at once
    (one damping factor per pixel, a step kept only where it lowers that pixel's cost).
    Returns the parameters and each pixel's final cost. Far lights
    (:func:`far_lights`) take the compiled kernel of :mod:`ltmstore.solve.physical_far`, near
    lights that of :mod:`ltmstore.solve.physical_near` (unless :data:`COMPILED` is off): the
    same steps pixel by pixel."""
    if lights.far and len(theta):
        return _far_levenberg_marquardt(theta, lights, y, w, n_iter=n_iter)
    if COMPILED and lights.lobe == "ggx" and len(theta):  # the near kernel's lobe is GGX
        return _near_levenberg_marquardt(theta, lights, y, w, n_iter=n_iter)
    theta = _clip(theta.copy())
    cost = _cost(theta, lights, y, w)
    lam = np.full(len(theta), 1e-2)
    for _ in range(n_iter):
        value, jac = _model(theta, lights, jacobian=True)
        jtj, grad = _normal_equations(jac, w, value - y)
        diag = np.einsum("nii->ni", jtj) + 1e-12
        system = jtj + (lam[:, None] * diag)[:, :, None] * np.eye(6)
        step = np.linalg.solve(system, -grad[..., None])[..., 0]
        trial = _clip(theta + step)
        trial_cost = _cost(trial, lights, y, w)
        better = trial_cost < cost
        theta[better], cost[better] = trial[better], trial_cost[better]
        lam = np.where(better, lam / 3, lam * 4)
    return theta, cost


def _far_levenberg_marquardt(theta: np.ndarray, lights: Lights, y: np.ndarray, w: np.ndarray,
                             *, n_iter: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`levenberg_marquardt` at far lights, compiled (imported here: Numba's import
    costs the commands that never fit far lights)."""
    from ltmstore.solve import physical_far

    out = np.array(theta, dtype=np.float64, order="C")
    toward, half = (np.ascontiguousarray(v[:, 0], dtype=np.float32)
                    for v in (lights.toward, lights.half))
    y32, w32 = (np.ascontiguousarray(v, dtype=np.float32) for v in (y, w))
    cost = physical_far.levenberg_marquardt(out, toward, half, y32, w32,
                                            lights.lobe == "beckmann", n_iter, CONVERGED)
    return out, cost


def _near_levenberg_marquardt(theta: np.ndarray, lights: Lights, y: np.ndarray, w: np.ndarray,
                              *, n_iter: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`levenberg_marquardt` at near lights, compiled
    (:mod:`ltmstore.solve.physical_near`; imported here, as the far kernel)."""
    from ltmstore.solve import physical_near

    out = np.array(theta, dtype=np.float64, order="C")
    toward, half, g, y32, w32 = (np.ascontiguousarray(v, dtype=np.float32)
                                 for v in (lights.toward, lights.half, lights.g, y, w))
    cost = physical_near.levenberg_marquardt(out, toward, half, g, y32, w32, n_iter)
    return out, cost


def _starts(lights: Lights, y: np.ndarray, w: np.ndarray) -> list[np.ndarray]:
    """Initial parameters: a flat normal with a rough lobe, and the normal that mirrors each
    pixel's brightest observation (relative to its fall-off) into the camera, with a sharp one."""
    n = len(y)
    flat = np.zeros((n, 6))
    flat[:, 4] = np.log(START_ALPHAS[0])
    brightest = np.argmax(np.where(w > 0, y / lights.g, -np.inf), axis=1)
    half = lights.half[:, np.arange(n), brightest].T
    mirror = np.zeros((n, 6))
    mirror[:, 0], mirror[:, 1] = -half[:, 0] / half[:, 2], -half[:, 1] / half[:, 2]
    mirror[:, 4] = np.log(START_ALPHAS[1])
    return [_linear_terms(_clip(t), lights, y, w) for t in (flat, mirror)]


def _robust_weights(theta, lights, y, observed) -> np.ndarray:
    """Cauchy weights of each observation from its residual over the pixel's robust scale."""
    res = np.where(observed, _model(theta, lights) - y, 0.0)
    mad = _row_median(np.abs(res), observed)
    # the floor is the pixel's own (a batch's largest value made each pixel's fit depend on
    # the pixels fitted beside it)
    floor = np.maximum(1e-9 * np.abs(y).max(axis=1, keepdims=True), 1e-30)
    scale = ROBUST * 1.4826 * mad + floor
    return observed / (1 + (res / scale) ** 2)


def _row_median(values: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Median of each row's ``values`` at ``where`` ``(n, 1)`` (NaN for a row with none): what
    ``np.nanmedian`` gives with NaN elsewhere, without its loop over rows."""
    ordered = np.sort(np.where(where, values, np.inf), axis=1)
    k = where.sum(axis=1)
    lo, hi = (np.take_along_axis(ordered, np.maximum(i, 0)[:, None], axis=1)
              for i in ((k - 1) // 2, k // 2))
    with np.errstate(invalid="ignore"):
        return np.where(k[:, None] > 0, (lo + hi) / 2, np.nan)


def fit_parameters(y: np.ndarray, w: np.ndarray, lights: Lights, *, n_iter: int = N_ITER,
                   robust: bool = True,
                   start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The model's parameters ``theta = (p, q, rho, k, log alpha, a)`` ``(n, 6)`` fitted to
    values ``y (n, K)`` with weights ``w (n, K)`` (0: unobserved) at ``lights``: a few
    Levenberg-Marquardt iterations from each start (:func:`_starts`), then more from each
    pixel's better one, then (``robust``) a refit with Cauchy weights. ``start``: ``(n, 6)``
    parameters to start from instead (:data:`WARM_ITER` iterations from them, then the robust
    refit). Returns ``theta`` and the weights of the last fit."""
    if start is not None:
        best, _ = levenberg_marquardt(np.asarray(start, dtype=np.float64), lights, y, w,
                                      n_iter=WARM_ITER)
    else:
        fits = [levenberg_marquardt(theta, lights, y, w, n_iter=START_ITER)
                for theta in _starts(lights, y, w)]
        best, cost = fits[0]
        for theta, other in fits[1:]:
            better = other < cost
            best[better], cost[better] = theta[better], other[better]
        best, _ = levenberg_marquardt(best, lights, y, w, n_iter=n_iter)
    if robust:
        w = _robust_weights(best, lights, y, w > 0)
        best, _ = levenberg_marquardt(best, lights, y, w, n_iter=max(n_iter // 2, 1))
    return best, w


def far_lights(directions: np.ndarray, n: int, lobe: str = "ggx",
               visible: np.ndarray | None = None) -> Lights:
    """Distant lights at unit ``directions (M, 3)``, the same for all ``n`` pixels (no
    fall-off): a classic RTI capture; the model's ``lobe`` there (one of :data:`LOBES`).
    ``visible (n, M)``: how much of each light reaches each pixel (its cast shadows, 0 to 1,
    :mod:`ltmstore.solve.shadows`); the ambient floor is not shadowed."""
    if lobe not in LOBES:
        raise LtmError(f"lobe {lobe!r} is not one of {', '.join(LOBES)}")
    toward = np.ascontiguousarray(np.asarray(directions, dtype=np.float32).T)
    half = toward.copy()
    half[2] += 1
    half /= np.sqrt((half**2).sum(axis=0))
    shape = (3, n, toward.shape[1])
    gain = (np.ones(shape[1:], dtype=np.float32) if visible is None
            else np.ascontiguousarray(visible, dtype=np.float32).reshape(shape[1:]))
    return Lights(np.broadcast_to(toward[:, None], shape), np.broadcast_to(half[:, None], shape),
                  gain, far=True, lobe=lobe)


def fit_colour(rgb: np.ndarray, lights: Lights, *, n_iter: int = N_ITER,
               compiled: bool = True) -> np.ndarray:
    """Parameters ``(n, 3, 6)`` (per colour channel) fitted to linear RGB ``rgb (n, M, 3)``
    observed at every light: the normal and roughness from the luminance (one nonlinear fit),
    albedo, lobe strength and floor per channel (linear least squares at that geometry). Far
    lights without shadows take :func:`ltmstore.solve.physical_far.fit_colour` (unless
    ``compiled`` or :data:`COMPILED` is off): the same steps pixel by pixel."""
    from ltmstore.core.dims import LUMA

    if compiled and COMPILED and lights.far and len(rgb) and (lights.g == 1).all():
        return _far_fit_colour(rgb, lights, n_iter=n_iter)
    luminance = rgb @ LUMA
    theta, w = fit_parameters(luminance, np.ones_like(luminance), lights, n_iter=n_iter)
    basis = _basis(theta, lights)  # the same geometry for the three channels
    # At the largest roughness a far light's GGX lobe is as flat as the floor: their split was
    # left to rounding, and clipping the negative one at 0 could leave a pixel several times
    # brighter than its photographs. The floor takes it there (no lobe).
    if lights.lobe == "ggx":
        basis[theta[:, 4] >= np.log(ALPHA_RANGE[1]), 1] = 0.0
    return np.stack([_linear_terms(theta, lights, rgb[..., c], w, basis=basis)
                     for c in range(3)], axis=1)


def _far_fit_colour(rgb: np.ndarray, lights: Lights, *, n_iter: int) -> np.ndarray:
    """:func:`fit_colour` at far lights through the compiled
    :func:`ltmstore.solve.physical_far.fit_colour` (its steps as :func:`fit_parameters`')."""
    from ltmstore.core.dims import LUMA
    from ltmstore.solve import physical_far

    out = np.empty((len(rgb), 3, 6))
    physical_far.fit_colour(np.ascontiguousarray(rgb, dtype=np.float32),
                            *far_directions(lights), lights.lobe == "beckmann", LUMA,
                            np.log(START_ALPHAS), START_ITER, n_iter, max(n_iter // 2, 1),
                            CONVERGED, ROBUST, out)
    return out


def render_colour(theta: np.ndarray, lights: Lights, *, compiled: bool = True) -> np.ndarray:
    """Linear values ``(n, M, C)`` of per-channel parameters ``theta (n, C, 6)`` (RGB: ``C =
    3``) at ``lights``; far lights through the compiled :func:`_far_render` (unless
    ``compiled`` or :data:`COMPILED` is off: NumPy's, which needs no Numba)."""
    if compiled and COMPILED and lights.far and len(theta) and lights.g.dtype == np.float32:
        return _far_render(theta, lights)
    return np.stack([_model(theta[:, c], lights) for c in range(theta.shape[1])], axis=-1)


def _far_render(theta: np.ndarray, lights: Lights) -> np.ndarray:
    """:func:`render_colour` at far lights through :func:`ltmstore.solve.physical_far.render`
    (the same values, GGX's bit for bit, without NumPy's ``(n, M)`` temporaries: a 24 MP
    relight evaluates the model at every pixel and photograph's light)."""
    from ltmstore.solve import physical_far

    out = np.empty((len(theta), lights.g.shape[1], theta.shape[1]), dtype=np.float32)
    physical_far.render(*far_parameters(theta), *far_directions(lights), lights.g,
                        lights.lobe == "beckmann", out)
    return out


def far_parameters(theta: np.ndarray) -> tuple[np.ndarray, ...]:
    """The compiled far-light kernels' parameters (:mod:`ltmstore.solve.physical_far`) of
    ``theta (n, C, 6)``: ``p``, ``q``, ``a2 = alpha^2`` ``(n, C)`` and ``rho, k, a`` ``(n, C,
    3)``, float32 (``a2`` by NumPy's ``exp``, as :func:`_model`)."""
    params = np.asarray(theta, dtype=np.float32)
    return (np.ascontiguousarray(params[..., 0]), np.ascontiguousarray(params[..., 1]),
            np.exp(2 * params[..., 4]), np.ascontiguousarray(params[..., [2, 3, 5]]))


def far_directions(lights: Lights) -> tuple[np.ndarray, np.ndarray]:
    """``toward`` and ``half`` ``(3, M)`` of :func:`far_lights` (the same for every pixel)."""
    return (np.ascontiguousarray(lights.toward[:, 0]), np.ascontiguousarray(lights.half[:, 0]))


def fit_surface(samples: np.ndarray, geometry: Geometry, *, led_exponent: float | None = None,
                n_iter: int = N_ITER, robust: bool = True, share: bool = True,
                start: np.ndarray | None = None, at: np.ndarray | None = None,
                at_samples: bool = False) -> tuple[Surface, np.ndarray]:
    """Fit the model to each pixel's observed cells.

    Parameters
    ----------
    samples : ndarray, shape (n, R, S)
        Binned samples, NaN where unobserved.
    geometry : Geometry
        With ``pixels`` (each row's object-plane position).
    led_exponent : float, optional
        ``m`` of the LED's ``cos^m`` emission profile (default: ``geometry.led_exponent``).
    n_iter : int
        Levenberg-Marquardt iterations after the starts (:data:`START_ITER` each).
    robust : bool
        Refit once with Cauchy weights (shadows and glints the model does not hold count less).
    share : bool
        A pixel that saw too little of its own lobe (its highlight fell in a hole) takes the
        median roughness of the tile's pixels that saw theirs, and refits its strength.
    start : ndarray, shape (n, 6), optional
        Parameters to start the fit from (:func:`parameters` of an earlier fit of these pixels;
        see :func:`fit_parameters`).
    at : ndarray of int, optional
        Flat indices of the only cells where the model is wanted.
    at_samples : bool
        With ``at``: the model where those cells' samples were taken (``geometry.sampled``),
        which a held-out fold compares it with, not at their centres.

    Returns
    -------
    surface : Surface
    model : ndarray, shape (n, R * S)
        The model over the whole lattice (``(n, len(at))``: at the cells ``at``), at the
        cells' centres (``at_samples``: where their samples were taken).
    fitted : tuple of ndarray
        The observed cells (flat indices) and the model there, ``(n, len(cells))``, where
        their samples were taken (``geometry.sampled``): what the residual is taken against.
    """
    n = len(samples)
    flat = samples.reshape(n, -1)
    observed_all = np.isfinite(flat)
    cells = np.flatnonzero(observed_all.any(axis=0))
    lights_all = near_lights(geometry, led_exponent=led_exponent)
    seen = lights_all if geometry.sampled is None and geometry.led_axis is None else (
        near_lights(geometry, led_exponent=led_exponent, sampled=True))
    lights = seen.take(cells)  # fitted where the samples were taken
    # np.take keeps rows contiguous (flat[:, cells] is laid out column-major, and every
    # Levenberg-Marquardt call copied it for the kernel)
    observed = np.take(observed_all, cells, axis=1)
    y = np.where(observed, np.take(flat, cells, axis=1), 0.0).astype(np.float32)
    w = observed.astype(np.float32)
    best, w = fit_parameters(y, w, lights, n_iter=n_iter, robust=robust, start=start)
    evidence = _evidence(best, lights_all, observed_all)
    if share:  # the evidence again where the roughness changed (row by row: the same values)
        shared = _share_roughness(best, evidence, lights, w)
        changed = np.flatnonzero((shared != best).any(axis=1))
        if changed.size:
            evidence[changed] = _evidence(shared[changed], lights_all.rows(changed),
                                          observed_all[changed])
        best = shared
    normal = unit_normal(best[:, 0], best[:, 1])
    surface = Surface(normal=normal, albedo=best[:, 2], specular=best[:, 3],
                      roughness=np.exp(best[:, 4]), ambient=best[:, 5], evidence=evidence)
    wanted = lights_all if at is None else (seen if at_samples else lights_all).take(at)
    model = _model(best, wanted)
    return surface, model, (cells, _model(best, lights))


def _lobes(theta: np.ndarray, lights: Lights) -> np.ndarray:
    """Each pixel's lobe alone (unit strength, no diffuse, no floor) at ``lights``."""
    unit = theta.copy()
    unit[:, [2, 3, 5]] = [0.0, 1.0, 0.0]
    return _model(unit, lights)


def _evidence(theta: np.ndarray, lights: Lights, observed: np.ndarray) -> np.ndarray:
    """How much of each pixel's highlight was seen: the lobe's largest value on an observed cell
    over its largest value on the lattice (1: the peak was observed; near 0: it fell in a
    hole)."""
    lobe = _lobes(theta, lights)
    return np.where(observed, lobe, 0.0).max(axis=1) / np.maximum(lobe.max(axis=1), 1e-30)


def _share_roughness(theta: np.ndarray, evidence: np.ndarray, lights: Lights,
                     w: np.ndarray) -> np.ndarray:
    """Pixels that did not see their highlight's peak (evidence below :data:`SHARE_EVIDENCE`)
    and fitted a lobe sharper than the tile's pixels that did are given the median roughness of
    those (the same materials, seen from other angles elsewhere in the tile; where fewer than 4
    saw theirs, the median of the whole tile's), with the strength that keeps the lobe's
    least-squares fit on their observed cells: a lobe is never sharpened into a hole that no
    observation supports. A prior, not a constraint: pixels that saw their peak keep their
    own."""
    good = evidence >= SHARE_EVIDENCE
    shared = np.median(theta[good, 4] if good.sum() >= 4 else theta[:, 4])
    weak = ~good & (theta[:, 4] < shared)
    if not weak.any():
        return theta
    out = theta.copy()
    out[weak, 4] = shared
    rows = lights.rows(weak)
    old, new = _lobes(theta[weak], rows), _lobes(out[weak], rows)
    scale = (w[weak] * old * new).sum(axis=1) / np.maximum((w[weak] * new**2).sum(axis=1), 1e-30)
    out[weak, 3] *= np.maximum(scale, 0.0)
    return out


def parameters(surface: Surface) -> np.ndarray:
    """The fit's parameters ``theta = (p, q, rho, k, log alpha, a)`` ``(n, 6)`` of ``surface``."""
    n = surface.normal
    return np.column_stack([-n[:, 0] / n[:, 2], -n[:, 1] / n[:, 2], surface.albedo,
                            surface.specular, np.log(surface.roughness), surface.ambient])


def render(surface: Surface, lights: Lights) -> np.ndarray:
    """The model of ``surface`` at ``lights``, ``(n, M)``."""
    return _model(parameters(surface), lights)


def damped_residual(residual: np.ndarray, geometry: Geometry, *,
                    damp_cells: float = DAMP_CELLS, at: np.ndarray | None = None) -> np.ndarray:
    """The residual ``(n, R, S)`` (NaN unobserved) interpolated over the lattice by a thin-plate
    RBF and damped with the distance (in cells) from the pixel's nearest observation,
    ``(n, R * S)`` (``(n, len(at))``: at the flat cells ``at`` only)."""
    from scipy import ndimage

    from ltmstore.solve import rbf
    from ltmstore.solve.masks import group_by_mask

    interpolated = rbf.solve(residual, geometry, at=at).reshape(len(residual), -1)
    damp = np.empty(interpolated.shape, dtype=interpolated.dtype)
    for mask, rows in group_by_mask(np.isfinite(residual)):
        dist = ndimage.distance_transform_edt(~mask.reshape(residual.shape[1:])).ravel()
        damp[rows] = np.exp(-((dist if at is None else dist[at]) / damp_cells) ** 2)
    return interpolated * damp


def solve(samples: np.ndarray, geometry: Geometry, *, led_exponent: float | None = None,
          share: bool = True, residual: float = 0.5, damp_cells: float = DAMP_CELLS,
          n_iter: int = N_ITER, start: np.ndarray | None = None,
          at: np.ndarray | None = None, at_samples: bool = False) -> np.ndarray:
    """Reconstruct a batch of near-light LTFs with the physical model (see the module).

    Parameters
    ----------
    samples : ndarray, shape (n, R, S)
        Binned samples, NaN where unobserved.
    geometry : Geometry
        Must carry ``pixels``.
    led_exponent : float, optional
        ``m`` of the LED's ``cos^m`` emission (default: ``geometry.led_exponent``).
    share : bool
        Pixels whose highlight fell in a hole take the tile's roughness (:func:`fit_surface`).
    residual : float
        Weight in ``[0, 1]`` of the damped interpolation of the model's residual at the
        observed cells (1: the result interpolates the observations; 0: the model alone, which
        also smooths the noise of the observed cells).
    damp_cells : float
        Distance (cells) over which the residual fades away from the observations.
    n_iter : int
        Levenberg-Marquardt iterations after the starts.
    start : ndarray, shape (n, 6), optional
        Start the fit from these parameters (:func:`parameters` of a fit of the same pixels on
        more cells, as a held-out fold of :func:`ltmstore.solve.confidence.expected_error`)
        instead of the generic starts: fewer iterations.
    at : ndarray of int, optional
        Flat indices of the only cells wanted (a held-out fold's hidden cells:
        :func:`ltmstore.solve.validate.heldout_error`); the fit is the same.
    at_samples : bool
        With ``at``: the model there where those cells' samples were taken
        (``geometry.sampled``), as a held-out fold of the expected error compares it with them
        (:func:`ltmstore.solve.confidence.expected_error`), not at the cells' centres.

    Returns
    -------
    ndarray of float32, same shape as ``samples`` (``(n, len(at))`` with ``at``).
    """
    return solve_surface(samples, geometry, led_exponent=led_exponent, share=share,
                         residual=residual, damp_cells=damp_cells, n_iter=n_iter,
                         start=start, at=at, at_samples=at_samples)[0]


def solve_surface(samples: np.ndarray, geometry: Geometry, *, led_exponent: float | None = None,
                  share: bool = True, residual: float = 0.5, damp_cells: float = DAMP_CELLS,
                  n_iter: int = N_ITER, start: np.ndarray | None = None,
                  at: np.ndarray | None = None,
                  at_samples: bool = False) -> tuple[np.ndarray, Surface]:
    """:func:`solve`, and the fitted :class:`Surface` behind it."""
    if not 0.0 <= residual <= 1.0:
        raise LtmError(f"physical residual weight {residual!r} must lie in [0, 1]")
    if samples.ndim != 3:
        raise LtmError(f"method 'physical' takes a 4-D capture (n, R, S); got samples of shape "
                       f"{samples.shape}")
    if geometry.pixels is not None and len(geometry.pixels) != len(samples):
        raise LtmError(f"geometry holds {len(geometry.pixels)} pixel positions for a batch of "
                       f"{len(samples)} pixels")
    if not np.isfinite(samples).any(axis=tuple(range(1, samples.ndim))).all():
        raise LtmError("method 'physical' needs at least one observed cell per pixel")
    if start is not None and np.shape(start) != (len(samples), 6):
        raise LtmError(f"physical start of shape {np.shape(start)} does not match the batch of "
                       f"{len(samples)} pixels; expected ({len(samples)}, 6)")
    flat = samples.reshape(len(samples), -1)
    # with `at`, the model where the residual is (the observed cells) and where it is wanted
    cols = None if at is None else np.union1d(np.flatnonzero(np.isfinite(flat).any(axis=0)), at)
    key = None if len(samples) > CACHED_ROWS else _fit_key(  # a tile is fitted once: no key
        samples, geometry, led_exponent, n_iter, share, damp_cells, at_samples,
        *(None if v is None else hashlib.sha1(np.ascontiguousarray(
            v, dtype=np.float64).tobytes()).hexdigest() for v in (start, at)))
    cached = None if key is None else _FITS.get(key)
    surface, model, fitted, damped = cached or (*fit_surface(
        samples, geometry, led_exponent=led_exponent, n_iter=n_iter, share=share,
        start=start, at=cols, at_samples=at_samples), None)
    out = model if at is None else model[:, np.searchsorted(cols, at)]
    if residual > 0:
        if damped is None:
            res = np.full(flat.shape, np.nan, dtype=np.result_type(flat, model))
            seen, at_seen = fitted
            res[:, seen] = flat[:, seen] - at_seen
            damped = damped_residual(res.reshape(samples.shape), geometry, damp_cells=damp_cells,
                                     at=at)
        out = out + residual * damped
    if key is not None:
        _FITS.put(key, (surface, model, fitted, damped))
    return out.reshape(samples.shape if at is None else out.shape).astype(np.float32), surface


# The fit does not depend on the residual's weight: the choice of that weight
# (ltmstore.solve.select.choose_params, three weights on the same held-out folds of a few dozen
# pixels) fits each fold once, not once per weight.
CACHED_LIGHTS = 2  # a tile's lights (70 MB for 32 x 32 pixels on 50 x 50 cells) and its pick's
CACHED_FITS = 6  # folds of small batches whose fit a process keeps (select.SEGMENT_FOLDS: 5)
_FITS = Recent(CACHED_FITS)
_LIGHTS = Recent(CACHED_LIGHTS)  # near_lights
CACHED_ROWS = 512  # ... batches of at most this many pixels (a tile is solved once)


def _fit_key(samples: np.ndarray, geometry: Geometry, *params) -> tuple:
    digest = hashlib.sha1(np.ascontiguousarray(samples).tobytes())
    for array in (geometry.pixels, geometry.positions(), geometry.sampled,
                  geometry.led_axis):
        digest.update(b"-" if array is None else np.ascontiguousarray(array).tobytes())
    return (digest.hexdigest(), samples.shape, str(samples.dtype), geometry.height,
            geometry.led_exponent, params)
