"""Where the rectified frame lies on the object plane, from a near-light capture alone.

A pixel at ``P = (X, Y, 0)`` under a point light at ``L = (r, s, h)`` is lit with the fall-off
``g = (h / d)^m / d^2`` and, for a flat diffuse surface, the cosine ``h / d``: its samples follow
a radial profile about the light position right above it::

    t(L) = a + b (1 + |L - P|^2 / h^2)^(-q)          (q = 3/2 for a Lambertian, isotropic LED)

A specular lobe seen by a camera looking down peaks there too (the half vector is the normal
when the light is right above a flat pixel), and an LED's ``cos^m`` emission only narrows the
profile (``q = 3/2 + m/2``), so ``q`` is one free number per capture.

:func:`place_pixels` fits ``P`` (with ``a``, ``b``) for a sample of pixels: the normalised
correlation of each pixel's samples with the profile centred on a grid of candidate positions
picks a start, a few batched Levenberg-Marquardt steps refine it. The half of the pixels whose
profile explains the most of their variance is kept. The rectified frame maps pixels to the
plane by an affine map ``P = P0 + A (col + 1/2, row + 1/2)`` in any orientation: camera B's image
axes need not run along ``r`` and ``s`` (a tracker, an AR app or a camera upside down gives any
turn, mirrored or not). :func:`fit_map` fits it by a robust regression of the pixels' positions
on their columns and rows (a least-median start from pixel triplets, then Tukey's biweight),
rounds it to the nearest of the eight turns by multiples of 90 degrees, and keeps the simplest
map the data do not reject (square pixels along that turn, separate sides, a similarity turned
by any angle, any affine map); a bootstrap over image blocks gives its statistical uncertainty
(neighbouring pixels share their errors), each edge of the frame across itself.

Where it fails: a tilted normal moves its pixel's peak (about ``0.2 h`` per unit of slope for
a glossy paint at ``h = 0.3``); random tilts average out over the frame, tilts alike do not: a
relief's frame whose bevel slopes inwards all round pulls the edges in (10 % of the side where
the bevel fills a quarter of a 32 px frame, 3 % at 64 px), a bias no bootstrap over pixels
sees. A light path that stays on one side of the object sees the profiles' flanks only
(``support`` measures how much of the estimated extent lies inside the lights' range); a
capture without fall-off (far lights) has no position to find. Pure NumPy, vectorised over
pixels: about 0.6 s of one core for 4096 pixels and 176 cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PROFILES = (1.5, 2.0, 2.5, 3.0, 4.0, 6.0)  # candidate exponents q of the radial profile
GRID_STEP = 1.0  # candidate start positions every this many ...
MARGIN = 0.25  # ... over the lights' range widened by this share of it on each side
LM_STEPS = 12  # Levenberg-Marquardt iterations per pixel
TUKEY = 4.685  # biweight constant, in robust standard deviations
BLOCK = 8  # pixels per side of the bootstrap's image blocks
BOOTSTRAP = 200  # bootstrap replicates
MIN_PIXELS = 16  # fewer placed pixels than this: no estimate
KEEP_QUANTILE = 0.5  # pixels whose profile explains less than this quantile are dropped
PAIRS = 20000  # random pixel pairs of the robust start of a frame along the plane's axes
STARTS = 300  # random pixel triplets of the robust start of any affine map
SELECT_SIGMAS = 3.0  # a more general map is kept where the data insist by this many sigmas
MODELS = ("square", "sides", "similarity", "affine")  # the maps fit_map weighs
CORNERS = ("top_left", "top_right", "bottom_left")  # the corners that name a map
# the frame's turns by multiples of 90 degrees, mirrored or not: (col, row) -> (r, s) directions
SIGNED_PERMUTATIONS = tuple(np.array(m, float) for m in (
    [[1, 0], [0, -1]], [[-1, 0], [0, -1]], [[1, 0], [0, 1]], [[-1, 0], [0, 1]],
    [[0, 1], [1, 0]], [[0, -1], [1, 0]], [[0, 1], [-1, 0]], [[0, -1], [-1, 0]]))


@dataclass(frozen=True)
class Placement:
    """The frame's map to the object plane, estimated from the samples.

    Attributes
    ----------
    extent : dict
        The map as ``acquisition.json``'s ``object`` writes it (plane units): ``{"x": [left,
        right], "y": [bottom, top]}`` where the frame's columns run along ``+r`` and its rows
        down ``s``, else the plane positions of three corners of the frame, ``{"top_left": [r,
        s], "top_right": [r, s], "bottom_left": [r, s]}``.
    sigma : dict
        Bootstrap standard deviation of each edge of the frame across itself, plane units:
        ``{"x": [left, right], "y": [bottom, top]}`` (the frame's left, right, bottom and top
        edges; for a frame along ``r`` and ``s``, those of the four numbers of ``extent``).
    pitch : tuple of float
        Pixel side ``(along the frame's rows, along its columns)``: the plane distance from one
        column to the next, and from one row to the next, plane units.
    profile : float
        The exponent ``q`` of the radial profile that fitted best.
    pixels : int
        Pixels placed; ``inliers`` of them kept by the robust regression.
    inliers : int
    scatter : float
        Robust standard deviation of the pixels' positions about the fitted map, plane units.
    support : float
        Share of the estimated frame's area inside the range of the observed lights.
    model : str
        The map kept (:func:`fit_map`): ``square`` or ``sides`` (turned by a multiple of 90
        degrees), ``similarity`` (by any angle) or ``affine``.
    turn : float
        The frame's turn on the plane, degrees counter-clockwise from columns along ``+r`` and
        rows along ``-s``; ``turn_sigma`` the bootstrap's standard deviation of a turn by any
        angle (whichever model is kept).
    turn_sigma : float
    mirrored : bool
        Whether the frame is mirrored (left to right, before the turn).
    """

    extent: dict
    sigma: dict
    pitch: tuple[float, float]
    profile: float
    pixels: int
    inliers: int
    scatter: float
    support: float
    model: str = "square"
    turn: float = 0.0
    turn_sigma: float = 0.0
    mirrored: bool = False

    @property
    def corners(self) -> np.ndarray:
        """The plane positions ``(3, 2)`` of the frame's top-left, top-right and bottom-left
        corners."""
        return frame_corners(self.extent)

    @property
    def sides(self) -> tuple[float, float]:
        """The frame's width and height on the plane (plane units)."""
        tl, tr, bl = self.corners
        return float(np.hypot(*(tr - tl))), float(np.hypot(*(bl - tl)))

    @property
    def sigma_max(self) -> float:
        """The largest of the four standard deviations, plane units."""
        return float(max(*self.sigma["x"], *self.sigma["y"]))

    @property
    def sigma_pixels(self) -> float:
        """:attr:`sigma_max` in pixels (of the smaller side)."""
        return self.sigma_max / min(self.pitch)

    def to_json(self) -> dict:
        """A JSON record (plane units, and the uncertainty in pixels)."""
        return {"extent": self.extent, "sigma": self.sigma, "sigma_max": self.sigma_max,
                "sigma_pixels": self.sigma_pixels, "pitch": list(self.pitch),
                "profile": self.profile, "pixels": self.pixels, "inliers": self.inliers,
                "scatter": self.scatter, "support": self.support,
                "orientation": {"model": self.model, "turn_degrees": self.turn,
                                "turn_sigma_degrees": self.turn_sigma,
                                "mirrored": self.mirrored}}


def profile(lights: np.ndarray, where: np.ndarray, height: float, q: float) -> np.ndarray:
    """``(1 + |L - P|^2 / h^2)^(-q)`` for the lights ``(K, 2)`` and positions ``(G, 2)``:
    ``(G, K)``."""
    d2 = ((where[:, None, :] - lights[None, :, :]) ** 2).sum(-1)
    return (1 + d2 / height**2) ** -q


def _candidates(lights: np.ndarray, height: float) -> np.ndarray:
    """Start positions: a grid over the lights' range widened by :data:`MARGIN`, every
    :data:`GRID_STEP` of the mean spacing of the lights' range over sqrt(K)."""
    lo, hi = lights.min(0), lights.max(0)
    span = np.maximum(hi - lo, 1e-3 * height)
    step = GRID_STEP * float(np.sqrt(np.prod(span) / len(lights)))
    axes = [np.arange(a - MARGIN * w, b + MARGIN * w + step / 2, step)
            for a, b, w in zip(lo, hi, span, strict=True)]
    xx, yy = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([xx.ravel(), yy.ravel()])


def _correlate(centred: np.ndarray, lights: np.ndarray, grid: np.ndarray, height: float,
               q: float) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's best grid position for the profile ``q`` and the variance it explains
    there (normalised correlation of the centred samples with the centred profile)."""
    f = profile(lights, grid, height, q)
    f -= f.mean(1, keepdims=True)
    f /= np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-30)
    score = centred @ f.T  # (n, G)
    pick = score.argmax(1)
    return pick, np.maximum(score[np.arange(len(pick)), pick], 0) ** 2


def _start(values: np.ndarray, lights: np.ndarray, height: float
           ) -> tuple[np.ndarray, float]:
    """Each pixel's best candidate position, and the profile exponent of :data:`PROFILES`
    that explains most of the pixels' variance. All of them choose it: a random subset (512
    pixels) chose another exponent for the same frame turned by 90 degrees, and its corners
    4.2 mm off relit 0.8 dB below the unturned frame's (tests/stages/test_orientation.py)."""
    centred = values - values.mean(1, keepdims=True)
    grid = _candidates(lights, height)
    scores = {q: _correlate(centred, lights, grid, height, q) for q in PROFILES}
    q = max(PROFILES, key=lambda q: scores[q][1].sum())
    return grid[scores[q][0]], q


def _linear(values: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the least-squares ``a, b`` of ``values ~ a + b f`` (both ``(n, K)``)."""
    fm, vm = f.mean(1), values.mean(1)
    fc = f - fm[:, None]
    b = ((values - vm[:, None]) * fc).sum(1) / np.maximum((fc**2).sum(1), 1e-30)
    return vm - b * fm, b


def _refine(values: np.ndarray, lights: np.ndarray, height: float, q: float,
            where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on ``(a, b, X, Y)`` of every pixel at once, from ``where``.
    Returns the positions ``(n, 2)`` and each pixel's share of variance explained."""
    pos = where.astype(float).copy()
    lam = np.full(len(values), 1e-3)

    def model(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        dx = p[:, 0, None] - lights[None, :, 0], p[:, 1, None] - lights[None, :, 1]
        u = 1 + (dx[0] ** 2 + dx[1] ** 2) / height**2
        f = u**-q
        a, b = _linear(values, f)
        res = values - a[:, None] - b[:, None] * f
        return (res**2).sum(1), res, f, (-2 * q / height**2) * (f / u) * b[:, None], dx

    err, res, f, scale, dx = model(pos)
    for _ in range(LM_STEPS):
        cols = (np.ones_like(f), f, scale * dx[0], scale * dx[1])  # the Jacobian's columns
        jtj = np.empty((len(values), 4, 4))
        for i in range(4):
            for j in range(i, 4):
                jtj[:, i, j] = jtj[:, j, i] = (cols[i] * cols[j]).sum(1)
        jtr = np.stack([(c * res).sum(1) for c in cols], axis=1)
        damped = jtj + lam[:, None, None] * (np.eye(4) * (jtj.diagonal(0, 1, 2)[:, None] + 1e-30))
        step = np.linalg.solve(damped, jtr[..., None])[..., 0]
        trial = pos + step[:, 2:]
        new = model(trial)
        better = new[0] < err
        pos[better] = trial[better]
        err, res, f, scale = (np.where(better[:, None] if o.ndim == 2 else better, n_, o)
                              for n_, o in zip(new[:4], (err, res, f, scale), strict=True))
        dx = tuple(np.where(better[:, None], n_, o) for n_, o in zip(new[4], dx, strict=True))
        lam = np.where(better, lam / 3, lam * 4)
    total = ((values - values.mean(1, keepdims=True)) ** 2).sum(1)
    return pos, 1 - err / np.maximum(total, 1e-30)


def place_pixels(values: np.ndarray, lights: np.ndarray, height: float
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Each pixel's position on the object plane from its samples.

    Parameters
    ----------
    values : ndarray of shape (n, K)
        Every pixel's samples at the ``K`` observed lights (linear, finite).
    lights : ndarray of shape (K, 2)
        The light positions ``(r, s)`` (plane units).
    height : float
        Height of the light plane above the object.

    Returns
    -------
    positions : ndarray of shape (n, 2)
        ``(X, Y)`` per pixel, plane units.
    explained : ndarray of shape (n,)
        Share of each pixel's variance the radial profile explains.
    q : float
        The profile exponent (of :data:`PROFILES`) that fitted best.
    """
    values = np.asarray(values, float)
    lights = np.asarray(lights, float)
    start, q = _start(values, lights, height)
    positions, explained = _refine(values, lights, height, q, start)
    return positions, explained, q


def frame_corners(extent: dict) -> np.ndarray:
    """The plane positions ``(3, 2)`` of the frame's top-left, top-right and bottom-left corners
    from either form of an object map: ``{"x": [left, right], "y": [bottom, top]}`` (the
    frame's axes along ``r`` and ``s``, mirrored where ``left > right`` or ``bottom > top``) or
    ``{"top_left": [r, s], "top_right": [r, s], "bottom_left": [r, s]}`` (any orientation)."""
    if "x" in extent:
        (left, right), (bottom, top) = extent["x"], extent["y"]
        return np.array([[left, top], [right, top], [left, bottom]], float)
    return np.array([extent[k] for k in CORNERS], float)


def pixel_map(corners: np.ndarray, image: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``origin (2,)`` and ``A (2, 2)`` of the map ``P = origin + A (col + 1/2, row + 1/2)`` of a
    frame ``image (H, W)`` whose corners are ``corners`` (:func:`frame_corners`)."""
    tl, tr, bl = np.asarray(corners, float)
    h, w = image
    return tl, np.column_stack([(tr - tl) / w, (bl - tl) / h])


def _bases(model: str, turn: np.ndarray) -> list[np.ndarray]:
    """The ``2 x 2`` matrices whose combination is a model's linear part ``A``: ``affine`` (any)
    or ``similarity`` (turned and scaled, mirrored as the signed permutation ``turn`` is)."""
    if model == "affine":
        return [np.eye(2)[:, [i]] * np.eye(2)[[j]] for i in range(2) for j in range(2)]
    m = 1.0 if np.linalg.det(turn) > 0 else -1.0
    return [np.array([[1.0, 0.0], [0.0, m]]), np.array([[0.0, -m], [1.0, 0.0]])]


def _design(rows: np.ndarray, cols: np.ndarray, bases: list[np.ndarray]) -> np.ndarray:
    """The stacked regression ``[X; Y] = D theta``, ``theta = (x0, y0, c_1, ...)`` and
    ``A = sum c_k bases[k]``."""
    n, u, v = len(rows), cols + 0.5, rows + 0.5
    zero, one = np.zeros(n), np.ones(n)
    top = [one, zero] + [b[0, 0] * u + b[0, 1] * v for b in bases]
    bottom = [zero, one] + [b[1, 0] * u + b[1, 1] * v for b in bases]
    return np.vstack([np.column_stack(top), np.column_stack(bottom)])


def _linear_part(theta: np.ndarray, bases: list[np.ndarray]) -> np.ndarray:
    """``A`` of parameters ``theta (..., 2 + k)``: ``(..., 2, 2)``."""
    return np.einsum("...k,kij->...ij", theta[..., 2:], np.array(bases))


def _start_affine(design: np.ndarray, target: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """A high-breakdown start (least median of squares): the exact affine map of each of
    :data:`STARTS` random, well spread pixel triplets; the one whose median residual is least
    (a quarter of the pixels displaced alike cannot move it)."""
    n = len(rows)
    pick = rng.integers(0, n, (8 * STARTS, 3))
    u, v = cols[pick], rows[pick]
    area = np.abs((u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0])
                  - (u[:, 2] - u[:, 0]) * (v[:, 1] - v[:, 0]))
    pick = pick[area >= 0.05 * max(np.ptp(cols), 1) * max(np.ptp(rows), 1)][:STARTS]
    if not len(pick):
        return np.linalg.lstsq(design, target, rcond=None)[0]
    idx = np.concatenate([pick, pick + n], axis=1)  # the X and Y rows of each triplet
    thetas = np.linalg.solve(design[idx], target[idx][..., None])[..., 0]
    med = np.median(np.abs(target[:, None] - design @ thetas.T), axis=0)
    return thetas[int(np.argmin(med))]


def _robust_fit(design: np.ndarray, target: np.ndarray, start: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Tukey-biweight IRLS from ``start``: parameters, final weights and the robust residual
    scale."""
    theta = start
    w = np.ones(len(target))
    scale = 0.0
    for _ in range(30):
        res = target - design @ theta
        scale = 1.4826 * float(np.median(np.abs(res))) + 1e-12
        z = res / (TUKEY * scale)
        w = np.where(np.abs(z) < 1, (1 - z**2) ** 2, 0.0)
        sw = np.sqrt(w)
        theta = np.linalg.lstsq(design * sw[:, None], target * sw, rcond=None)[0]
    return theta, w, scale


def _bootstrap(design: np.ndarray, target: np.ndarray, weights: np.ndarray, block: np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
    """Weighted least-squares parameters over :data:`BOOTSTRAP` resamplings of whole image
    blocks (the robust weights held fixed): each block's normal equations summed once, then
    each resampling's as the blocks it draws, solved (minimum norm, as ``lstsq``)."""
    n_blocks = int(block.max()) + 1
    both = np.concatenate([block, block])
    weighted = design * weights[:, None]
    k = design.shape[1]
    gram = np.zeros((n_blocks, k, k))
    np.add.at(gram, both, weighted[:, :, None] * design[:, None, :])
    moment = np.zeros((n_blocks, k))
    np.add.at(moment, both, weighted * target[:, None])
    times = np.array([np.bincount(rng.integers(0, n_blocks, n_blocks), minlength=n_blocks)
                      for _ in range(BOOTSTRAP)], float)
    return (np.linalg.pinv(np.einsum("rb,bij->rij", times, gram))
            @ (times @ moment)[..., None])[..., 0]


def _aligned_design(rows: np.ndarray, cols: np.ndarray, square: bool) -> np.ndarray:
    """The regression of a frame along the plane's axes, ``X = left + w_x (col + 1/2)``, ``Y =
    top - w_y (row + 1/2)``: ``theta = (left, top, w)`` with square pixels, ``(left, top, w_x,
    w_y)`` without (``rows``, ``cols`` turned by :func:`_along`)."""
    n, u, v = len(rows), cols + 0.5, -(rows + 0.5)
    zero, one = np.zeros(n), np.ones(n)
    top = [one, zero, u] + ([] if square else [zero])
    bottom = [zero, one, v] if square else [zero, one, zero, v]
    return np.vstack([np.column_stack(top), np.column_stack(bottom)])


def _pair_slope(coord: np.ndarray, value: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Slopes ``d value / d coord`` of random pairs of points at least a quarter of the
    coordinate's range apart (the pairs of a Theil-Sen estimate, subsampled)."""
    i, j = rng.integers(0, len(coord), (2, PAIRS))
    dc = coord[j] - coord[i]
    keep = np.abs(dc) >= max(1.0, np.ptp(coord) / 4)
    return (value[j] - value[i])[keep] / dc[keep]


def _start_aligned(design: np.ndarray, target: np.ndarray, square: bool,
                   rng: np.random.Generator) -> np.ndarray:
    """A high-breakdown start: pixel sides from the median of pair slopes, offsets from the
    median of what they leave (a quarter of the pixels displaced alike cannot move it)."""
    n = len(target) // 2
    u, v = design[:n, 2], design[n:, -1]
    x, y = target[:n], target[n:]
    sx, sy = _pair_slope(u, x, rng), _pair_slope(v, y, rng)
    if square:
        w = float(np.median(np.concatenate([sx, sy]))) if len(sx) + len(sy) else 0.0
        wx = wy = w
    else:
        wx = float(np.median(sx)) if len(sx) else 0.0
        wy = float(np.median(sy)) if len(sy) else 0.0
    left, top = float(np.median(x - wx * u)), float(np.median(y - wy * v))
    return np.array([left, top, wx] if square else [left, top, wx, wy])


def _along(turn: np.ndarray, rows: np.ndarray, cols: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """The pixels' rows and columns counted along the plane's ``-s`` and ``r`` for a frame
    turned by the signed permutation ``turn`` (the identity for the usual frame)."""
    u, v = cols + 0.5, rows + 0.5
    return -(turn[1, 0] * u + turn[1, 1] * v) - 0.5, turn[0, 0] * u + turn[0, 1] * v - 0.5


def _fit_aligned(square: bool, turn: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                 target: np.ndarray, block: np.ndarray, rng: np.random.Generator) -> tuple:
    """The frame along the plane's axes, turned by ``turn``: square pixels or separate sides.
    Returns the map ``(origin, A)`` of the fit and of its bootstrap replicates, its weights and
    robust scale."""
    design = _aligned_design(*_along(turn, rows, cols), square)
    theta, w, scale = _robust_fit(design, target, _start_aligned(design, target, square, rng))
    reps = _bootstrap(design, target, w, block, rng)

    def linear(t: np.ndarray) -> np.ndarray:  # A = diag(w_x, w_y) turn
        sides = np.stack([t[..., 2], t[..., -1]], axis=-1)
        return sides[..., :, None] * turn

    return (theta[:2], linear(theta)), (reps[:, :2], linear(reps)), w, scale


@dataclass(frozen=True)
class MapFit:
    """The frame's map fitted by :func:`fit_map`: ``corners (3, 2)`` and their bootstrap
    replicates ``(B, 3, 2)``, the ``model`` kept, the ``turn`` (signed permutation) nearest the
    map, the ``pixels`` fitted, the robust fit's ``inliers`` and ``scatter``, and the
    bootstrap's standard deviation of the turn's angle (radians) of the ``similarity`` fit."""

    corners: np.ndarray
    replicates: np.ndarray
    model: str
    turn: np.ndarray
    pixels: int
    inliers: int
    scatter: float
    angle_sigma: float


def _fit_turned(model: str, turn: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                target: np.ndarray, weights: np.ndarray, block: np.ndarray,
                rng: np.random.Generator) -> tuple:
    """A ``similarity`` or ``affine`` map from the affine fit's robust ``weights``: as
    :func:`_fit_aligned`."""
    bases = _bases(model, turn)
    design = _design(rows, cols, bases)
    sw = np.sqrt(weights)
    start = np.linalg.lstsq(design * sw[:, None], target * sw, rcond=None)[0]
    theta, w, scale = _robust_fit(design, target, start)
    reps = _bootstrap(design, target, w, block, rng)
    return ((theta[:2], _linear_part(theta, bases)), (reps[:, :2], _linear_part(reps, bases)),
            w, scale)


def _angle(a: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """The angle (radians) of the rotation nearest ``a (..., 2, 2)`` times ``turn``'s
    transpose: how far the map is turned from the signed permutation ``turn``."""
    x = a @ turn.T
    return np.arctan2(x[..., 1, 0] - x[..., 0, 1], x[..., 0, 0] + x[..., 1, 1])


def _insists(value: np.ndarray, replicates: np.ndarray) -> bool:
    """Whether any of ``value (k,)`` lies beyond :data:`SELECT_SIGMAS` bootstrap standard
    deviations (``replicates (B, k)``) from zero."""
    spread = np.maximum(np.std(replicates, axis=0, ddof=1), 1e-15)
    return bool((np.abs(value) > SELECT_SIGMAS * spread).any())


def fit_map(rows: np.ndarray, cols: np.ndarray, positions: np.ndarray, image: tuple[int, int],
            *, seed: int = 0) -> MapFit:
    """The frame's map to the plane from the placed pixels ``positions (n, 2)`` at ``rows``,
    ``cols``, whatever its orientation.

    A robust affine fit first (:func:`_start_affine`, then Tukey's biweight) and the signed
    permutation nearest it (the frame's turn by a multiple of 90 degrees, mirrored or not);
    then the simplest map the data do not reject by :data:`SELECT_SIGMAS` bootstrap standard
    deviations: square pixels along that turn, separate sides along it (each from a Theil-Sen
    start), a similarity turned by any angle, or any affine map.
    """
    target = np.concatenate([positions[:, 0], positions[:, 1]])
    blocks = (rows // BLOCK) * (image[1] // BLOCK + 1) + cols // BLOCK
    _, block = np.unique(blocks, return_inverse=True)
    rng, rng_turned = (np.random.default_rng([seed, k]) for k in (2811, 2812))
    affine = _design(rows, cols, _bases("affine", np.eye(2)))
    theta, weights, _ = _robust_fit(affine, target,
                                    _start_affine(affine, target, rows, cols, rng_turned))
    a = _linear_part(theta, _bases("affine", np.eye(2)))
    turn = max(SIGNED_PERMUTATIONS, key=lambda d: float((d * a).sum()))
    fits = {m: _fit_aligned(m == "square", turn, rows, cols, target, block, rng)
            for m in ("square", "sides")}
    fits |= {m: _fit_turned(m, turn, rows, cols, target, weights, block, rng_turned)
             for m in ("similarity", "affine")}
    angles = _angle(fits["similarity"][1][1], turn)
    if _insists(np.atleast_1d(_angle(fits["similarity"][0][1], turn)), angles[:, None]):
        m = 1.0 if np.linalg.det(turn) > 0 else -1.0

        def departure(x: np.ndarray) -> np.ndarray:  # of A from the nearest similarity
            return np.stack([x[..., 0, 0] - m * x[..., 1, 1], x[..., 0, 1] + m * x[..., 1, 0]],
                            axis=-1)
        fit, reps = fits["affine"][0][1], fits["affine"][1][1]
        model = "affine" if _insists(departure(fit), departure(reps)) else "similarity"
    else:
        def aspect(x: np.ndarray) -> np.ndarray:  # the row's pixel side less the column's
            return np.hypot(*np.moveaxis(x[..., :, 1], -1, 0)) - np.hypot(
                *np.moveaxis(x[..., :, 0], -1, 0))
        sides = fits["sides"]
        model = "sides" if _insists(np.atleast_1d(aspect(sides[0][1])),
                                    aspect(sides[1][1])[:, None]) else "square"
    (origin, lin), (rep_origin, rep_lin), w, scale = fits[model]

    def corners(o: np.ndarray, x: np.ndarray) -> np.ndarray:
        h, wd = image
        return np.stack([o, o + x[..., :, 0] * wd, o + x[..., :, 1] * h], axis=-2)

    return MapFit(corners=corners(origin, lin), replicates=corners(rep_origin, rep_lin),
                  model=model, turn=turn, pixels=len(rows),
                  inliers=int((w[: len(rows)] > 0).sum()), scatter=scale,
                  angle_sigma=float(np.std(angles, ddof=1)))


def edge_sigma(corners: np.ndarray, replicates: np.ndarray) -> np.ndarray:
    """Each frame edge's standard deviation ``(left, right, bottom, top)`` across itself (the
    larger of its two ends) over the corners' ``replicates (B, 3, 2)`` of ``corners (3, 2)``:
    for a frame along ``r`` and ``s``, those of ``left``, ``right``, ``bottom``, ``top``."""
    lr, tb = _normals(corners)
    ends = _four(replicates)
    return np.array([max(float(np.std(ends[:, e] @ normal, ddof=1)) for e in pair)
                     for pair, normal in zip(EDGE_ENDS, (lr, lr, tb, tb), strict=True)])


def _four(corners: np.ndarray) -> np.ndarray:
    """The four corners ``(..., 4, 2)`` (top-left, top-right, bottom-left, bottom-right) of
    three ``(..., 3, 2)``."""
    c = np.asarray(corners, float)
    return np.concatenate([c, (c[..., 1, :] + c[..., 2, :] - c[..., 0, :])[..., None, :]], -2)


def _normals(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit plane directions across the frame's left and right edges, and across its bottom
    and top edges."""
    tl, tr, bl = np.asarray(corners, float)
    col, row = tr - tl, bl - tl
    return (np.array([row[1], -row[0]]) / max(float(np.hypot(*row)), 1e-300),
            np.array([col[1], -col[0]]) / max(float(np.hypot(*col)), 1e-300))


EDGE_ENDS = ((0, 2), (1, 3), (2, 3), (0, 1))  # left, right, bottom, top: corners of _four


def edge_offsets(corners: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """How far each edge ``(left, right, bottom, top)`` of the frame with ``corners (..., 3, 2)``
    lies from that of ``reference (3, 2)`` across it (the larger of its two ends; plane units):
    for frames along ``r`` and ``s``, the differences of ``left``, ``right``, ``bottom``,
    ``top``."""
    lr, tb = _normals(reference)
    diff = _four(corners) - _four(reference)
    return np.stack([np.abs(diff[..., list(ends), :] @ normal).max(-1) for ends, normal in zip(
        EDGE_ENDS, (lr, lr, tb, tb), strict=True)], axis=-1)


def _clip(polygon: list[np.ndarray], axis: int, bound: float, above: bool) -> list[np.ndarray]:
    """The part of a convex ``polygon`` on one side of ``coordinate axis = bound``."""
    out = []
    for i in range(len(polygon)):
        p, q = polygon[i - 1], polygon[i]
        p_in, q_in = ((p[axis] >= bound, q[axis] >= bound) if above
                      else (p[axis] <= bound, q[axis] <= bound))
        if p_in != q_in:
            out.append(p + (bound - p[axis]) / (q[axis] - p[axis]) * (q - p))
        if q_in:
            out.append(q)
    return out


def _area(polygon: list[np.ndarray]) -> float:
    if len(polygon) < 3:
        return 0.0
    x, y = np.array(polygon).T
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2)


def support(corners: np.ndarray, lights: np.ndarray) -> float:
    """Share of the area of the frame with ``corners`` (:func:`frame_corners`) inside the
    lights' range."""
    tl, tr, bl = np.asarray(corners, float)
    polygon = [tl, tr, tr + bl - tl, bl]
    area = _area(polygon)
    lo, hi = lights.min(0), lights.max(0)
    for axis in (0, 1):
        polygon = _clip(_clip(polygon, axis, lo[axis], True), axis, hi[axis], False)
    return _area(polygon) / area if area > 0 else 0.0


def turn_degrees(corners: np.ndarray) -> tuple[float, bool]:
    """The frame's turn on the plane (degrees in ``(-180, 180]``, counter-clockwise, from columns
    along ``+r`` and rows along ``-s``) and whether it is mirrored (left to right, before the
    turn)."""
    tl, tr, bl = np.asarray(corners, float)
    a = np.column_stack([tr - tl, tl - bl])  # columns, and rows upwards: det > 0 unmirrored
    mirrored = bool(np.linalg.det(a) < 0)
    if mirrored:
        a = a * [-1.0, 1.0]
    turn = float(np.degrees(np.arctan2(a[1, 0] - a[0, 1], a[0, 0] + a[1, 1])))
    return 180.0 - (180.0 - turn) % 360.0, mirrored  # in (-180, 180]


def extent_of(corners: np.ndarray, model: str, turn: np.ndarray) -> dict:
    """The map as ``acquisition.json``'s ``object`` writes it: ``{"x", "y"}`` where the frame's
    columns run along ``+r`` and its rows down ``s``, else its three corners."""
    (tl, tr, bl) = (c.tolist() for c in np.asarray(corners, float))
    if model in ("square", "sides") and np.array_equal(turn, SIGNED_PERMUTATIONS[0]):
        return {"x": [tl[0], tr[0]], "y": [bl[1], tl[1]]}
    return dict(zip(CORNERS, (tl, tr, bl), strict=True))


def fit_frame(values: np.ndarray, rows: np.ndarray, cols: np.ndarray, image: tuple[int, int],
              lights: np.ndarray, height: float, *, seed: int = 0) -> tuple[MapFit, float] | None:
    """The frame's map from the samples of a subset of its pixels (:func:`place_pixels`, then
    :func:`fit_map` of the half whose profile explains most), and the profile's exponent; the
    parameters are :func:`estimate_placement`'s. None where fewer than :data:`MIN_PIXELS`
    pixels have any variation to place."""
    values = np.asarray(values, float)
    lights = np.asarray(lights, float)
    varied = values.std(1) > 1e-6 * max(float(np.abs(values).max()), 1e-30)
    if varied.sum() < MIN_PIXELS or len(lights) < 4:
        return None
    rows, cols, values = np.asarray(rows)[varied], np.asarray(cols)[varied], values[varied]
    positions, explained, q = place_pixels(values, lights, height)
    good = explained >= np.quantile(explained, KEEP_QUANTILE)  # the most radial profiles
    return fit_map(rows[good], cols[good], positions[good], image, seed=seed), q


def placement_of(fit: MapFit, image: tuple[int, int], lights: np.ndarray,
                 profile: float) -> Placement:
    """The :class:`Placement` of a frame ``image (H, W)`` mapped by ``fit``, with the lights'
    support of it and the radial ``profile``'s exponent."""
    sigma = edge_sigma(fit.corners, fit.replicates)
    _, lin = pixel_map(fit.corners, image)
    turn, mirrored = turn_degrees(fit.corners)
    return Placement(extent=extent_of(fit.corners, fit.model, fit.turn),
                     sigma={"x": [float(sigma[0]), float(sigma[1])],
                            "y": [float(sigma[2]), float(sigma[3])]},
                     pitch=(float(np.hypot(*lin[:, 0])), float(np.hypot(*lin[:, 1]))),
                     profile=float(profile), pixels=int(fit.pixels), inliers=fit.inliers,
                     scatter=float(fit.scatter),
                     support=support(fit.corners, np.asarray(lights, float)),
                     model=fit.model, turn=turn, turn_sigma=float(np.degrees(fit.angle_sigma)),
                     mirrored=mirrored)


def estimate_placement(values: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                       image: tuple[int, int], lights: np.ndarray, height: float, *,
                       seed: int = 0) -> Placement | None:
    """The frame's map to the object plane from the samples of a subset of its pixels.

    Parameters
    ----------
    values : ndarray of shape (n, K)
        Samples of ``n`` pixels at the ``K`` observed lights (linear, finite).
    rows, cols : ndarray of shape (n,)
        The pixels' row and column in the frame.
    image : (int, int)
        The frame's ``(H, W)``.
    lights : ndarray of shape (K, 2)
        Light positions ``(r, s)`` of the samples, plane units.
    height : float
        Height of the light plane above the object.
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    Placement or None
        None where fewer than :data:`MIN_PIXELS` pixels have any variation to place.
    """
    found = fit_frame(values, rows, cols, image, lights, height, seed=seed)
    return None if found is None else placement_of(found[0], image, lights, found[1])
