"""Camera B's exposure and white-balance drift, estimated from the frames themselves.

A fixed camera B films a static painting: each frame's linear value is ``g_c(t) * L(light)``,
the light transport at the light's position (room light included) times the camera's gain per
colour channel ``c`` at the frame's time. With exposure and white balance locked ``g`` is
constant. For every channel the log of the frame's block means is modelled as

    log F[i, b] = x(t_i) + f_b(r_i, s_i, z_i)

with ``x`` piecewise linear in time (knots every :data:`KNOT_S`, a first-difference smoothness
prior) and ``f_b`` a smooth function of the light position per block (bilinear hats on a
:data:`POSITION_GRID` grid over the plane, plus a term in ``z``). The light comes back near
where it was at other times, so a gain that changes in time is told apart from a brightness
that changes with position. The block functions are eliminated exactly (a projection), which
leaves a small linear system in the knots whose inverse gives each frame's standard error.

Phone A's LED emits about ``cos^k`` of the angle off its axis, and a hand tilts that axis by a
few degrees from frame to frame: the light reaching the painting then changes with time at a
fixed position, which the model above reads as drift (a 2 degree wobble at the plane's edge:
several per cent). Where the poses give the LED's axis, ``beam`` (the log of the beam's cosine
relative to that of the LED held level, over the object, per frame) enters the model as one
more term ``k * beam_i``, common to all blocks, with ``k`` (the beam's exponent) estimated
jointly. The level beam's part is a function of the position alone, the painting's as before
(a regressor holding it too took up the position model's misfit: ``k`` came out 0.8-1.0 on
frames with no beam at all). That ``k`` is the drift's nuisance: the beam itself is measured
across the frame (:mod:`ltmstore.capture.led_beam`), where the gain and the codec's shared errors
do not reach.

Limits: a gain that follows the light position with no lag (an auto-exposure reacting
instantly to the frame's brightness) is indistinguishable from the painting itself, and is not
seen; nor is a change faster than the knot spacing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ltmstore.core.dims import Plane

KNOT_S = 0.5  # seconds between gain knots
POSITION_GRID = 11  # hats per plane side for each block's brightness as a function of position
SMOOTHNESS = 0.3  # weight of the first difference of x between knots (per unit of log gain)
MIN_FRAMES = 90  # fewer lit frames: the drift is not judged
MIN_DOF = 45  # fewer lit frames than this beyond the model's parameters: not judged either
MIN_BLOCK_FRACTION = 0.02  # blocks darker than this fraction of the brightest are left out


@dataclass(frozen=True)
class DriftEstimate:
    """Log gain per frame and channel with standard errors.

    Attributes
    ----------
    log_gain : ndarray (n, 3)
        ``x_c(t_i)`` for every frame (clamped outside the lit frames), mean zero over the lit
        frames.
    stderr : ndarray (n, 3)
        Standard error of ``log_gain``.
    stderr_data : ndarray (n, 3)
        Standard error of the log gain that the data alone give (without the smoothness
        prior): large where the light path does not come back near where it was at other
        times, so that a change in time cannot be told from a change with position.
    lit : ndarray (n,) of bool
        The frames the estimate used.
    residual : float
        RMS residual of the model (log units), per frame.
    beam_exponent, beam_stderr : ndarray (3,) or None
        The LED's ``cos^k`` exponent per channel and its standard error, where a ``beam`` term
        was fitted.
    """

    log_gain: np.ndarray
    stderr: np.ndarray
    stderr_data: np.ndarray
    lit: np.ndarray
    residual: float
    beam_exponent: np.ndarray | None = None
    beam_stderr: np.ndarray | None = None

    def amplitude(self) -> float:
        """RMS over the lit frames and channels of the log gain."""
        return float(np.sqrt(np.mean(self.log_gain[self.lit] ** 2)))

    def noise(self) -> float:
        """RMS over the lit frames and channels of the standard error."""
        return float(np.sqrt(np.mean(self.stderr[self.lit] ** 2)))

    def determination(self) -> float:
        """Median over the lit frames and channels of :attr:`stderr_data`."""
        return float(np.median(self.stderr_data[self.lit]))

    def span(self) -> float:
        """Largest minus smallest log gain over the lit frames, any channel."""
        x = self.log_gain[self.lit]
        return float(np.max(x.max(axis=0) - x.min(axis=0)))


def estimate_drift(blocks: np.ndarray, t: np.ndarray, r: np.ndarray, s: np.ndarray,
                   z: np.ndarray, lit: np.ndarray, plane: Plane, *,
                   beam: np.ndarray | None = None) -> DriftEstimate | None:
    """Estimate camera B's log gain per frame and colour channel.

    Parameters
    ----------
    blocks : ndarray (n, B, 3)
        Mean linear RGB of ``B`` image blocks of every frame.
    t : ndarray (n,)
        Frame times, seconds.
    r, s, z : ndarray (n,)
        Light position per frame (ignored where ``lit`` is False).
    lit : ndarray (n,) of bool
        Frames lit by the LED at a known position.
    plane : Plane
        The illumination plane (the position basis spans it).
    beam : ndarray (n,), optional
        The LED's log beam relative to the LED held level, per frame
        (:func:`beam_log_ratio`); frames where it is not finite are left out.

    Returns
    -------
    DriftEstimate or None
        None when fewer than :data:`MIN_FRAMES` frames are lit, or fewer than :data:`MIN_DOF`
        beyond the parameters of the model (a short path: its misfit would be noise).
    """
    lit = np.asarray(lit, dtype=bool) & np.isfinite(r) & np.isfinite(s) & np.isfinite(z)
    if beam is not None:
        lit &= np.isfinite(beam)
    if lit.sum() < MIN_FRAMES:
        return None
    knots = _knots(t[lit])
    k = len(knots)
    extra = np.zeros((len(t), 0)) if beam is None else np.nan_to_num(beam)[:, None]
    m_all = np.column_stack([_hats_1d(t, knots), extra])  # knots, then the beam term
    m = m_all[lit]
    q = scipy.linalg.orth(position_basis(r[lit], s[lit], z[lit], plane))  # the hats visited
    dof = int(lit.sum()) - q.shape[1] - m.shape[1]
    if dof < MIN_DOF:
        return None
    m_perp = m - q @ (q.T @ m)  # (I - P_W) M
    d = np.diff(np.eye(k, m.shape[1]), axis=0)[:k - 1]  # smoothness of the knots alone
    gauge = np.concatenate([m[:, :k].mean(axis=0), np.zeros(m.shape[1] - k)])
    data = m_perp.T @ m_perp + np.outer(gauge, gauge)  # gauge: mean zero
    inverse = np.linalg.pinv(data + SMOOTHNESS**2 * d.T @ d)
    hats = m_all[:, :k]
    data_only = np.einsum("ij,jk,ik->i", hats, np.linalg.pinv(data)[:k, :k], hats)
    n = len(t)
    log_gain, stderr, stderr_data = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    residuals, exponent, exponent_se = [], np.zeros(3), np.zeros(3)
    for c in range(3):
        y = _mean_log(blocks[lit, :, c])
        y_perp = y - q @ (q.T @ y)
        x = inverse @ (m_perp.T @ y_perp)
        resid = y_perp - m_perp @ x
        sigma2 = float(resid @ resid) / dof
        log_gain[:, c] = hats @ x[:k] - float(np.mean(m[:, :k] @ x[:k]))
        stderr[:, c] = np.sqrt(sigma2 * np.einsum("ij,jk,ik->i", hats, inverse[:k, :k], hats))
        stderr_data[:, c] = np.sqrt(sigma2 * np.maximum(data_only, 0))
        residuals.append(sigma2)
        if beam is not None:
            exponent[c], exponent_se[c] = x[k], np.sqrt(sigma2 * max(inverse[k, k], 0.0))
    return DriftEstimate(log_gain=log_gain, stderr=stderr, stderr_data=stderr_data, lit=lit,
                         residual=float(np.sqrt(np.mean(residuals))),
                         beam_exponent=None if beam is None else exponent,
                         beam_stderr=None if beam is None else exponent_se)


def beam_log_ratio(r: np.ndarray, s: np.ndarray, z: np.ndarray, axis: np.ndarray,
                   extent: tuple[tuple[float, float], tuple[float, float]],
                   grid: int = 8) -> np.ndarray:
    """The LED's beam about ``axis`` ``(n, 3)`` relative to the LED held level, per frame: the
    mean of :func:`beam_log_ratios` over a ``grid x grid`` of points over the object rectangle
    ``extent`` (``((r0, r1), (s0, s1))`` at height 0). Its exponent times this is the beam's
    term in the mean log brightness over the frame's blocks that is not a function of the
    light's position (the level beam's part is, and the painting's model holds it)."""
    (r0, r1), (s0, s1) = extent
    u = (np.arange(grid) + 0.5) / grid
    pr, ps = np.meshgrid(r0 + (r1 - r0) * u, s0 + (s1 - s0) * u)
    return beam_log_ratios(r, s, z, axis, pr.ravel(), ps.ravel()).mean(axis=1)


def beam_log_ratios(r: np.ndarray, s: np.ndarray, z: np.ndarray, axis: np.ndarray,
                    pr: np.ndarray, ps: np.ndarray) -> np.ndarray:
    """``(n, P)``: ``log(cos a / cos a0)`` from the LED at ``(r, s, z)`` to each point
    ``(pr, ps, 0)``, ``a`` and ``a0`` the angles between the direction to the point and the
    LED's ``axis`` ``(n, 3)`` or straight down (NaN where the LED points away from a point)."""
    d = np.stack([pr[None] - np.asarray(r)[:, None], ps[None] - np.asarray(s)[:, None],
                  np.broadcast_to(-np.asarray(z)[:, None], (len(r), len(pr)))], -1)
    ratio = np.einsum("npj,nj->np", d, axis) / -d[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ratio > 0, np.log(np.where(ratio > 0, ratio, 1.0)), np.nan)


def _mean_log(values: np.ndarray) -> np.ndarray:
    """Mean over the usable blocks of the log of each frame's block values ``(n, B)``."""
    level = np.median(values, axis=0)
    keep = level > MIN_BLOCK_FRACTION * max(float(level.max()), 1e-30)
    v = np.maximum(values[:, keep], 1e-6 * max(float(level.max()), 1e-30))
    return np.log(v).mean(axis=1)


def _knots(t: np.ndarray) -> np.ndarray:
    count = max(2, int(np.ceil((t.max() - t.min()) / KNOT_S)) + 1)
    return np.linspace(t.min(), t.max(), count)


def _hats_1d(u: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation weights ``(len(u), len(knots))`` (clamped outside)."""
    u = np.clip(u, knots[0], knots[-1])
    eye = np.eye(len(knots))
    return np.stack([np.interp(u, knots, row) for row in eye], axis=1)


def position_basis(r: np.ndarray, s: np.ndarray, z: np.ndarray, plane: Plane) -> np.ndarray:
    """Bilinear hats on a :data:`POSITION_GRID` grid over the plane, and ``z`` (centred)."""
    hr = _hats_1d(r, np.linspace(*plane.r, POSITION_GRID))
    hs = _hats_1d(s, np.linspace(*plane.s, POSITION_GRID))
    hats = (hr[:, :, None] * hs[:, None, :]).reshape(len(r), -1)
    dz = (z - plane.height) / max(plane.height, 1e-9)
    return np.column_stack([hats, dz])
