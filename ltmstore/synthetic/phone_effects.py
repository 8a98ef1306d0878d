"""What real phones add to a simulated two-phone capture (``ltm simulate --raw --effects``).

Each effect is on by default at a typical strength and can be switched off alone
(:func:`parse_effects`); off means the ideal camera of the earlier simulation. The strengths and
where each number comes from:

``distortion``
    Radial lens distortion of both phones, OpenCV's ``k1, k2`` (``p1 = p2 = k3 = 0``, the model
    ``ltm calibrate`` fits). Phone A (a main camera, 65 degree field): ``k1 = -0.04``, barrel of
    about 2 % at the image corner (15 px at 1280 x 720), in the 0.5-3 % that lens reviews
    (DxOMark's distortion measurement) report for phone main cameras without the ISP's
    correction. Camera B (the painting fills the frame of a narrower, tele-like field from 45 cm):
    ``k1 = -0.15``, again 1.5 % barrel at the frame's corners.
``rolling-shutter``
    Phone A's rows are read one after another over :data:`READOUT_S` = 16 ms, top to bottom:
    rolling-shutter calibrations measured 30 ms on early smartphones (Forssen and Ringaby,
    CVPR 2010, iPhone 3GS; Oth et al., CVPR 2013: 20-30 ms); the stacked sensors of current
    phones read a 1080p frame in about 10-20 ms.
``motion-blur``
    Phone A's shutter is open :data:`SHUTTER_S` = 1/120 s, what a phone's auto exposure picks
    for 30 fps video at a few hundred lux (the torch at 30 cm); off: the earlier simulation's
    bright-light shutter, 1/250 s (:data:`SHUTTER_OFF_S`).
``auto-exposure``
    Camera B meters each frame (mean luminance) and moves its gain towards the target with a
    first-order lag of :data:`AE_TAU_S` = 0.4 s (phones converge in 0.3-1 s), compensating
    :data:`AE_STRENGTH` = 60 % of a brightness change (in log units); the gain is recorded per
    frame in ``truth/camera_b.csv``. Off: exposure locked (the gain stays 1).
``white-balance``
    Camera B's red and blue gains wander slowly (log-normal, :data:`WB_STD` = 3 %, correlated
    over :data:`WB_CORR_S` = 4 s): auto white balance hunting under mixed LED and room light.
    Off: white balance locked.
``ambient``
    The room light stays on: a uniform irradiance :data:`AMBIENT` = 0.2 of the LED's at 30 cm
    straight below (a phone torch of about 50 cd gives ~550 lux at 30 cm; a dimmed living room
    ~100 lux). Both recordings start with the LED off for :data:`LED_OFF_LEAD_S` = 1.0 s.
``led-falloff``
    The LED emits ``cos^m`` of the angle from phone A's optical axis, :data:`LED_EXPONENT` =
    2 (half intensity at 45 degrees; a flash LED behind its lens: half-intensity angles of
    45-60 degrees, m = 1-2.4). The truth is the LED held level (axis straight down).
``h264``
    Both phones' videos are H.264 (yuv420p, High profile, 1 s key-frame interval) at
    :data:`H264_BITS_PER_PIXEL` = 0.27 bits per pixel: a phone's 1080p30 H.264 default of about
    17 Mbit/s (17e6 / (1920 x 1080 x 30)), scaled to the simulated frame size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ltmstore.core.errors import LtmError

EFFECTS = ("distortion", "rolling-shutter", "motion-blur", "auto-exposure", "white-balance",
           "ambient", "led-falloff", "h264")
DISTORTION_A = (-0.04, 0.0)  # k1, k2 of phone A (see the module docstring)
DISTORTION_B = (-0.15, 0.0)  # k1, k2 of camera B
CAMERA_B_DISTANCE = 0.45  # m: camera B's focal length in frame pixels is size * 0.45 / 0.2
READOUT_S = 0.016
SHUTTER_S = 1 / 120
BLUR_SAMPLES = 5  # sub-instants averaged over the open shutter
SHUTTER_OFF_S = 1 / 250  # motion blur off: as the simulation before issue 29, 3 sub-instants
SHUTTER_OFF_SAMPLES = 3
AE_TAU_S = 0.4
AE_STRENGTH = 0.6
AE_MAX_GAIN = 4.0
WB_STD = 0.03
WB_CORR_S = 4.0
AMBIENT = 0.2
LED_OFF_LEAD_S = 1.0
LED_EXPONENT = 2.0
H264_BITS_PER_PIXEL = 0.27
H264_MIN_BITRATE = 64_000  # bit/s: the encoder's floor for tiny test frames


@dataclass(frozen=True)
class PhoneEffects:
    """Which phone effects a raw simulation applies (see the module docstring)."""

    on: frozenset = field(default_factory=lambda: frozenset(EFFECTS))

    def __contains__(self, name: str) -> bool:
        return name in self.on

    @property
    def lead_s(self) -> float:
        """Length of the LED-off lead at the start of both videos (ambient only)."""
        return LED_OFF_LEAD_S if "ambient" in self else 0.0

    def to_json(self) -> dict:
        """Every effect with its strength (``None`` when off), for ``truth/raw.json``."""
        strengths = {
            "distortion": {"phone_a_k1_k2": list(DISTORTION_A), "camera_b_k1_k2":
                           list(DISTORTION_B)},
            "rolling-shutter": {"readout_s": READOUT_S},
            "motion-blur": {"shutter_s": SHUTTER_S, "samples": BLUR_SAMPLES},
            "auto-exposure": {"tau_s": AE_TAU_S, "strength": AE_STRENGTH,
                              "max_gain": AE_MAX_GAIN},
            "white-balance": {"std": WB_STD, "correlation_s": WB_CORR_S},
            "ambient": {"relative_irradiance": AMBIENT, "led_off_lead_s": LED_OFF_LEAD_S},
            "led-falloff": {"cos_exponent": LED_EXPONENT},
            "h264": {"bits_per_pixel": H264_BITS_PER_PIXEL},
        }
        return {name: strengths[name] if name in self else None for name in EFFECTS}


def parse_effects(text: str | PhoneEffects | None) -> PhoneEffects:
    """``all``, ``none`` or a comma list of :data:`EFFECTS`; one-line :class:`LtmError`
    otherwise."""
    if isinstance(text, PhoneEffects):
        return text
    if text is None or str(text).strip() == "all":
        return PhoneEffects()
    if str(text).strip() == "none":
        return PhoneEffects(frozenset())
    names = [n.strip() for n in str(text).split(",") if n.strip()]
    bad = [n for n in names if n not in EFFECTS]
    if bad or not names:
        raise LtmError(f"--effects {text!r}: expected all, none or a comma list of "
                       f"{', '.join(EFFECTS)}")
    return PhoneEffects(frozenset(names))


def camera_b_matrix(size: tuple[int, int]) -> np.ndarray:
    """Camera B's camera matrix for a frame of ``size = (w, h)`` showing the 20 cm object."""
    w, h = size
    f = w * CAMERA_B_DISTANCE / 0.2
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])


def undistort_normalised(xd: np.ndarray, yd: np.ndarray,
                         dist: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Invert OpenCV's radial model ``x_d = x (1 + k1 r^2 + k2 r^4)`` by fixed-point steps
    (exact to 1e-12 for the strengths used here)."""
    k1, k2 = dist
    x, y = xd.copy(), yd.copy()
    for _ in range(30):
        r2 = x * x + y * y
        scale = 1 + k1 * r2 + k2 * r2 * r2
        x, y = xd / scale, yd / scale
    return x, y


def _pixel_grid(matrix: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return (u - matrix[0, 2]) / matrix[0, 0], (v - matrix[1, 2]) / matrix[1, 1]


def distortion_maps(matrix: np.ndarray, dist: tuple[float, float],
                    size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of the distorted image, where it looks in the ideal (undistorted) one:
    ``map_x, map_y`` (float32, ``(h, w)``) for :func:`cv2.remap`."""
    x, y = undistort_normalised(*_pixel_grid(matrix, size), dist)
    return ((x * matrix[0, 0] + matrix[0, 2]).astype(np.float32),
            (y * matrix[1, 1] + matrix[1, 2]).astype(np.float32))


def normalised_rays(matrix: np.ndarray, dist: tuple[float, float],
                    size: tuple[int, int]) -> np.ndarray:
    """Ray directions ``(h, w, 3)`` (camera axes, ``z = 1``) of every pixel of a camera with
    radial distortion ``dist``."""
    x, y = undistort_normalised(*_pixel_grid(matrix, size), dist)
    return np.stack([x, y, np.ones_like(x)], -1)


def led_profile(axis: np.ndarray, light: np.ndarray, points: np.ndarray,
                exponent: float = LED_EXPONENT) -> np.ndarray:
    """``cos^m`` of the angle between the LED's ``axis`` (unit, plane coordinates) and the
    direction from the LED at ``light`` to each of ``points (3, ...)``."""
    d = points - np.reshape(light, (3,) + (1,) * (points.ndim - 1))
    cos = np.tensordot(np.asarray(axis, np.float64), d, axes=(0, 0)) / np.linalg.norm(d, axis=0)
    return np.clip(cos, 0.0, None) ** exponent


class AutoExposure:
    """Camera B's auto exposure: meter each frame, move the gain towards the target with a lag.

    ``step(mean)`` takes the frame's mean linear luminance before the gain and returns the gain
    the frame was taken with (the gain set from the frames before it).
    """

    def __init__(self, fps: float, *, tau_s: float = AE_TAU_S,
                 strength: float = AE_STRENGTH) -> None:
        self.k = 1 - np.exp(-1 / (fps * tau_s))
        self.strength = strength
        self.reference: float | None = None
        self.log_gain = 0.0

    def step(self, mean: float) -> float:
        gain = float(np.exp(self.log_gain))
        mean = max(float(mean), 1e-6)
        if self.reference is None:
            self.reference = mean
        target = np.clip(-self.strength * np.log(mean / self.reference), -np.log(AE_MAX_GAIN),
                         np.log(AE_MAX_GAIN))
        self.log_gain += self.k * (target - self.log_gain)
        return gain


def white_balance(n: int, fps: float, seed: int, *, std: float = WB_STD,
                  corr_s: float = WB_CORR_S) -> np.ndarray:
    """Per-frame white-balance gains ``(n, 3)`` (green fixed at 1): slow log-normal wander of
    red and blue."""
    rng = np.random.default_rng([seed, 909])
    pad = int(3 * corr_s * fps)
    noise = ndimage.gaussian_filter1d(rng.standard_normal((n + 2 * pad, 2)), corr_s * fps / 2,
                                      axis=0)[pad:pad + n]
    noise *= std / max(float(noise.std()), 1e-12)
    out = np.ones((n, 3))
    out[:, 0], out[:, 2] = np.exp(noise[:, 0]), np.exp(noise[:, 1])
    return out


def h264_bitrate(size: tuple[int, int], fps: float) -> int:
    """A phone's H.264 bitrate scaled to a frame of ``size = (w, h)``, bit/s."""
    return max(H264_MIN_BITRATE, int(H264_BITS_PER_PIXEL * size[0] * size[1] * fps))
