"""Dimension names, lattice geometry and the store schema, defined once.

Conventions
-----------
* Pixels: ``y`` is the row (grows downwards), ``x`` the column.
* Object plane: ``z = 0``; a pixel centre sits at ``X = (x + 0.5 - W/2) * pitch`` (right) and
  ``Y = (H/2 - y - 0.5) * pitch`` (up), in plane units (metres).
* Illumination plane: parallel to the object at height ``h``; a light at ``(r, s)`` sits at
  ``(X, Y, Z) = (r, s, h)``: ``r`` along image right, ``s`` along image up (the RTI convention:
  ``r = h lx / lz``, ``s = h ly / lz``).
* View plane (6D): camera centre at ``(p, q)`` on a plane parallel to the object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ltmstore.core.errors import LtmError

T, Y, X = "t", "y", "x"
R, S, P, Q = "r", "s", "p", "q"
CHANNEL, COLOR = "channel", "color"
LIGHT_DIMS = (R, S)
VIEW_DIMS = (P, Q)
PIXEL_DIMS = (Y, X)
CHROMA_CHANNELS = ("cb", "cr")
COLOR_CHANNELS = ("R", "G", "B")

# Store variables (ARCHITECTURE.md section 3.2).
FRAMES = "frames"  # (t, y, x) linear luminance
FRAME_CHROMA = "frame_chroma"  # (channel, t, y, x) linear Cb, Cr (for a colour LTM)
POSES = ("pose_r", "pose_s", "pose_z", "pose_valid")  # (t,) light per frame; + pose_p, pose_q in 6D
# (t,) phone A's LED axis per frame (unit vector, plane coordinates), where poses.csv gives it
POSE_AXIS = ("pose_axis_r", "pose_axis_s", "pose_axis_z")
SAMPLES = "samples"  # (y, x, r, s[, p, q]) binned means, NaN where unobserved
# The measurements (frames, frame_chroma, samples and the chroma samples) are stored in float16:
# its rounding (at most 2^-11 of a value, -71 dB RMS) lies below one step of an 8-bit video and
# far below a camera's noise, and it takes about half the disk of float32 (the Toys-size frames
# 272 against 532 MB). Readers compute in float32; open_store serves them as float32. Stores
# written before hold float32 frames and samples, read the same way.
OBSERVATION_DTYPE = np.float16
COUNT = "count"  # (r, s[, p, q]) number of frames per cell
LTM = "ltm"  # (y, x, r, s[, p, q]) float32 linear luminance
# A colour LTM, when the chroma varies with the light: the Cb and Cr LTMs beside ``ltm``.
CHROMA_LTM = {"cb": "ltm_cb", "cr": "ltm_cr"}
CHROMA_SAMPLES = {"cb": "samples_cb", "cr": "samples_cr"}
EXPECTED_ERROR = "expected_error"  # (y, x) held-out RMS error / observed range, per pixel
UNSUPPORTED = "unsupported"  # (y, x) True where the data cannot support a model
CHROMA = "chroma"  # (y, x, channel) chroma as a ratio to luminance (illumination invariant)
CHROMA_SPREAD = "chroma_spread"  # (y, x, channel) how much that ratio varies with the light
LTM_RGB = "ltm_rgb"  # (y, x, r, s, color) ground truth colour LTM (simulations only)

# Plane ranges (plane units, metres by default): beyond these magnitudes the lattice's float
# arithmetic (cell sides, centres, light distances) overflows or loses every digit of the cells.
MAX_COORD = 1e6
MIN_WIDTH = 1e-6
# The most cells of a lattice: a flat cell index must fit an int64.
MAX_CELLS = 2**62

# BT.601 luma weights; chroma scales so that R = Y + 1.402 Cr, B = Y + 1.772 Cb.
LUMA = np.array([0.299, 0.587, 0.114])
_YCBCR = np.array([LUMA, (np.array([0, 0, 1]) - LUMA) / 1.772,  # Cb = (B - Y) / 1.772
                   (np.array([1, 0, 0]) - LUMA) / 1.402], dtype=np.float32)  # Cr = (R - Y) / 1.402


def rgb_to_ycbcr(rgb: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Linear RGB (..., 3) to Y, Cb, Cr (..., 3) float32, BT.601 weights, no offsets (into
    ``out`` where given: C-contiguous float32 of ``rgb``'s shape).

    One 3 x 3 transform per pixel (OpenCV's, vectorised: about 4x NumPy's channel by channel
    on a 4K frame)."""
    import cv2

    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if rgb.size == 0:
        return rgb.copy()
    dst = None if out is None else out.reshape(-1, 1, 3)
    return cv2.transform(rgb.reshape(-1, 1, 3), _YCBCR, dst=dst).reshape(rgb.shape)


def rgb_from_ycbcr(y, cb, cr):
    """``(R, G, B)`` from ``Y, Cb, Cr`` given separately (NumPy or xarray operands), in their
    precision: the weights are Python floats, so float32 operands stay float32 (NumPy's float64
    weights made green float64: 3x the time on a capture's frames)."""
    red, green, blue = (float(w) for w in LUMA)
    r = y + 1.402 * cr
    b = y + 1.772 * cb
    g = (y - red * r - blue * b) / green
    return r, g, b


def ycbcr_to_rgb(ycc: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rgb_to_ycbcr`."""
    ycc = np.asarray(ycc)
    return np.stack(rgb_from_ycbcr(ycc[..., 0], ycc[..., 1], ycc[..., 2]), axis=-1)


def check_range(what: str, lo: float, hi: float) -> None:
    """Refuse a plane range ``[lo, hi]`` that a lattice cannot divide.

    Parameters
    ----------
    what : str
        The range's name for the message (e.g. ``"plane r"``).
    lo, hi : float
        The range's ends, plane units.

    Raises
    ------
    LtmError
        Unless both ends are finite, within :data:`MAX_COORD` of 0, and ``hi - lo`` is at least
        :data:`MIN_WIDTH`.
    """
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise LtmError(f"{what} range {[lo, hi]} must be two finite numbers, min < max")
    if max(abs(lo), abs(hi)) > MAX_COORD or hi - lo < MIN_WIDTH:
        raise LtmError(f"{what} range {[lo, hi]} must lie within [-{MAX_COORD:g}, "
                       f"{MAX_COORD:g}] plane units and be at least {MIN_WIDTH:g} wide")


@dataclass(frozen=True)
class Plane:
    """A rectangle ``[r0, r1] x [s0, s1]`` at height ``height`` above the object (plane units)."""

    r: tuple[float, float]
    s: tuple[float, float]
    height: float
    unit: str = "m"

    def __post_init__(self) -> None:
        for name, (lo, hi) in (("r", self.r), ("s", self.s)):
            check_range(f"plane {name}", lo, hi)
        if not (np.isfinite(self.height) and 0 < self.height <= MAX_COORD):
            raise LtmError(f"plane height {self.height!r} must be a positive number of at most "
                           f"{MAX_COORD:g} plane units")

    @property
    def area(self) -> float:
        return (self.r[1] - self.r[0]) * (self.s[1] - self.s[0])

    def contains(self, r: np.ndarray, s: np.ndarray) -> np.ndarray:
        """True where ``(r, s)`` lies inside the closed rectangle."""
        return (r >= self.r[0]) & (r <= self.r[1]) & (s >= self.s[0]) & (s <= self.s[1])

    def to_json(self) -> dict:
        return {"r": list(self.r), "s": list(self.s), "height": self.height, "unit": self.unit}

    @classmethod
    def from_json(cls, d: dict) -> Plane:
        try:
            return cls(
                r=(float(d["r"][0]), float(d["r"][1])),
                s=(float(d["s"][0]), float(d["s"][1])),
                height=float(d["height"]),
                unit=str(d.get("unit", "m")),
            )
        except (KeyError, TypeError, IndexError, ValueError) as exc:
            raise LtmError(
                f"plane {d!r} must look like {{'r': [min, max], 's': [min, max], 'height': h}}"
            ) from exc


def object_extent(attrs: dict) -> dict | None:
    """The object extent (``{"x": [left, right], "y": [bottom, top]}``) that places a store's
    pixels on the object plane: the one its reconstruct stage used (``placement.extent``:
    declared or estimated from the capture), else the acquisition's declared ``object``, else
    None. ``attrs`` are the store's group attributes."""
    record = ((attrs.get("stages") or {}).get("reconstruct") or {}).get("placement") or {}
    if "extent" in record:
        return record["extent"]
    return (attrs.get("acquisition") or {}).get("object")


def object_pixels(extent: dict, image: tuple[int, int], rows: slice, cols: slice) -> np.ndarray:
    """Object-plane ``(X, Y)`` of the pixel centres ``rows x cols`` of an ``image (H, W)`` that
    shows ``extent = {"x": [left, right], "y": [bottom, top]}`` (``acquisition.json``'s
    ``object``, plane units), or in any orientation ``{"top_left": [X, Y], "top_right": [X, Y],
    "bottom_left": [X, Y]}`` (the plane positions of the frame's corners): ``(n, 2)`` in C order
    of ``(y, x)``. Pixel ``(0, 0)`` is the top left corner; ``Y`` grows upwards as ``s`` does."""
    h, w = image
    if "x" not in extent:  # any orientation: the corners span the frame
        tl, tr, bl = (np.asarray(extent[k], float) for k in ("top_left", "top_right",
                                                             "bottom_left"))
        vv, uu = np.meshgrid((np.arange(h)[rows] + 0.5) / h, (np.arange(w)[cols] + 0.5) / w,
                             indexing="ij")
        return tl + uu.reshape(-1, 1) * (tr - tl) + vv.reshape(-1, 1) * (bl - tl)
    (left, right), (bottom, top) = extent["x"], extent["y"]
    x = left + (np.arange(w)[cols] + 0.5) * (right - left) / w
    y = top - (np.arange(h)[rows] + 0.5) * (top - bottom) / h
    xx, yy = np.meshgrid(x, y)
    return np.column_stack([xx.ravel(), yy.ravel()])


@dataclass(frozen=True)
class Lattice:
    """A regular lattice of ``shape`` equal cells over a plane rectangle.

    ``shape`` has one entry per lattice dimension (``(R, S)`` for 4D, ``(R, S, P, Q)`` for 6D);
    ``bounds`` holds ``(lo, hi)`` for each of them.
    """

    bounds: tuple[tuple[float, float], ...]
    shape: tuple[int, ...]
    dims: tuple[str, ...] = LIGHT_DIMS

    def __post_init__(self) -> None:
        if len(self.bounds) != len(self.shape) or len(self.dims) != len(self.shape):
            raise LtmError(f"lattice dims {self.dims}, bounds and shape {self.shape} must agree")
        if any(int(n) < 1 for n in self.shape):
            raise LtmError(f"lattice shape {self.shape} must have at least one cell per axis")
        cells = math.prod(int(n) for n in self.shape)
        if cells > MAX_CELLS:
            shape = "x".join(str(n) if n < 10**12 else approx(n) for n in map(int, self.shape))
            raise LtmError(f"lattice {shape} has {approx(cells)} cells; "
                           "expected at most 2**62 (a cell index must fit 64 bits)")

    @classmethod
    def from_plane(cls, plane: Plane, shape: tuple[int, int]) -> Lattice:
        """``shape = (R, S)`` equal cells over the plane rectangle."""
        return cls(bounds=(plane.r, plane.s), shape=tuple(int(n) for n in shape))

    @classmethod
    def from_delta(cls, plane: Plane, delta: float) -> Lattice:
        """Cells of side about ``delta`` (rounded so that a whole number fits each axis)."""
        return cls.from_plane(plane, cells_of_delta((plane.r, plane.s), delta))

    @property
    def size(self) -> int:
        """``M``: the number of cells."""
        return math.prod(int(n) for n in self.shape)

    @property
    def deltas(self) -> tuple[float, ...]:
        return tuple((hi - lo) / n for (lo, hi), n in zip(self.bounds, self.shape, strict=True))

    def centres(self, axis: int) -> np.ndarray:
        lo, _ = self.bounds[axis]
        d = self.deltas[axis]
        return lo + (np.arange(self.shape[axis]) + 0.5) * d

    def coords(self) -> dict[str, np.ndarray]:
        return {name: self.centres(i) for i, name in enumerate(self.dims)}

    def cell_index(self, *positions: np.ndarray) -> np.ndarray:
        """Flat (C-order) cell index of each position; -1 outside the lattice.

        Cells are half-open ``[lo, lo + delta)``, except that the upper plane edge belongs to the
        last cell.
        """
        flat = np.zeros(np.shape(positions[0]), dtype=np.int64)
        inside = np.ones(np.shape(positions[0]), dtype=bool)
        for axis, pos in enumerate(positions):
            lo, hi = self.bounds[axis]
            pos = np.asarray(pos, dtype=np.float64)
            finite = np.isfinite(pos)
            idx = np.floor((np.where(finite, pos, lo - hi) - lo) / self.deltas[axis])
            idx = idx.astype(np.int64)
            idx = np.where(pos == hi, self.shape[axis] - 1, idx)
            inside &= (idx >= 0) & (idx < self.shape[axis]) & finite
            flat = flat * self.shape[axis] + np.clip(idx, 0, self.shape[axis] - 1)
        return np.where(inside, flat, -1)

    def to_json(self) -> dict:
        return {"dims": list(self.dims), "bounds": [list(b) for b in self.bounds],
                "shape": list(self.shape), "deltas": list(self.deltas)}


def approx(n: int) -> str:
    """A count of any size in three digits (``1e+10``, or ``10**600`` beyond floats)."""
    return f"{n:.3g}" if n < 1e300 else f"10**{int(math.log10(n))}"


def cells_of_delta(bounds: tuple[tuple[float, float], ...], delta: float) -> tuple[int, ...]:
    """Cells per axis of side about ``delta`` over ``bounds`` (``--delta-rs``).

    Raises
    ------
    LtmError
        If ``delta`` is not a positive number, or the cells would be more than
        :data:`MAX_CELLS` (``--delta-rs 1e-300``), naming the count.
    """
    if not (np.isfinite(delta) and delta > 0):
        raise LtmError(f"--delta-rs {delta!r} must be a positive number (plane units)")
    counts = [(hi - lo) / delta for lo, hi in bounds]
    if not all(math.isfinite(n) and n <= MAX_CELLS for n in counts) \
            or math.prod(max(1.0, n) for n in counts) > MAX_CELLS:
        cells = " x ".join(f"{n:.3g}" for n in counts)
        raise LtmError(f"--delta-rs {delta!r} cuts the plane into {cells} cells; expected at "
                       "most 2**62 in all (a larger cell size)")
    return tuple(max(1, int(round(n))) for n in counts)


def parse_lattice(text: str) -> tuple[int, ...]:
    """Parse ``--lattice RxS`` (e.g. ``32x32``), or ``RxSxPxQ`` for a 6D store."""
    parts = text.lower().split("x")
    try:
        shape = tuple(int(p) for p in parts)
    except ValueError:
        shape = ()
    if len(shape) not in (2, 4) or min(shape) < 1:
        raise LtmError(f"--lattice {text!r} must look like RxS with positive integers, e.g. 32x32"
                       " (RxSxPxQ for 6D, e.g. 25x25x16x16)")
    return shape
