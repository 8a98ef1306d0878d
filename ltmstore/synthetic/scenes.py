"""Ground-truth painting scenes: a height field plus a diffuse + GGX microfacet material.

A :class:`Scene` is a square almost-planar object seen from above on the pixel grid of
:mod:`ltmstore.core.dims` (row ``y`` down, column ``x`` right, object plane ``z = 0``). Three
scenes are built in, each seeded and resolution independent (features are placed in object units):

* ``canvas``: an oil painting, impasto brush strokes (0.2-1 mm), mild varnish gloss;
* ``icon``: a tempera icon with a gilded border and halo (metallic gold, sharp coloured highlight);
* ``relief``: a painting in a raised frame (8 mm) with a raised relief block (6 mm) and a boss,
  which cast hard shadows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ltmstore.core.errors import LtmError
from ltmstore.core.transfer import srgb_to_linear

SCENES = ("canvas", "icon", "relief")
OBJECT_WIDTH = 0.2  # metres: the default object is 20 cm wide
GOLD = np.array([1.0, 0.766, 0.336])  # linear F0 of gold
DIELECTRIC_F0 = 0.04  # varnish, oil, tempera


@dataclass(frozen=True, eq=False)
class Scene:
    """An almost-planar object: height field and spatially varying reflectance.

    Parameters
    ----------
    height : ndarray, shape (H, W)
        Surface height above the object plane ``z = 0``, metres.
    albedo : ndarray, shape (H, W, 3)
        Diffuse albedo, linear RGB in ``[0, 1]`` (ignored where ``metallic``).
    spec_color : ndarray, shape (H, W, 3)
        Specular reflectance at normal incidence (Schlick ``F0``), linear RGB.
    roughness : ndarray, shape (H, W)
        GGX ``alpha`` (0 = mirror, 1 = very rough).
    metallic : ndarray, shape (H, W)
        Metalness in ``[0, 1]``: scales the diffuse term by ``1 - metallic``.
    pixel_size : float
        Pixel pitch on the object plane, metres.
    name : str
        A label, e.g. the built-in scene name.
    """

    height: np.ndarray
    albedo: np.ndarray
    spec_color: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    pixel_size: float
    name: str = "custom"

    def __post_init__(self) -> None:
        shape = np.shape(self.height)
        if len(shape) != 2:
            raise LtmError(f"scene height must be (H, W), got shape {shape}")
        for field, want in (("albedo", (*shape, 3)), ("spec_color", (*shape, 3)),
                            ("roughness", shape), ("metallic", shape)):
            got = np.shape(getattr(self, field))
            if got != want:
                raise LtmError(f"scene {field} shape {got} must be {want}")
        if not np.all(np.asarray(self.roughness) > 0):
            raise LtmError("scene roughness must be positive everywhere (GGX alpha > 0)")
        if not (np.isfinite(self.pixel_size) and self.pixel_size > 0):
            raise LtmError(f"scene pixel_size {self.pixel_size!r} must be a positive number")

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` in pixels."""
        return tuple(np.shape(self.height))  # type: ignore[return-value]

    def pixel_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Object-plane coordinates ``(X, Y)`` of the pixel centres, each ``(H, W)``, metres."""
        h, w = self.shape
        xs = (np.arange(w) + 0.5 - w / 2) * self.pixel_size
        ys = (h / 2 - np.arange(h) - 0.5) * self.pixel_size
        return np.meshgrid(xs, ys)

    def normals(self) -> np.ndarray:
        """Unit surface normals ``(3, H, W)`` from central differences of the height field."""
        dh_dy, dh_dx = np.gradient(np.asarray(self.height, dtype=np.float64), self.pixel_size)
        # Y grows upwards while rows grow downwards: dh/dY = -dh/drow.
        n = np.stack([-dh_dx, dh_dy, np.ones_like(dh_dx)])
        return n / np.linalg.norm(n, axis=0)


def make_scene(name: str, *, size: int = 128, seed: int = 0,
               pixel_size: float | None = None) -> Scene:
    """Build one of the :data:`SCENES` at ``size x size`` pixels.

    Parameters
    ----------
    name : {"canvas", "icon", "relief"}
        Which scene.
    size : int
        Pixels per side.
    seed : int
        Seed of the brush strokes (the picture itself is fixed).
    pixel_size : float, optional
        Pixel pitch in metres; default ``0.2 / size`` (a 20 cm wide object).

    Returns
    -------
    Scene

    Raises
    ------
    LtmError
        Unknown ``name`` or a bad ``size``.
    """
    if name not in SCENES:
        raise LtmError(f"unknown scene {name!r}; expected one of {', '.join(SCENES)}")
    if int(size) != size or size < 8:
        raise LtmError(f"scene size {size!r} must be an integer of at least 8 pixels")
    size = int(size)
    pitch = OBJECT_WIDTH / size if pixel_size is None else float(pixel_size)
    rng = np.random.default_rng([seed, SCENES.index(name)])
    return _BUILDERS[name](size, pitch, rng)


def _picture(name: str, size: int) -> np.ndarray:
    """scikit-image's sample picture ``name``, centre-cropped to a square, resized, linearised
    and mapped into [0.03, 0.8]."""
    from skimage import data  # here: listing the scenes (the CLI's choices) needs no skimage
    from skimage.transform import resize

    image = getattr(data, name)()
    h, w = image.shape[:2]
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    square = image[top:top + side, left:left + side, :3] / 255.0
    small = resize(square, (size, size), anti_aliasing=True)
    return 0.03 + 0.77 * srgb_to_linear(np.clip(small, 0.0, 1.0)).astype(np.float64)


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised coordinates ``(u, v)`` in ``[0, 1)`` of the pixel centres (u right, v down)."""
    c = (np.arange(size) + 0.5) / size
    return np.meshgrid(c, c)


def _strokes(size: int, rng: np.random.Generator, *, count: int, height: tuple[float, float],
             width: tuple[float, float] = (0.025, 0.06),
             length: tuple[float, float] = (0.05, 0.2)) -> tuple[np.ndarray, np.ndarray]:
    """Impasto: ``count`` brush strokes piled up; returns (height in metres, stroke id map).

    Each stroke is a ridge with an elliptical cross-section, tapered ends and bristle grooves;
    sizes are fractions of the object width, ``height`` the peak range in metres.
    """
    u, v = _grid(size)
    total = np.zeros((size, size))
    ids = np.full((size, size), -1)
    for k in range(count):
        cu, cv = rng.uniform(0, 1, 2)
        angle = rng.uniform(0, np.pi)
        half_l, half_w = rng.uniform(*length) / 2, rng.uniform(*width) / 2
        along = (u - cu) * np.cos(angle) + (v - cv) * np.sin(angle)
        across = -(u - cu) * np.sin(angle) + (v - cv) * np.cos(angle)
        inside = np.clip(1 - (across / half_w) ** 2, 0, None)
        taper = np.clip(1 - (along / half_l) ** 4, 0, None)
        grooves = 1 + 0.25 * np.cos(2 * np.pi * across / (half_w / 2.5) + rng.uniform(0, 6.3))
        ridge = np.sqrt(inside) * taper * grooves * rng.uniform(*height)
        total += ridge
        ids[ridge > 0] = k
    return total, ids


def _smooth(height: np.ndarray, sigma_px: float) -> np.ndarray:
    from scipy import ndimage

    return ndimage.gaussian_filter(height, sigma_px, mode="nearest")


def _dielectric(albedo: np.ndarray, height: np.ndarray, roughness: np.ndarray, pitch: float,
                name: str, *, metallic: np.ndarray | None = None,
                spec_color: np.ndarray | None = None) -> Scene:
    shape = height.shape
    f0 = np.full((*shape, 3), DIELECTRIC_F0) if spec_color is None else spec_color
    metal = np.zeros(shape) if metallic is None else metallic
    return Scene(height=height, albedo=albedo, spec_color=f0, roughness=roughness,
                 metallic=metal, pixel_size=pitch, name=name)


def _canvas(size: int, pitch: float, rng: np.random.Generator) -> Scene:
    """Oil on canvas: dense impasto, varnish with per-stroke roughness 0.12-0.4."""
    height, ids = _strokes(size, rng, count=260, height=(0.2e-3, 0.6e-3))
    height = _smooth(np.minimum(height, 1.0e-3), 0.6)
    per_stroke = rng.uniform(0.12, 0.4, 260)
    roughness = np.where(ids >= 0, per_stroke[ids], 0.5)
    return _dielectric(_canvas_albedo(size), height, roughness, pitch, "canvas")


def _canvas_albedo(size: int) -> np.ndarray:
    return _picture("coffee", size)


def _icon(size: int, pitch: float, rng: np.random.Generator) -> Scene:
    """Tempera icon: gilded border and halo (gold, alpha 0.1) on a raised gesso layer."""
    gold = _icon_gold(size)
    paint, _ = _strokes(size, rng, count=120, height=(0.1e-3, 0.35e-3))
    height = _smooth(np.where(gold, 0.3e-3, np.minimum(paint, 0.6e-3)), 0.7)
    spec = np.where(gold[..., None], GOLD, DIELECTRIC_F0)
    roughness = np.where(gold, 0.1, 0.25)
    return _dielectric(_icon_albedo(size), height, roughness, pitch, "icon",
                       metallic=gold.astype(np.float64), spec_color=spec)


def _icon_gold(size: int) -> np.ndarray:
    u, v = _grid(size)
    ring = np.hypot(u - 0.47, v - 0.33)
    return (np.minimum.reduce([u, v, 1 - u, 1 - v]) < 0.08) | ((ring > 0.17) & (ring < 0.26))


def _icon_albedo(size: int) -> np.ndarray:
    return np.where(_icon_gold(size)[..., None], 0.0, _picture("astronaut", size))


def _relief(size: int, pitch: float, rng: np.random.Generator) -> Scene:
    """A painting in an 8 mm frame with a 6 mm relief block and a 4 mm boss: hard cast shadows."""
    frame, block, boss = _relief_parts(size)
    paint, _ = _strokes(size, rng, count=160, height=(0.2e-3, 0.5e-3))
    relief = np.select([frame, block, boss], [8e-3, 6e-3, 4e-3], 0.0)
    height = _smooth(np.where(relief > 0, relief, np.minimum(paint, 0.8e-3)), 0.5)
    roughness = np.select([frame, block | boss], [0.35, 0.6], 0.2)
    return _dielectric(_relief_albedo(size), height, roughness, pitch, "relief")


def _relief_parts(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of the frame, the relief block and the boss."""
    u, v = _grid(size)
    frame = np.minimum.reduce([u, v, 1 - u, 1 - v]) < 0.07
    block = (u > 0.18) & (u < 0.45) & (v > 0.55) & (v < 0.8)
    boss = np.hypot(u - 0.68, v - 0.35) < 0.1
    return frame, block, boss


def _relief_albedo(size: int) -> np.ndarray:
    frame, block, boss = _relief_parts(size)
    albedo = np.where(frame[..., None], [0.30, 0.17, 0.08], _picture("chelsea", size))
    return np.where((block | boss)[..., None], [0.75, 0.72, 0.66], albedo)


_BUILDERS = {"canvas": _canvas, "icon": _icon, "relief": _relief}
_ALBEDOS = {"canvas": _canvas_albedo, "icon": _icon_albedo, "relief": _relief_albedo}


def scene_albedo(name: str, size: int) -> np.ndarray:
    """The albedo ``(size, size, 3)`` of ``make_scene(name, size=size)`` alone: cheap at any
    size (no relief is built), e.g. the painting as a close-up camera resolves it."""
    if name not in SCENES:
        raise LtmError(f"unknown scene {name!r}; expected one of {', '.join(SCENES)}")
    return _ALBEDOS[name](int(size))
