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
    """

    log_gain: np.ndarray
    stderr: np.ndarray
    stderr_data: np.ndarray
    lit: np.ndarray
    residual: float

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
                   z: np.ndarray, lit: np.ndarray, plane: Plane) -> DriftEstimate | None:
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

    Returns
    -------
    DriftEstimate or None
        None when fewer than :data:`MIN_FRAMES` frames are lit, or fewer than :data:`MIN_DOF`
        beyond the parameters of the model (a short path: its misfit would be noise).
    """
    lit = np.asarray(lit, dtype=bool) & np.isfinite(r) & np.isfinite(s) & np.isfinite(z)
    if lit.sum() < MIN_FRAMES:
        return None
    knots = _knots(t[lit])
    m_all = _hats_1d(t, knots)
    m = m_all[lit]
    q = scipy.linalg.orth(_position_basis(r[lit], s[lit], z[lit], plane))  # the hats visited
    dof = int(lit.sum()) - q.shape[1] - len(knots)
    if dof < MIN_DOF:
        return None
    m_perp = m - q @ (q.T @ m)  # (I - P_W) M
    d = np.diff(np.eye(len(knots)), axis=0)
    data = m_perp.T @ m_perp + np.outer(m.mean(axis=0), m.mean(axis=0))  # gauge: mean zero
    inverse = np.linalg.pinv(data + SMOOTHNESS**2 * d.T @ d)
    data_only = np.einsum("ij,jk,ik->i", m_all, np.linalg.pinv(data), m_all)
    n = len(t)
    log_gain, stderr, stderr_data = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    residuals = []
    for c in range(3):
        y = _mean_log(blocks[lit, :, c])
        y_perp = y - q @ (q.T @ y)
        x = inverse @ (m_perp.T @ y_perp)
        resid = y_perp - m_perp @ x
        sigma2 = float(resid @ resid) / dof
        log_gain[:, c] = m_all @ x - float(np.mean(m @ x))
        stderr[:, c] = np.sqrt(sigma2 * np.einsum("ij,jk,ik->i", m_all, inverse, m_all))
        stderr_data[:, c] = np.sqrt(sigma2 * np.maximum(data_only, 0))
        residuals.append(sigma2)
    return DriftEstimate(log_gain=log_gain, stderr=stderr, stderr_data=stderr_data, lit=lit,
                         residual=float(np.sqrt(np.mean(residuals))))


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


def _position_basis(r: np.ndarray, s: np.ndarray, z: np.ndarray, plane: Plane) -> np.ndarray:
    """Bilinear hats on a :data:`POSITION_GRID` grid over the plane, and ``z`` (centred)."""
    hr = _hats_1d(r, np.linspace(*plane.r, POSITION_GRID))
    hs = _hats_1d(s, np.linspace(*plane.s, POSITION_GRID))
    hats = (hr[:, :, None] * hs[:, None, :]).reshape(len(r), -1)
    dz = (z - plane.height) / max(plane.height, 1e-9)
    return np.column_stack([hats, dz])
