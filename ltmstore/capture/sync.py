"""Clock offset between the poses (phone A) and video B: ``ltm sync``.

Video B's brightness is a smooth function of where the light is: a flat diffuse painting lit by
a point light at ``(r, s, z)`` follows an inverse-square and cosine falloff, and real paintings
add slow variations on top. For a candidate offset ``tau`` every frame of video B (at time
``t`` on B's clock) gets the tracked light at ``t - tau`` on the poses' clock, and the mean
linear brightness of each block of a coarse grid over the image is fitted, by least squares,
with a low-order polynomial of ``(r, s)``, terms in ``z`` and the falloff ``z / d^3`` of a flat
diffuse plane at the plane centre (where the painting lies; the polynomial absorbs the rest, so
no camera geometry is needed). At the true offset the brightness follows the light and the
residual drops sharply; elsewhere it lags. Two stages: on a grid of half a frame over the whole
search range, the total brightness is fitted by the rigid physical falloff alone (gain and
bias: a short stretch of path at a wrong offset cannot be fitted well by it, as it can by the
flexible model); around that optimum the block model is minimised on a 1 ms grid and by a
parabola through the minimum (sub-frame). The standard error comes from the curvature of the
residual, the confidence from how much better the optimum is than the runner-up.

Where the poses carry the LED's axis (``ltm track`` writes it), the brightness is divided by
the beam ``cos^k`` of the angle between that axis and the direction to the plane centre, ``k``
measured from how the wobble moves light across the frame's blocks at the offset found without
the beam (:func:`ltmstore.capture.led_beam.estimate_beam`, the room light of the LED-off lead
taken off), and the offset found again: twice (:data:`BEAM_ROUNDS`). A hand wobbles the phone
by a degree or two, and a beam's brightness that follows the wobble, not the path, pulls the
offset: on a simulated 720 px canvas with a ``cos^2`` beam and its true poses, -0.45 frame;
with the beam, +0.01 (a beam-free capture keeps 0 and +0.04 frame). The exponent was once
chosen by the fit's residual among 0-3; with room light, lens and codec as well (every effect,
tracked poses) the residual chose 0 and the offset was 0.25-0.38 frame off.

The estimate is written to ``acquisition.json`` as ``time_offset`` (seconds added to the pose
times, ingest's convention) with a ``time_offset_estimate`` record; the file is replaced
atomically and its previous version kept as ``acquisition.json.bak``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.acquisition import load_acquisition, load_poses, write_text_atomic
from ltmstore.capture.lead import find_lead
from ltmstore.capture.led_beam import estimate_beam, object_guess
from ltmstore.capture.video import VideoReader, transfer_lut
from ltmstore.core.dims import Plane
from ltmstore.core.errors import LtmError

GRID = 6  # blocks per image side
DEGREE = 6  # polynomial degree in (r, s): lower ones cannot follow a varnish highlight and bias
# the offset (a simulated canvas with its true poses: -0.44 frame at degree 3, -0.17 at 5, +0.05)
MIN_DEGREE = 3  # a video too short for DEGREE is fitted with fewer terms, down to this
ROWS_PER_PARAM = 3  # frames the block fit needs per parameter at an offset
DEFAULT_MAX_OFFSET = 3.0  # seconds searched either side
MIN_R2 = 0.5  # fraction of the brightness variance the light path must explain
MIN_CONTRAST = 0.3  # 1 - best residual / residual at the runner-up local minimum
MIN_OVERLAP = 0.5  # fraction of video B that must overlap the poses at an offset
FINE_STEP = 0.001  # seconds
FINE_WINDOW = 3  # coarse steps either side of the coarse optimum searched finely
# Rounds of the beam's exponent measured at the offset found, then the offset found again. On
# the 720 px every-effect and beam captures of the phone-size bench (tracked poses), one round
# left the beam-only ones 0.08-0.21 frame off (measured at the beam-free offset, 0.45 frame
# early: k 2.7-2.8); two, 0.02-0.14; three, 0.03-0.14.
BEAM_ROUNDS = 2
# The measured beam is divided out where it stands this many standard errors above none and
# at least MIN_BEAM_EXPONENT: beam-free simulated canvases measured 0.13-0.21 (720 px),
# 0.25-0.44 +- 0.04 (64 px; dividing by 0.44 had moved the offset 0.2 frame) and, tracked from
# the board in the live pages' 24 px capture, 1.12 +- 0.19; the cos^2 beams measured 1.7-2.8.
BEAM_SIGNIFICANCE = 2.0
MIN_BEAM_EXPONENT = 1.5
MIN_BEAM_COS = 0.05  # the beam's cosine is floored here (a light beside the plane)
KERNEL_CENTRES = [(cr, cs) for cr in (-0.05, 0.0, 0.05) for cs in (-0.05, 0.0, 0.05)]  # m


def block_brightness(video: str | os.PathLike, transfer: str, *, grid: int = GRID,
                     progress: bool = True) -> tuple[np.ndarray, float]:
    """Mean linear brightness of ``grid x grid`` blocks of every frame, ``(n, grid * grid)``,
    and the frame rate."""
    lut = transfer_lut(transfer)
    rows = []
    with VideoReader(Path(video)) as reader:
        fps = reader.fps
        for rgb in tqdm(reader, total=reader.frame_count, disable=not progress, desc="sync",
                        unit="frame"):
            y = lut[cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)]
            rows.append(cv2.resize(y, (grid, grid), interpolation=cv2.INTER_AREA).ravel())
    return np.array(rows, dtype=np.float64), fps


def n_params(degree: int) -> int:
    """Parameters of the block fit: the constant and the columns of :func:`_basis` (the
    polynomial, three ``dz`` terms, the falloff)."""
    return 1 + (degree + 1) * (degree + 2) // 2 + 3 + 1


def fit_degree(frames: int) -> int:
    """The polynomial degree for a block fit over ``frames`` frames: :data:`DEGREE`, or the
    highest from :data:`MIN_DEGREE` up that leaves :data:`ROWS_PER_PARAM` frames per parameter
    (90 % of them, so offsets that overlap a little less are still fitted)."""
    fits = [d for d in range(MIN_DEGREE, DEGREE + 1)
            if ROWS_PER_PARAM * n_params(d) <= 0.9 * frames]
    return max(fits, default=MIN_DEGREE)


def _basis(r: np.ndarray, s: np.ndarray, z: np.ndarray, scale: tuple,
           degree: int = DEGREE) -> np.ndarray:
    """Polynomial of ``(r, s)`` up to ``degree``, ``dz`` terms and the falloff ``z/d^3``."""
    (r0, rs), (s0, ss), (z0, zs) = scale
    u, v, w = (r - r0) / rs, (s - s0) / ss, (z - z0) / zs
    cols = [u**i * v**j for i in range(degree + 1) for j in range(degree + 1 - i)]
    cols += [w, w * u, w * v]
    d2 = r * r + s * s + z * z
    cols.append(z / d2**1.5 / (1 / z0**2))
    return np.column_stack(cols)


class OffsetCost:
    """Residual of the brightness fit as a function of the clock offset."""

    def __init__(self, brightness: np.ndarray, fps: float, poses, skip_frames: int = 0,
                 beam: float = 0.0, centre: tuple[float, float] = (0.0, 0.0)) -> None:
        self.skip_frames = skip_frames
        self.beam = beam  # the exponent k of the LED's cos^k beam the brightness is divided by
        self.centre = np.array([*centre, 0.0])[:, None]  # where the beam is taken towards
        self.brightness = brightness
        self.y = brightness - brightness[skip_frames:].mean(axis=0)
        self.total = self.y.sum(axis=1)
        self.t = np.arange(len(brightness)) / fps
        self.poses = poses
        tp = poses.t
        gap = np.diff(tp)
        self.max_gap = max(3 * float(np.median(gap)), 2.5 / fps)
        self.gaps = gap
        z = poses.z
        self.scale = ((float(np.mean(poses.r)), float(np.ptp(poses.r)) / 2 or 1.0),
                      (float(np.mean(poses.s)), float(np.ptp(poses.s)) / 2 or 1.0),
                      (float(np.median(z)), max(float(np.ptp(z)) / 2, 1e-3)))
        pose_frames = (tp[-1] - tp[0]) * fps
        self.min_rows = int(MIN_OVERLAP * min(len(self.t), pose_frames))
        self.degree = fit_degree(int(min(len(self.t) - skip_frames, pose_frames)))
        self.n_params = n_params(self.degree)

    def lights(self, tau: float) -> tuple[np.ndarray, np.ndarray | None]:
        """Frames of video B used at offset ``tau`` and the light ``(3, n)`` at each, or None
        when too few frames overlap the poses."""
        use = self.rows(tau)
        if int(use.sum()) < max(self.min_rows, ROWS_PER_PARAM * self.n_params):
            return use, None
        p = self.poses
        return use, self.poses_at(tau, use, (p.r, p.s, p.z))

    def poses_at(self, tau: float, use: np.ndarray | slice, columns) -> np.ndarray:
        """The poses' ``columns`` (each ``(m,)``) interpolated at video B's frames ``use`` with
        the offset ``tau``: ``(len(columns), n)``."""
        u = self.t[use] - tau
        return np.stack([np.interp(u, self.poses.t, c) for c in columns])

    def coarse(self, tau: float) -> float:
        """Fraction of the total brightness's variance that the physical falloff of a flat
        diffuse plane leaves unexplained (best of a few centres near the plane centre; one
        gain and one bias: too rigid to fit a wrong offset well)."""
        use, light = self.lights(tau)
        if light is None:
            return math.inf
        r, s, z = light
        y = self.total[use] - self.total[use].mean()
        best = 0.0
        for cr, cs in KERNEL_CENTRES:
            pred = z / ((r - cr) ** 2 + (s - cs) ** 2 + z * z) ** 1.5
            pred -= pred.mean()
            best = max(best, float(pred @ y) ** 2 / max(float(pred @ pred) * float(y @ y),
                                                       1e-300))
        return 1 - best

    def rows(self, tau: float) -> np.ndarray:
        """Frames of video B whose light is known at offset ``tau`` (no long pose gap)."""
        u = self.t - tau
        tp = self.poses.t
        inside = (u >= tp[0]) & (u <= tp[-1]) & (np.arange(len(u)) >= self.skip_frames)
        i = np.clip(np.searchsorted(tp, u) - 1, 0, len(self.gaps) - 1)
        return inside & (self.gaps[i] <= self.max_gap)

    def __call__(self, tau: float) -> tuple[float, int]:
        """Fraction of brightness variance left unexplained (adjusted for the number of
        parameters), and frames used."""
        use, light = self.lights(tau)
        n = int(use.sum())
        if light is None:
            return math.inf, n
        a = np.column_stack([np.ones(n), _basis(*light, self.scale, self.degree)])
        y = self.y[use] if not self.beam else self._unbeamed(use, tau, light)
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        resid = y - a @ coef
        total = np.sum((y - y.mean(axis=0)) ** 2)
        # adjusted: fewer frames at the search edges must not fit better by having fewer
        return float(np.sum(resid**2) / (n - a.shape[1]) / max(total / (n - 1), 1e-300)), n

    def _unbeamed(self, use: np.ndarray, tau: float, light: np.ndarray) -> np.ndarray:
        """The brightness of the frames ``use`` divided by the beam (exponent :attr:`beam`)
        towards the plane centre from the ``light (3, n)`` along the LED's axis at ``tau``,
        less its mean."""
        axis = self.poses_at(tau, use, self.poses.axis.T)
        towards = self.centre - light
        cos = np.sum(axis * towards, axis=0) / np.linalg.norm(towards, axis=0)
        y = self.brightness[use] / np.maximum(cos, MIN_BEAM_COS)[:, None] ** self.beam
        return y - y.mean(axis=0)


def estimate_offset(brightness: np.ndarray, fps: float, poses, *,
                    max_offset: float = DEFAULT_MAX_OFFSET, skip_frames: int = 0,
                    plane: Plane | None = None, room: np.ndarray | float = 0.0) -> dict:
    """Estimate the clock offset ``tau`` (``t_B = t_poses + tau``) with its confidence.

    Parameters
    ----------
    brightness : ndarray (n, blocks)
        Linear block brightness of video B per frame (:func:`block_brightness`).
    fps : float
        Video B's frame rate (frame ``i`` at ``i / fps``).
    poses : Poses
        The tracked light path.
    max_offset : float
        Offsets searched: ``[-max_offset, max_offset]`` seconds.
    skip_frames : int
        Leading frames of video B left out of the fit (the LED-off lead: its brightness is
        the room light's, not a function of the light's position).
    plane : Plane, optional
        The light plane; where given and the poses carry the LED's axis, the LED's beam is
        measured and divided out, taken towards the plane's centre (where the painting lies).
    room : ndarray (blocks,) or float
        The room light's block brightness (the LED-off lead's), taken off to measure the beam.

    Returns
    -------
    dict
        ``time_offset`` (s), ``stderr_s``, ``r2`` (variance of the total brightness that the
        physical falloff explains at the coarse optimum), ``r2_fine`` (block brightness
        explained by the fine model), ``contrast`` (1 - best residual / residual at the
        runner-up: the lowest other coarse local minimum more than two frames away; the
        confidence that the offset is not confused with another), ``runner_up_s``,
        ``runner_up_r2``, ``frames_used``, ``beam_exponent`` (the LED's ``cos^k`` beam the
        brightness was divided by: 0 where the poses carry no axis, no ``plane`` is given or
        the beam measured is within :data:`BEAM_SIGNIFICANCE` standard errors of none or below
        :data:`MIN_BEAM_EXPONENT`) and ``beam_stderr`` (None where not measured).

    Raises
    ------
    LtmError
        If video B carries no usable signal (the light path explains too little of its
        brightness at any offset, or no offset stands out).
    """
    cost = OffsetCost(brightness, fps, poses, skip_frames)
    step = 0.5 / fps
    taus = np.arange(-max_offset, max_offset + step / 2, step)
    costs = np.array([cost.coarse(t) for t in taus])
    if not np.isfinite(costs).any():
        raise LtmError(f"video B ({len(brightness) / fps:.1f} s) and the poses "
                       f"({poses.t[-1] - poses.t[0]:.1f} s) overlap by less than "
                       f"{MIN_OVERLAP:.0%} at every offset within +-{max_offset:g} s; expected "
                       "recordings of the same sweep")
    k = int(np.nanargmin(costs))
    reach = FINE_WINDOW * step
    fine = np.arange(taus[k] - reach, taus[k] + reach + FINE_STEP / 2, FINE_STEP)
    tau, best, used, fine_costs = _fine(cost, fine)
    beam, beam_stderr = 0.0, None
    if poses.axis is not None and plane is not None:
        centre = (sum(plane.r) / 2, sum(plane.s) / 2)
        for _ in range(BEAM_ROUNDS):
            measured = _beam_at(cost, tau, plane, room)
            if measured is None or measured[0] < max(BEAM_SIGNIFICANCE * measured[1],
                                                      MIN_BEAM_EXPONENT):
                break
            beam, beam_stderr = measured
            beamed = OffsetCost(brightness, fps, poses, skip_frames, beam, centre)
            tau, best, used, fine_costs = _fine(beamed, fine)
    # standard error: RSS(tau) ~ RSS_min (1 + curv/2 dtau^2); var(tau) = 2 sigma^2 / RSS''
    near = np.abs(fine - tau) <= 4 * FINE_STEP + 1e-12
    curv = (float(np.polyfit(fine[near] - tau, fine_costs[near], 2)[0] * 2)
            if near.sum() >= 3 else math.nan)
    dof = max(used - cost.n_params, 1)
    stderr = math.sqrt(2 * best / dof / curv) if curv > 0 else math.inf
    runner = _runner_up(taus, costs, taus[k], 2 / fps)
    runner_cost = costs[runner] if runner is not None else float(np.nanmedian(
        costs[np.isfinite(costs)]))
    result = {"time_offset": float(tau), "stderr_s": stderr, "r2": float(1 - costs[k]),
              "r2_fine": 1 - best, "contrast": float(1 - costs[k] / max(runner_cost, 1e-300)),
              "runner_up_s": None if runner is None else float(taus[runner]),
              "runner_up_r2": float(1 - runner_cost),
              "frames_used": used, "search_s": [-max_offset, max_offset], "grid": GRID,
              "degree": cost.degree, "beam_exponent": beam, "beam_stderr": beam_stderr,
              "method": "brightness of video B against the tracked light path"}
    if result["r2"] < MIN_R2 or result["contrast"] < MIN_CONTRAST:
        raise LtmError(f"no usable signal for sync: the light path explains "
                       f"{result['r2']:.0%} of video B's brightness at best (offset "
                       f"{tau:+.3f} s, contrast {result['contrast']:.2f}); expected at least "
                       f"{MIN_R2:.0%} with contrast {MIN_CONTRAST} (is the LED lighting the "
                       "painting, and do both videos record the same sweep?)")
    return result


def _fine(cost: OffsetCost, fine: np.ndarray) -> tuple[float, float, int, np.ndarray]:
    """The offset of least ``cost`` on the grid ``fine`` (refined by a parabola through the
    minimum: sub-step), its cost and frames used, and the cost at every grid point."""
    fine_costs = np.array([cost(t)[0] for t in fine])
    j = int(np.argmin(fine_costs))
    tau = float(fine[j])
    if 0 < j < len(fine) - 1 and np.all(np.isfinite(fine_costs[j - 1:j + 2])):
        c0, c1, c2 = fine_costs[j - 1:j + 2]
        if c0 - 2 * c1 + c2 > 0:  # a parabola through the minimum: sub-step vertex
            tau -= 0.5 * FINE_STEP * (c2 - c0) / (c0 - 2 * c1 + c2)
    best, used = cost(tau)
    return tau, best, used, fine_costs


def _beam_at(cost: OffsetCost, tau: float, plane: Plane,
             room: np.ndarray | float) -> tuple[float, float] | None:
    """The LED beam's exponent and its standard error measured across the frame's blocks
    (luminance, ``room`` taken off) with the light and the LED's axis at offset ``tau``."""
    poses = cost.poses
    r, s, z = cost.poses_at(tau, slice(None), (poses.r, poses.s, poses.z))
    axis = cost.poses_at(tau, slice(None), poses.axis.T).T
    blocks = (cost.brightness - room)[:, :, None]
    measured = estimate_beam(blocks, r, s, z, axis, cost.rows(tau), plane, object_guess(plane))
    return None if measured is None else (float(measured[0][0]), float(measured[1][0]))


def _runner_up(taus: np.ndarray, costs: np.ndarray, tau: float, away: float) -> int | None:
    """Index of the lowest local minimum of ``costs`` further than ``away`` from ``tau``."""
    c = np.where(np.isfinite(costs), costs, np.inf)
    left = np.concatenate([[np.inf], c[:-1]])
    right = np.concatenate([c[1:], [np.inf]])
    minima = np.flatnonzero((c <= left) & (c <= right) & np.isfinite(c)
                            & (np.abs(taus - tau) > away))
    return int(minima[np.argmin(c[minima])]) if minima.size else None


def sync_acquisition(acq_dir: str | os.PathLike, *, max_offset: float = DEFAULT_MAX_OFFSET,
                     overwrite: bool = False, progress: bool = True) -> dict:
    """Estimate the poses-to-video clock offset of an acquisition and record it.

    Parameters
    ----------
    acq_dir : path
        Acquisition folder whose ``poses.csv`` comes from ``ltm track``.
    max_offset : float
        Search range, seconds either side of zero.
    overwrite : bool
        Re-estimate when ``acquisition.json`` already declares a ``time_offset``.
    progress : bool
        Show a progress bar.

    Returns
    -------
    dict
        The estimate (:func:`estimate_offset`) and ``acquisition`` (the file updated).

    Raises
    ------
    LtmError
        For a bad folder, a declared offset without ``overwrite``, recordings of different
        lengths, or no usable signal.
    """
    if not (math.isfinite(max_offset) and max_offset > 0):
        raise LtmError(f"--max-offset {max_offset!r} must be a positive number of seconds")
    acq = load_acquisition(acq_dir)
    meta_path = acq.folder / "acquisition.json"
    if "time_offset" in acq.raw and not overwrite:
        raise LtmError(f"{str(meta_path)} already declares time_offset "
                       f"{acq.raw['time_offset']!r}; pass --overwrite to estimate it again")
    poses = load_poses(acq.poses)
    with VideoReader(acq.video) as reader:  # the header alone: fail fast on different lengths
        span_b = (reader.frame_count or 0) / reader.fps
    span_p = float(poses.t[-1] - poses.t[0])
    if span_b and (abs(span_b - span_p) > 2 * max_offset
                   or min(span_b, span_p) < MIN_OVERLAP * max(span_b, span_p)):
        raise LtmError(f"video B {str(acq.video)!r} lasts {span_b:.1f} s but the poses span "
                       f"{span_p:.1f} s; expected recordings of the same sweep (lengths within "
                       f"{2 * max_offset:g} s, see --max-offset, and within a factor "
                       f"{1 / MIN_OVERLAP:g})")
    result = video_offset(acq.video, acq.transfer, poses, acq.plane, max_offset=max_offset,
                          progress=progress)
    meta = dict(acq.raw)
    meta["time_offset"] = result["time_offset"]
    meta["time_offset_estimate"] = {k: v for k, v in result.items() if k != "time_offset"}
    _replace_json(meta_path, meta)
    return {**result, "acquisition": str(meta_path)}


def video_offset(video: str | os.PathLike, transfer: str, poses, plane: Plane, *,
                 max_offset: float = DEFAULT_MAX_OFFSET, progress: bool = False) -> dict:
    """:func:`estimate_offset` of video B's frames against ``poses``, its LED-off lead found
    and left out (``led_off_frames`` added to the result), its room light taken off where the
    beam is measured: what ``ltm sync`` records, and what the live capture counts with."""
    brightness, fps = block_brightness(video, transfer, progress=progress)
    lead = find_lead(brightness.mean(axis=1), fps)
    skip = 0 if lead is None else lead.excluded[1]
    room = 0.0 if lead is None else brightness[slice(*lead.ambient)].mean(axis=0)
    result = estimate_offset(brightness, fps, poses, max_offset=max_offset, skip_frames=skip,
                             plane=plane, room=room)
    return {**result, "led_off_frames": skip}


def _replace_json(path: Path, meta: dict) -> None:
    """Keep the old file as ``.bak`` and replace it atomically."""
    try:
        shutil.copy2(path, path.with_name(path.name + ".bak"))
    except OSError as exc:
        raise LtmError(f"cannot back up {str(path)!r}: {exc.strerror or exc}") from None
    write_text_atomic(path, json.dumps(meta, indent=2) + "\n", what="acquisition")
