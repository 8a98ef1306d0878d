"""Camera B's frames of a raw two-phone capture, with the phone effects of
:mod:`ltmstore.synthetic.phone_effects`.

Per frame, in the order light takes: the painting lit by phone A's LED (its emission profile
about the phone's *actual* optical axis when ``led-falloff`` is on), plus the room's ambient
light; the lens's distortion; the camera's auto-exposure gain and white-balance gains; sensor
noise; sRGB. During the LED-off lead only the ambient term is there. With every effect off the
frames are exactly :func:`ltmstore.synthetic.simulate.video_frames`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ltmstore.core.dims import LUMA
from ltmstore.synthetic.phone_effects import (
    AMBIENT,
    DISTORTION_B,
    LED_EXPONENT,
    AutoExposure,
    PhoneEffects,
    camera_b_matrix,
    distortion_maps,
    led_profile,
    white_balance,
)
from ltmstore.synthetic.render import GGX, Shading, _Renderer
from ltmstore.synthetic.simulate import SimulationPlan, _sensor
from ltmstore.synthetic.writer import FPS


@dataclass(frozen=True, eq=False)
class CameraBTimeline:
    """Camera B's frames on the hand's clock: ``times``, the LED positions ``lights (n, 3)``,
    whether the LED is on, and phone A's optical axis ``axes (n, 3)`` at each frame."""

    times: np.ndarray
    lights: np.ndarray
    led_on: np.ndarray
    axes: np.ndarray


def ambient_term(plan: SimulationPlan, exposure: float) -> np.ndarray:
    """The room light's image ``(h, w, 3)``: uniform irradiance :data:`AMBIENT` times the LED's
    at the plane height straight below, reflected diffusely (and by the specular ``F0``)."""
    scene = plan.scene
    kd = np.asarray(scene.albedo) / np.pi * (1 - np.asarray(scene.metallic))[..., None]
    reflect = kd + np.asarray(scene.spec_color) / np.pi
    return reflect * (AMBIENT / plan.plane.height**2) * exposure


def camera_b_frames(plan: SimulationPlan, timeline: CameraBTimeline, *, exposure: float,
                    effects: PhoneEffects, records: list,
                    shading: Shading = GGX) -> Iterator[np.ndarray]:
    """Yield camera B's frames ``(h, w, 3)`` sRGB uint8 of the painting shaded by ``shading``
    (its LED exponent ignored: the beam is the ``led-falloff`` effect); append ``(gain, wb_r,
    wb_g, wb_b)`` per frame to ``records``."""
    rng = np.random.default_rng([plan.seed, 303])
    renderer = _Renderer(plan.scene, shading=replace(shading, led_exponent=0.0))
    h, w = plan.scene.shape
    ambient = ambient_term(plan, exposure) if "ambient" in effects else None
    maps = distortion_maps(camera_b_matrix((w, h)), DISTORTION_B, (w, h)) \
        if "distortion" in effects else None
    ae = AutoExposure(FPS) if "auto-exposure" in effects else None
    wb = white_balance(len(timeline.times), FPS, plan.seed) if "white-balance" in effects \
        else np.ones((len(timeline.times), 3))
    points = np.asarray(renderer.pos)
    for k, light in enumerate(timeline.lights):
        if timeline.led_on[k]:
            lin = renderer(light).astype(np.float64) * exposure
            if "led-falloff" in effects:
                lin *= led_profile(timeline.axes[k], light, points, LED_EXPONENT)[..., None]
        else:
            lin = np.zeros((h, w, 3))
        if ambient is not None:
            lin += ambient
        if maps is not None:
            lin = cv2.remap(lin, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        gain = ae.step(float(np.mean(lin @ LUMA))) if ae is not None else 1.0
        if gain != 1.0 or "white-balance" in effects:
            lin = lin * (gain * wb[k])
        records.append((gain, *wb[k]))
        yield _sensor(lin, rng)
