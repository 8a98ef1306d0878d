"""Light directions from reflective spheres photographed beside the object (``ltm lights``).

A chrome or black glossy sphere shows each light as a highlight where its normal ``n`` bisects
the view ``v`` and the light: ``l = 2 (n.v) n - v``. The camera is taken as orthographic,
looking down the object's normal (``v = (0, 0, 1)``), as the ``.lp`` file's directions assume.
Image coordinates follow OpenCV (pixel centres at integers); directions x right, y up, z
towards the camera, as :func:`ltmstore.capture.lp.read_lp` reads them.

Steps:

1. the spheres: found by a Hough transform on the median of a few photographs
   (:func:`detect_spheres`) or given as a crop ``(x, y, r)``, then refined to a fraction of a
   pixel by fitting a circle to the outline's edge, sampled along rays (:func:`refine_sphere`);
2. in every photograph, on every sphere, the highlight (:func:`find_highlight`): the connected
   blob above half its contrast around the brightest pixel inside 0.85 r, its sphere normals
   averaged with the blob's brightness above that threshold as weights (a clipped blob: its
   centroid), so that the estimate is sub-pixel;
3. the direction: the mirror of the mean normal; with two or more spheres, the least-squares
   meeting point of the reflected rays (a near light's position, :func:`triangulate`) where the
   rays are not parallel, the direction from the image centre towards it; else their mean.

Failures are named in one line (:class:`SphereError`): no sphere found, a highlight clipped
across a sphere (overexposed), a photograph whose highlight is missing on every sphere.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from ltmstore.core.errors import LtmError

SEARCH = 0.85  # highlights are looked for within this fraction of the radius (normals < 58 deg)
CLIPPED_SHARE = 0.2  # a photograph with more of a sphere's disc saturated is overexposed
SATURATED = 0.965  # linear (sRGB code 0.985 of white): a saturated pixel
MIN_CONTRAST = 0.05  # linear: the highlight above the sphere's median
RELATIVE_CONTRAST = 0.25  # ... and at least this share of the photographs' median contrast
SPOT_CONTRAST = 0.3  # linear: a detected sphere's highlight (a lit metal relief's: 0.1-0.2)
SPOT_AREA = 0.03  # a highlight's blob covers at most this share of the searched disc
SPOT_ALONE = 0.8  # ... and holds at least this share of the disc's bright pixels
MEDIAN_PHOTOS = 9  # photographs whose median finds the spheres
PARALLEL_DEG = 2.0  # rays closer than this in angle meet too far to place the light
EDGE_RAYS = 360
DETECT_SIDE = 800  # the median is shrunk to this many pixels (longest side) to find circles


class SphereError(LtmError):
    """No sphere, or a highlight that cannot be measured (one line)."""


@dataclass(frozen=True)
class Sphere:
    """A sphere's outline: centre ``(x, y)`` and radius ``r`` in pixels (OpenCV convention)."""

    x: float
    y: float
    r: float

    def describe(self) -> str:
        return f"({self.x:.1f}, {self.y:.1f}) r {self.r:.1f} px"


@dataclass
class Lights:
    """What :func:`lights_from_spheres` found.

    ``directions (n, 3)`` towards the lights; ``positions (n, 3)`` near-light positions in
    pixels from the image centre on the object plane (NaN where the rays are parallel, or
    with one sphere); ``per_sphere (k, n, 3)`` each sphere's direction (NaN: no highlight);
    ``spheres`` the refined outlines; ``size`` the photographs' ``(height, width)``.
    """

    directions: np.ndarray
    positions: np.ndarray
    per_sphere: np.ndarray
    spheres: list[Sphere]
    size: tuple[int, int]
    notes: list[str] = field(default_factory=list)


def grey(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` float32 linear light in ``[0, 1]`` of an sRGB RGB (or grey) image of any
    integer depth: the brightest channel, so that a coloured light's highlight still saturates.
    Linear, so that an outline's anti-aliased edge and a blob's weights are not bent by the
    sRGB curve (measured: 0.15 px smaller radii from the sRGB codes)."""
    from ltmstore.core.transfer import srgb_to_linear

    scale = float(np.iinfo(image.dtype).max) if image.dtype.kind in "ui" else 1.0
    g = np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2]) \
        if image.ndim == 3 else image
    return srgb_to_linear(g.astype(np.float32) / np.float32(scale))


def detect_spheres(median: np.ndarray, *, count: int | None = None) -> list[Sphere]:
    """Circles in the median image ``median (H, W)`` (linear, ``[0, 1]``) by OpenCV's Hough
    gradient transform on its sRGB codes, shrunk to at most :data:`DETECT_SIDE` pixels (a
    large photograph's outlines are soft at full size); strongest first, at most ``count``.
    Candidates are refined and checked for highlights by the caller."""
    import cv2

    from ltmstore.core.transfer import linear_to_srgb

    scale = min(1.0, DETECT_SIDE / max(median.shape))
    code = np.round(linear_to_srgb(median) * 255).astype(np.uint8)
    if scale < 1:
        code = cv2.resize(code, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    code = cv2.GaussianBlur(code, (0, 0), 1.0)
    h, w = code.shape
    small = max(6, int(min(h, w) / 40))
    found = cv2.HoughCircles(code, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=2 * small,
                             param1=100, param2=0.75, minRadius=small,
                             maxRadius=int(min(h, w) / 2.5))
    circles = [] if found is None else found.reshape(-1, 3)
    spheres = [Sphere((x + 0.5) / scale - 0.5, (y + 0.5) / scale - 0.5, r / scale)
               for x, y, r in circles]
    return spheres if count is None else spheres[:count]


def _kasa(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares circle through points (Kasa's algebraic fit)."""
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x**2 + y**2
    (c0, c1, c2), *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = c0 / 2, c1 / 2
    return float(cx), float(cy), float(np.sqrt(max(c2 + cx**2 + cy**2, 0.0)))


def refine_sphere(image: np.ndarray, sphere: Sphere, *, passes: int = 3) -> Sphere:
    """The outline of ``sphere`` in ``image (H, W)`` to a fraction of a pixel: along
    :data:`EDGE_RAYS` rays from its centre, the strongest edge between 0.75 r and 1.25 r
    (parabolic peak of the gradient's magnitude), then a circle fitted to those points with
    the ones farther than 3 median deviations dropped."""
    h, w = image.shape
    y0, x0 = max(int(sphere.y - 1.5 * sphere.r), 0), max(int(sphere.x - 1.5 * sphere.r), 0)
    y1 = min(int(sphere.y + 1.5 * sphere.r) + 2, h)
    x1 = min(int(sphere.x + 1.5 * sphere.r) + 2, w)
    inner = _refine(image[y0:y1, x0:x1], Sphere(sphere.x - x0, sphere.y - y0, sphere.r), passes)
    return Sphere(inner.x + x0, inner.y + y0, inner.r)


def _refine(image: np.ndarray, sphere: Sphere, passes: int) -> Sphere:
    angles = np.linspace(0, 2 * np.pi, EDGE_RAYS, endpoint=False)
    for _ in range(passes):
        radii = np.arange(0.75 * sphere.r, 1.25 * sphere.r, 0.25)
        xs = sphere.x + np.cos(angles)[:, None] * radii
        ys = sphere.y + np.sin(angles)[:, None] * radii
        profile = ndimage.map_coordinates(image, [ys, xs], order=3, mode="nearest")
        slope = np.abs(np.gradient(profile, axis=1))
        k = np.clip(slope.argmax(axis=1), 1, len(radii) - 2)
        i = np.arange(len(angles))
        a, b, c = slope[i, k - 1], slope[i, k], slope[i, k + 1]
        curve = a - 2 * b + c
        shift = 0.5 * (a - c) / np.where(curve < 0, curve, -np.inf)  # 0 where no peak
        rho = radii[k] + np.clip(shift, -0.5, 0.5) * 0.25
        px, py = sphere.x + np.cos(angles) * rho, sphere.y + np.sin(angles) * rho
        keep = np.ones(len(px), bool)
        for _ in range(3):
            cx, cy, r = _kasa(px[keep], py[keep])
            resid = np.abs(np.hypot(px - cx, py - cy) - r)
            keep = resid <= max(3 * 1.4826 * np.median(resid[keep]), 0.05)
        sphere = Sphere(cx, cy, r)
    return sphere


@dataclass(frozen=True)
class Highlight:
    """One sphere's highlight in one photograph: ``normal`` (unit, NaN when missing), its
    image position ``(x, y)``, ``contrast`` (peak above the sphere's median, in ``[0, 1]``) and
    ``clipped`` (share of the sphere's disc saturated) and ``area`` (the blob's share of the
    searched disc: a highlight is small, a lit texture is not) and ``alone`` (the blob's share
    of the bright pixels: one highlight per light on a sphere, many on a metal relief)."""

    normal: np.ndarray
    x: float
    y: float
    contrast: float
    clipped: float
    area: float = 0.0
    alone: float = 0.0


def _disc(sphere: Sphere, shape: tuple[int, int], fraction: float
          ) -> tuple[slice, slice, np.ndarray, np.ndarray, np.ndarray]:
    """The sphere's bounding box, and inside it the mask of pixels within ``fraction`` r and
    their sphere coordinates ``dx`` (right), ``dy`` (up) in radii."""
    h, w = shape
    r = sphere.r * fraction
    y0, y1 = max(int(np.floor(sphere.y - r)), 0), min(int(np.ceil(sphere.y + r)) + 1, h)
    x0, x1 = max(int(np.floor(sphere.x - r)), 0), min(int(np.ceil(sphere.x + r)) + 1, w)
    row, col = np.mgrid[y0:y1, x0:x1]
    dx, dy = (col - sphere.x) / sphere.r, -(row - sphere.y) / sphere.r
    return slice(y0, y1), slice(x0, x1), dx**2 + dy**2 <= fraction**2, dx, dy


def find_highlight(image: np.ndarray, sphere: Sphere) -> Highlight:
    """The highlight of ``sphere`` in the grey ``image (H, W)`` in ``[0, 1]``.

    The blob: the connected pixels above half the contrast (median to peak) around the
    brightest pixel within :data:`SEARCH` r; its normal: the mean of the blob's sphere normals
    weighted by brightness above that threshold (equal weights where it is saturated).
    """
    rows, cols, full, _, _ = _disc(sphere, image.shape, 0.98)
    clipped = float((image[rows, cols][full] >= SATURATED).mean()) if full.any() else 0.0
    rows, cols, search, dx, dy = _disc(sphere, image.shape, SEARCH)
    patch = image[rows, cols]
    if not search.any():
        return Highlight(np.full(3, np.nan), np.nan, np.nan, 0.0, clipped, 1.0)
    values = np.where(search, patch, -np.inf)
    peak_at = np.unravel_index(np.argmax(values), values.shape)
    peak, base = float(patch[peak_at]), float(np.median(patch[search]))
    threshold = base + 0.5 * (peak - base)
    labels, _ = ndimage.label(values > threshold)
    if labels[peak_at] == 0:  # a flat disc: no highlight
        return Highlight(np.full(3, np.nan), np.nan, np.nan, 0.0, clipped, 1.0)
    blob = labels == labels[peak_at]
    weight = np.minimum(patch[blob], SATURATED) - threshold
    weight = np.where(weight > 0, weight, 0.0) + 1e-12
    bx, by = dx[blob], dy[blob]
    normals = np.column_stack([bx, by, np.sqrt(np.clip(1 - bx**2 - by**2, 0, None))])
    normal = (normals * weight[:, None]).sum(axis=0)
    normal /= np.linalg.norm(normal)
    x = sphere.x + normal[0] * sphere.r
    y = sphere.y - normal[1] * sphere.r
    return Highlight(normal, x, y, peak - base, clipped, float(blob.sum() / search.sum()),
                     float(blob.sum() / (labels > 0).sum()))


def mirror(normal: np.ndarray) -> np.ndarray:
    """The direction towards the light whose highlight is at ``normal (..., 3)``:
    ``2 (n.v) n - v`` with ``v = (0, 0, 1)``."""
    normal = np.asarray(normal, dtype=np.float64)
    return 2 * normal[..., 2:3] * normal - np.array([0.0, 0.0, 1.0])


def sphere_point(sphere: Sphere, normal: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The 3D point of ``sphere`` (resting on the object plane) at ``normal``, in pixels from
    the image centre (x right, y up, z towards the camera)."""
    h, w = size
    centre = np.array([sphere.x + 0.5 - w / 2, h / 2 - sphere.y - 0.5, sphere.r])
    return centre + sphere.r * np.asarray(normal)


def triangulate(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, float]:
    """The least-squares meeting point of the rays ``origins[k] + t directions[k]`` and the
    largest angle between two of them (degrees). NaN where fewer than two rays are given."""
    good = np.isfinite(directions).all(axis=1)
    o, d = origins[good], directions[good]
    if len(d) < 2:
        return np.full(3, np.nan), 0.0
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    spread = float(np.degrees(np.arccos(np.clip((d @ d.T).min(), -1, 1))))
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # (k, 3, 3): off-ray components
    point = np.linalg.solve(proj.sum(axis=0), np.einsum("kij,kj->i", proj, o))
    return point, spread


def _photo_name(path: str | os.PathLike) -> str:
    return Path(path).name


def _crop(given: Sequence[float], shape: tuple[int, int]) -> Sphere:
    """A ``--sphere X,Y,R`` crop as a :class:`Sphere`, refused unless its centre lies in the
    photographs and its radius is at least 3 pixels and fits them."""
    h, w = shape
    x, y, r = (float(v) for v in given)
    if not (np.isfinite([x, y, r]).all() and 0 <= x < w and 0 <= y < h
            and 3 <= r <= max(h, w)):
        raise SphereError(f"--sphere {x:g},{y:g},{r:g} must be a circle's centre inside the "
                          f"{w} x {h} px photographs and its radius (3 to {max(h, w)} px)")
    return Sphere(x, y, r)


def _sample(paths: Sequence[Path], read) -> list[np.ndarray]:
    """Grey linear images of up to :data:`MEDIAN_PHOTOS` photographs spread over the capture,
    all of the first one's size."""
    pick = np.unique(np.linspace(0, len(paths) - 1, min(MEDIAN_PHOTOS, len(paths))).round()
                     ).astype(int)
    images = [grey(read(paths[i])) for i in pick]
    for i, image in zip(pick, images, strict=True):
        if image.shape != images[0].shape:
            raise SphereError(f"photo {_photo_name(paths[i])!r} is {image.shape[1]} x "
                              f"{image.shape[0]} px; expected {images[0].shape[1]} x "
                              f"{images[0].shape[0]} px like the others")
    return images


def _check_highlights(name: str, found: list[Highlight], spheres: list[Sphere]) -> None:
    for k, (sphere, hl) in enumerate(zip(spheres, found, strict=True)):
        if hl.clipped > CLIPPED_SHARE:
            raise SphereError(f"photo {name!r}: highlight clipped across sphere {k + 1} at "
                              f"{sphere.describe()} ({100 * hl.clipped:.0f}% of its disc "
                              f"saturated); expected a small highlight: lower the exposure")


def _missing(contrasts: np.ndarray) -> np.ndarray:
    """``(n, k)`` bool: no highlight (too little contrast, absolutely or beside the
    photographs' median on that sphere)."""
    typical = np.median(contrasts, axis=0, keepdims=True)
    return (contrasts < MIN_CONTRAST) | (contrasts < RELATIVE_CONTRAST * typical)


def usable_spheres(median: np.ndarray, candidates: list[Sphere], photos: list[np.ndarray],
                   count: int | None) -> list[Sphere]:
    """The refined candidates that show a highlight in most of the sample ``photos``."""
    keep = []
    for candidate in candidates:
        sphere = refine_sphere(median, candidate)
        if not (0.5 * candidate.r < sphere.r < 1.5 * candidate.r):
            continue
        lights = [find_highlight(p, sphere) for p in photos]
        spots = np.array([hl.contrast >= SPOT_CONTRAST and hl.area <= SPOT_AREA
                          and hl.alone >= SPOT_ALONE for hl in lights])
        if spots.mean() >= 0.5 and len(
                {(round(hl.x), round(hl.y)) for hl in lights}) > min(2, len(lights) - 1):
            keep.append(sphere)
        if count is not None and len(keep) == count:
            break
    return keep


def lights_from_spheres(paths: Sequence[str | os.PathLike], *,
                        spheres: Sequence[tuple[float, float, float]] | None = None,
                        count: int | None = None, read=None) -> Lights:
    """Find the spheres and every photograph's light direction.

    Parameters
    ----------
    paths : sequence of path-like
        The photographs, all of one size.
    spheres : sequence of (x, y, r), optional
        The spheres' outlines, approximately (a crop); refined here. Default: detected.
    count : int, optional
        How many spheres to detect (default: every one that shows highlights).
    read : callable, optional
        ``read(path) -> (H, W, 3)`` integer RGB (default: the ``.lp`` reader's decoder).

    Returns
    -------
    Lights

    Raises
    ------
    SphereError
        No sphere found; a highlight clipped across a sphere; a photograph with no highlight
        on any sphere; photographs of different sizes.
    """
    read = read or _read
    paths = [Path(p) for p in paths]
    if not paths:
        raise SphereError("no photographs given; expected the capture's images")
    if count is not None and (isinstance(count, bool) or int(count) != count or count < 1):
        raise SphereError(f"--spheres {count!r} must be a whole number >= 1")
    sample = _sample(paths, read)
    median = np.median(np.stack(sample), axis=0)
    if spheres:
        found = [refine_sphere(median, _crop(s, median.shape)) for s in spheres]
    else:
        found = usable_spheres(median, detect_spheres(median), sample, count)
        if not found:
            raise SphereError(f"no sphere found in the {len(paths)} photographs (a round "
                              "outline showing a moving highlight); give one with --sphere "
                              "X,Y,R")
        if count is not None and len(found) < count:
            raise SphereError(f"found {len(found)} sphere(s) of the {count} asked for "
                              f"(--spheres): {'; '.join(s.describe() for s in found)}; give "
                              "the others with --sphere X,Y,R")
    return measure(paths, found, median.shape, read)


def _highlight_in_box(image: np.ndarray, sphere: Sphere) -> Highlight:
    """:func:`find_highlight` on the sphere's box of the integer RGB ``image`` alone (only
    those pixels are made linear: a 12 MP photograph's sphere is a small part of it)."""
    h, w = image.shape[:2]
    y0, x0 = max(int(sphere.y - sphere.r) - 2, 0), max(int(sphere.x - sphere.r) - 2, 0)
    y1, x1 = min(int(sphere.y + sphere.r) + 3, h), min(int(sphere.x + sphere.r) + 3, w)
    found = find_highlight(grey(image[y0:y1, x0:x1]), Sphere(sphere.x - x0, sphere.y - y0,
                                                                sphere.r))
    return Highlight(found.normal, found.x + x0, found.y + y0, found.contrast, found.clipped,
                     found.area, found.alone)


def measure(paths: list[Path], spheres: list[Sphere], size: tuple[int, int], read) -> Lights:
    """Every photograph's highlights on ``spheres`` and the lights they give."""
    normals = np.full((len(paths), len(spheres), 3), np.nan)
    contrasts = np.zeros((len(paths), len(spheres)))
    for i, path in enumerate(paths):
        image = read(path)
        if image.shape[:2] != tuple(size):
            raise SphereError(f"photo {_photo_name(path)!r} is {image.shape[1]} x "
                              f"{image.shape[0]} px; expected {size[1]} x {size[0]} like the "
                              "others")
        found = [_highlight_in_box(image, s) for s in spheres]
        _check_highlights(_photo_name(path), found, spheres)
        normals[i] = [hl.normal for hl in found]
        contrasts[i] = [hl.contrast for hl in found]
    missing = _missing(contrasts)
    if missing.all(axis=1).any():
        bad = [_photo_name(paths[i]) for i in np.flatnonzero(missing.all(axis=1))]
        more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
        raise SphereError(f"highlight missing in photo {', '.join(map(repr, bad[:3]))}{more} "
                          f"(no bright spot on the sphere at "
                          f"{'; '.join(s.describe() for s in spheres)}); expected the light "
                          "reflected in every photograph: drop those photographs")
    normals[missing] = np.nan
    per_sphere = np.moveaxis(mirror(normals), 1, 0)  # (k, n, 3)
    return combine(per_sphere, spheres, size)


def combine(per_sphere: np.ndarray, spheres: list[Sphere], size: tuple[int, int]) -> Lights:
    """The lights from each sphere's directions ``(k, n, 3)``: near-light positions where two
    or more rays meet at an angle of at least :data:`PARALLEL_DEG`, else the mean direction."""
    k, n, _ = per_sphere.shape
    positions = np.full((n, 3), np.nan)
    directions = np.nanmean(per_sphere, axis=0)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    notes = []
    if k >= 2:
        spreads = []
        for i in range(n):
            origins = np.array([sphere_point(s, (d + [0, 0, 1]) / np.linalg.norm(d + [0, 0, 1]),
                                             size) if np.isfinite(d).all() else np.full(3, 0.0)
                                for s, d in zip(spheres, per_sphere[:, i], strict=True)])
            point, spread = triangulate(origins, per_sphere[:, i])
            spreads.append(spread)
            if spread >= PARALLEL_DEG and point[2] > 0:
                positions[i] = point
                directions[i] = point / np.linalg.norm(point)
        placed = int(np.isfinite(positions[:, 0]).sum())
        notes.append(f"{placed} of {n} lights placed by triangulation (rays meeting at "
                     f"{np.median(spreads):.1f} deg, median); the others are far lights")
    return Lights(directions, positions, per_sphere, list(spheres), tuple(size), notes)


def _read(path: Path) -> np.ndarray:
    from ltmstore.capture.photographs import decode_image

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise SphereError(f"photo {str(path)!r} cannot be read: {exc.strerror}") from exc
    return decode_image(data, str(path))


def lp_text(names: Sequence[str], directions: np.ndarray) -> str:
    """The ``.lp`` file: the count, then ``name lx ly lz`` per photograph."""
    lines = [str(len(names))]
    lines += [f"{name} {d[0]:.6f} {d[1]:.6f} {d[2]:.6f}"
              for name, d in zip(names, directions, strict=True)]
    return "\n".join(lines) + "\n"


def dome_json(lights: Lights, *, image_width_mm: float | None = None) -> dict:
    """Relight's ``.dome`` file (JSON) for lights with 3D positions (``lightConfiguration``
    ``lights3d``): ``directions`` and ``positions3d`` as ``{"x", "y", "z"}`` objects, origin
    at the image centre on the object plane, x right, y up, z towards the camera; positions in
    mm when ``image_width_mm`` (the photographs' field width at the object) is given, else in
    image widths (``imageWidth`` 0, Relight's "width 1"). A light the spheres could not place
    (parallel rays) gets its direction at the placed lights' median distance."""
    h, w = lights.size
    unit = (image_width_mm or 1.0) / w
    pos = lights.positions * unit
    placed = np.isfinite(pos[:, 0])
    if placed.any():
        distance = float(np.median(np.linalg.norm(pos[placed], axis=1)))
        pos[~placed] = lights.directions[~placed] * distance

    def xyz(values: np.ndarray) -> list[dict]:
        return [{"x": float(v[0]), "y": float(v[1]), "z": float(v[2])} for v in values]

    return {"label": "ltm lights", "notes": "; ".join(lights.notes),
            "imageWidth": float(image_width_mm or 0.0), "domeDiameter": 0.0,
            "verticalOffset": 0.0,
            "lightConfiguration": "lights3d" if placed.any() else "directional",
            "directions": xyz(lights.directions), "positionsSphere": [],
            "positions3d": xyz(pos) if placed.any() else [], "ledAdjust": []}


PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


def photographs(items: Sequence[str | os.PathLike]) -> list[Path]:
    """The photographs named by ``items``: files as given, or one folder's images
    (:data:`PHOTO_SUFFIXES`, sorted by name)."""
    paths = [Path(p) for p in items]
    if len(paths) == 1 and paths[0].is_dir():
        found = sorted(p for p in paths[0].iterdir()
                       if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES)
        if not found:
            raise SphereError(f"folder {str(paths[0])!r} holds no photograph (expected "
                              f"{', '.join(PHOTO_SUFFIXES)} files)")
        return found
    for p in paths:
        if not p.is_file():
            raise SphereError(f"photo {str(p)!r} is not a file; expected photographs or one "
                              "folder of them")
    return paths


def relative_names(paths: Sequence[Path], lp: Path) -> list[str]:
    """The photographs' paths relative to the ``.lp`` file's folder, where :func:`read_lp`
    looks for them; refused when one lies outside that folder."""
    folder = Path(os.path.realpath(lp.parent))
    names = []
    for p in paths:
        real = Path(os.path.realpath(p))
        if not real.is_relative_to(folder):
            raise SphereError(f"photo {str(p)!r} lies outside the folder of {str(lp)!r}; "
                              "expected the .lp file in the photographs' folder or above it "
                              "(it names them relative to itself)")
        names.append(real.relative_to(folder).as_posix())
    return names


def write_lights(photos: Sequence[str | os.PathLike], output: str | os.PathLike, *,
                 spheres: Sequence[tuple[float, float, float]] | None = None,
                 count: int | None = None, dome: str | os.PathLike | None = None,
                 image_width_mm: float | None = None, overwrite: bool = False) -> dict:
    """``ltm lights``: the ``.lp`` file of ``photos`` from their spheres, and with ``dome``
    Relight's ``.dome`` file with the near lights' positions (two spheres or more).

    Returns
    -------
    dict
        ``path``, ``dome`` (or None), ``lights``, ``spheres`` (the refined outlines as
        ``(x, y, r)``), ``placed`` (lights with a position) and ``notes``.
    """
    import json

    from ltmstore.core.imagefile import write_bytes_atomic
    from ltmstore.core.paths import check_output

    paths = photographs(photos)
    if image_width_mm is not None and not (np.isfinite(image_width_mm) and image_width_mm > 0):
        raise SphereError(f"--image-width {image_width_mm!r} must be a width in mm > 0")
    if spheres is not None and count is not None and len(spheres) != count:
        raise SphereError(f"--spheres {count} but {len(spheres)} --sphere crop(s) given")
    outs = [Path(output)] + ([Path(dome)] if dome is not None else [])
    for out in outs:
        check_output(out, paths)
        if out.exists() and not overwrite:
            raise SphereError(f"output {str(out)!r} already exists; pass --overwrite to "
                              "replace it")
        if not out.parent.is_dir():
            raise SphereError(f"output folder {str(out.parent)!r} does not exist")
    names = relative_names(paths, outs[0])
    given = len(spheres) if spheres else count
    if dome is not None and given is not None and given < 2:
        raise SphereError(f"--dome needs two spheres or more (a near light's position is where "
                          f"their reflected rays meet); {given} given")
    lights = lights_from_spheres(paths, spheres=spheres, count=count)
    if dome is not None and len(lights.spheres) < 2:
        raise SphereError("--dome needs two spheres or more (a near light's position is where "
                          "their reflected rays meet); found one")
    write_bytes_atomic(outs[0], lp_text(names, lights.directions).encode(), what="light file")
    if dome is not None:
        text = json.dumps(dome_json(lights, image_width_mm=image_width_mm), indent=1)
        write_bytes_atomic(outs[1], text.encode(), what="dome file")
    return {"path": str(outs[0]), "dome": None if dome is None else str(outs[1]),
            "lights": len(names), "spheres": [(s.x, s.y, s.r) for s in lights.spheres],
            "placed": int(np.isfinite(lights.positions[:, 0]).sum()), "notes": lights.notes}
