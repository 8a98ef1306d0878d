"""Simulated raw two-phone capture: ``ltm simulate --raw``.

Phone A is waved over the painting; its LED is the light and its camera films a ChArUco board
laid in the object plane around the painting. Phone B films the painting from a fixed position.
Nothing but the two videos is written for the pipeline (no poses file, no clock offset):
``ltm track``, ``ltm sync`` and ``ltm ingest`` have to recover them. Layout::

    OUT/acquisition.json   video B, plane, transfer; poses "poses.csv" (written by `ltm track`)
    OUT/video.mkv          phone B: the painting lit by the LED (as `ltm simulate`)
    OUT/phone_a.mkv        phone A: the board seen from the phone's pose, blur and noise
    OUT/calibration.mkv    phone A: still views of the board from varied angles
    OUT/board.json/.png    the board spec and image
    OUT/truth/             intrinsics.json, poses_true.csv (true LED on video B's clock),
                           raw.json (true clock offset, LED offset); and OUT/truth.zarr

Geometry: plane coordinates ``(r, s, z)`` centred on the board (:meth:`BoardSpec.to_plane`);
phone A's camera looks down, its image ``x`` axis along ``r`` turned by a slowly wandering yaw,
with small smooth tilts; the LED sits at ``led_offset`` (camera axes: x right, y down, z along
the optical axis) from the camera centre. Phone A's clock starts ``time_offset`` seconds after
phone B's (``t_B = t_A + time_offset``, the ``acquisition.json`` convention).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage
from tqdm.auto import tqdm

from ltmstore.capture.board import BoardSpec, board_image, board_spec, page_image
from ltmstore.capture.calibrate import Intrinsics
from ltmstore.core.dims import LUMA
from ltmstore.core.errors import LtmError
from ltmstore.synthetic import writer
from ltmstore.synthetic.render import render_ltm
from ltmstore.synthetic.simulate import (
    DEFAULT_PATH_DENSITY,
    EXPOSURE_PEAK,
    PLANE,
    SimulationPlan,
    plan_simulation,
    video_frames,
    write_truth,
)

CAMERA_SIZE = (1280, 720)
FOCAL_PX = 1000.0  # at 1280 px wide: a 65 degree horizontal field of view
LED_OFFSET = (0.012, 0.0, 0.0)  # metres, camera axes
BOARD_PAPER = "A0"  # 1189 x 841 mm: the camera sees the board everywhere over the 40 cm plane
BOARD_SQUARE_MM = 30.0
TEXTURE_PX_PER_M = 5000.0  # board texture resolution (0.2 mm per pixel)
EXPOSURE_S = 1 / 250  # phone A shutter time: motion blur
MOTION_SAMPLES = 3
OPTICS_BLUR_PX = 0.8  # Gaussian sigma of the lens blur, pixels at 1280 wide
NOISE_DN = 2.0  # read noise, 8-bit code values
SHOT_DN = 0.02  # shot noise variance per code value
YAW_WANDER_DEG = 20.0
TILT_DEG = 2.0  # standard deviation of the phone's tilt
CALIBRATION_VIEWS = 30
OFFSET_RANGE = (0.2, 0.5)  # seconds, magnitude of the clock offset (random sign)
OUTPUTS = ("acquisition.json", "video.mkv", "phone_a.mkv", "calibration.mkv", "board.json",
           "board.png", "truth", "truth.zarr", "poses.csv")


@dataclass(frozen=True, eq=False)
class PhoneCamera:
    """Phone A's camera: intrinsics and the LED offset."""

    size: tuple[int, int] = CAMERA_SIZE
    focal_px: float = FOCAL_PX
    led_offset: tuple[float, float, float] = LED_OFFSET

    @property
    def matrix(self) -> np.ndarray:
        w, h = self.size
        return np.array([[self.focal_px, 0, w / 2 - 0.5], [0, self.focal_px, h / 2 - 0.5],
                         [0, 0, 1]])


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


DOWN = np.diag([1.0, -1.0, -1.0])  # camera axes in plane coordinates when looking straight down
TO_BOARD = np.diag([1.0, -1.0, -1.0])  # plane axes -> board axes


def camera_extrinsics(spec: BoardSpec, centre: np.ndarray, r_wc: np.ndarray) -> tuple:
    """Board-to-camera rotation and translation for a camera at ``centre`` (plane coordinates)
    whose axes are the columns of ``r_wc`` (plane coordinates)."""
    origin = np.array([spec.size[0] / 2, spec.size[1] / 2, 0.0])
    r_cb = r_wc.T @ TO_BOARD
    t = -r_cb @ origin - r_wc.T @ centre
    return r_cb, t


def phone_orientation(t: np.ndarray, seed: int) -> np.ndarray:
    """Camera axes ``(n, 3, 3)`` over time: wandering yaw, small smooth tilts."""
    rng = np.random.default_rng([seed, 505])
    grid = np.arange(t.min() - 1, t.max() + 1, 0.01)

    def smooth(std_deg: float, corr_s: float) -> np.ndarray:
        noise = ndimage.gaussian_filter1d(rng.standard_normal(len(grid)), corr_s / 0.01)
        noise *= std_deg / max(noise.std(), 1e-12)
        return np.interp(t, grid, np.deg2rad(noise))

    yaw, tx, ty = smooth(YAW_WANDER_DEG / 2, 1.5), smooth(TILT_DEG, 0.4), smooth(TILT_DEG, 0.4)
    return np.stack([_rot(2, a) @ _rot(0, b) @ _rot(1, c) @ DOWN
                     for a, b, c in zip(yaw, tx, ty, strict=True)])


class BoardView:
    """Render phone A's view of the board (with the painting pasted at its centre)."""

    def __init__(self, spec: BoardSpec, camera: PhoneCamera, albedo: np.ndarray | None = None,
                 object_width: float = 0.2) -> None:
        self.spec, self.camera = spec, camera
        tex = board_image(spec, TEXTURE_PX_PER_M).astype(np.float32) / 255
        if albedo is not None:
            side = round(object_width * TEXTURE_PX_PER_M)
            patch = cv2.resize(np.asarray(albedo, np.float32), (side, side),
                               interpolation=cv2.INTER_LINEAR)
            y0, x0 = (tex.shape[0] - side) // 2, (tex.shape[1] - side) // 2
            tex[y0:y0 + side, x0:x0 + side] = np.clip(patch, 0, 1)
        self.texture = cv2.GaussianBlur(tex, (0, 0), 0.7)
        w, h = camera.size
        u, v = np.meshgrid(np.arange(w) - w / 2, np.arange(h) - h / 2)
        self.falloff = ((1 + (u * u + v * v) / camera.focal_px**2) ** -2).astype(np.float32)
        self.scale = np.array([[1 / TEXTURE_PX_PER_M, 0, 0.5 / TEXTURE_PX_PER_M],
                               [0, 1 / TEXTURE_PX_PER_M, 0.5 / TEXTURE_PX_PER_M], [0, 0, 1]])

    def homography(self, centre: np.ndarray, r_wc: np.ndarray) -> np.ndarray:
        r_cb, t = camera_extrinsics(self.spec, centre, r_wc)
        return self.camera.matrix @ np.column_stack([r_cb[:, 0], r_cb[:, 1], t]) @ self.scale

    def render(self, poses: list[tuple[np.ndarray, np.ndarray]],
               rng: np.random.Generator) -> np.ndarray:
        """One frame, uint8 grey: the mean of the views at ``poses`` (motion blur), lens blur,
        light falloff and sensor noise."""
        acc = np.zeros(self.camera.size[::-1], np.float32)
        for centre, r_wc in poses:
            acc += cv2.warpPerspective(self.texture, self.homography(centre, r_wc),
                                       self.camera.size, flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=0.45)
        sigma = OPTICS_BLUR_PX * self.camera.size[0] / CAMERA_SIZE[0]
        img = cv2.GaussianBlur(acc / len(poses), (0, 0), sigma)
        dn = (30 + 190 * img) * self.falloff
        dn += rng.standard_normal(dn.shape).astype(np.float32) * np.sqrt(
            NOISE_DN**2 + SHOT_DN * np.clip(dn, 0, None))
        return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


def led_to_camera(led: np.ndarray, r_wc: np.ndarray, led_offset) -> np.ndarray:
    """Camera centres ``(n, 3)`` from LED positions and camera axes."""
    return led - np.einsum("nij,j->ni", r_wc, np.asarray(led_offset, np.float64))


def phone_a_frames(plan: SimulationPlan, view: BoardView, times: np.ndarray,
                   seed: int) -> Iterator[np.ndarray]:
    """Yield phone A's frames (uint8 grey) at hand-clock ``times``; motion blurred."""
    rng = np.random.default_rng([seed, 606])
    offsets = EXPOSURE_S * (np.arange(MOTION_SAMPLES) / max(MOTION_SAMPLES - 1, 1) - 0.5)
    for t in times:
        sub = t + offsets
        led = np.column_stack(plan.trajectory.at(sub)[:3])
        r_wc = phone_orientation_at(sub, seed)
        centres = led_to_camera(led, r_wc, view.camera.led_offset)
        yield view.render(list(zip(centres, r_wc, strict=True)), rng)


@lru_cache(maxsize=2)
def _orientation_table(seed: int) -> tuple[np.ndarray, np.ndarray]:
    grid = np.arange(-5.0, 300.0, 0.01)
    return grid, phone_orientation(grid, seed).reshape(len(grid), 9)


def phone_orientation_at(t: np.ndarray, seed: int) -> np.ndarray:
    """:func:`phone_orientation` on a fixed 0.01 s grid (the same path whatever ``t``)."""
    grid, mats = _orientation_table(seed)
    out = np.stack([np.interp(t, grid, mats[:, k]) for k in range(9)], -1).reshape(-1, 3, 3)
    u, _, vt = np.linalg.svd(out)  # back onto rotations
    return u @ vt


def calibration_frames(view: BoardView, seed: int,
                       n: int = CALIBRATION_VIEWS) -> Iterator[np.ndarray]:
    """Still views of the board from varied positions and angles (tilts up to ~35 degrees)."""
    rng = np.random.default_rng([seed, 707])
    for _ in range(n):
        centre = np.array([*rng.uniform(-0.15, 0.15, 2), rng.uniform(0.28, 0.45)])
        target = np.array([*rng.uniform(-0.1, 0.1, 2), 0.0])
        z = target - centre
        z /= np.linalg.norm(z)
        roll = rng.uniform(-0.5, 0.5)
        hint = np.array([np.sin(roll), -np.cos(roll), 0.0])
        y = hint - z * (hint @ z)
        y /= np.linalg.norm(y)
        r_wc = np.column_stack([np.cross(y, z), y, z])
        yield view.render([(centre, r_wc)], rng)


def simulate_raw(out: str | os.PathLike, *, scene: str = "canvas",
                 path_density: float = DEFAULT_PATH_DENSITY, seed: int = 0, size: int = 128,
                 lattice: tuple[int, int] = (32, 32), camera: PhoneCamera | None = None,
                 time_offset: float | None = None, calibration_views: int = CALIBRATION_VIEWS,
                 truth: bool = True, overwrite: bool = False, progress: bool = True) -> dict:
    """Simulate a raw two-phone capture (see the module docstring).

    Parameters
    ----------
    out : path
        Output folder (created; must be empty unless ``overwrite``).
    scene, path_density, seed, size, lattice
        As :func:`ltmstore.synthetic.simulate.simulate_acquisition` (video B and truth).
    camera : PhoneCamera, optional
        Phone A's camera (default 1280 x 720, focal 1000 px, LED 12 mm to the right).
    time_offset : float, optional
        True clock offset ``t_B - t_A`` in seconds (default: random, 0.2-0.5 s either sign).
    calibration_views : int
        Frames of ``calibration.mkv`` (0: none).
    truth : bool
        Write ``truth.zarr``.
    overwrite : bool
        Replace an earlier simulation in ``out``.
    progress : bool
        Show progress bars.

    Returns
    -------
    dict
        ``frames``, ``time_offset``, ``led_offset``, ``camera``, ``paths`` and the video B
        simulation info.
    """
    camera = camera or PhoneCamera()
    plan = plan_simulation(scene=scene, path_density=path_density, seed=seed, size=size,
                           lattice=lattice, plane=PLANE)
    if time_offset is None:
        rng = np.random.default_rng([seed, 808])
        time_offset = float(rng.choice([-1, 1]) * rng.uniform(*OFFSET_RANGE))
    folder = writer.prepare_folder(Path(out), OUTPUTS, overwrite=overwrite)
    spec = board_spec(BOARD_PAPER, square_mm=BOARD_SQUARE_MM)
    try:
        return _execute(plan, folder, spec, camera, float(time_offset), calibration_views,
                        truth, progress)
    except OSError as exc:
        raise LtmError(f"cannot write simulation into {str(folder)!r}: {exc.strerror or exc}") \
            from exc


def _execute(plan: SimulationPlan, folder: Path, spec: BoardSpec, camera: PhoneCamera,
             offset: float, calibration_views: int, truth: bool, progress: bool) -> dict:
    (folder / "truth").mkdir(exist_ok=True)
    (folder / "board.json").write_text(json.dumps(spec.to_json(), indent=2) + "\n")
    cv2.imwrite(str(folder / "board.png"), page_image(spec, dpi=50))
    albedo = plan.scene.albedo @ LUMA
    view = BoardView(spec, camera, albedo, plan.scene.shape[1] * plan.scene.pixel_size)
    if calibration_views:
        frames = (cv2.cvtColor(f, cv2.COLOR_GRAY2RGB) for f in
                  calibration_frames(view, plan.seed, calibration_views))
        writer.write_video(folder / "calibration.mkv", frames, fps=writer.FPS)
    times_a = plan.video_start + offset + np.arange(plan.frame_count) / writer.FPS
    frames = tqdm(phone_a_frames(plan, view, times_a, plan.seed), total=len(times_a),
                  disable=not progress, desc="phone A", unit="frame")
    writer.write_video(folder / "phone_a.mkv",
                       (cv2.cvtColor(f, cv2.COLOR_GRAY2RGB) for f in frames), fps=writer.FPS)
    ltm = render_ltm(plan.scene, plan.lattice, plan.plane.height, progress=progress)
    exposure = EXPOSURE_PEAK / float(ltm.max())
    km = plan.sampling_ratio()
    if truth:
        ltm *= np.float32(exposure)
        write_truth(folder / "truth.zarr", plan, ltm, exposure=exposure, sampling_ratio=km)
    del ltm
    frames = tqdm(video_frames(plan, exposure=exposure), total=plan.frame_count,
                  disable=not progress, desc="phone B", unit="frame")
    n = writer.write_video(folder / "video.mkv", frames, fps=writer.FPS)
    writer.write_poses(folder / "truth" / "poses_true.csv", times_a - plan.video_start,
                       *plan.trajectory.at(times_a)[:3])
    Intrinsics(camera.size, camera.matrix, np.zeros(5)).write(folder / "truth" / "intrinsics.json")
    info = {"time_offset": offset, "led_offset": list(camera.led_offset),
            "camera": {"size": list(camera.size), "focal_px": camera.focal_px},
            "fps": writer.FPS, "frames": n, "scene": plan.scene.name, "seed": plan.seed,
            "exposure": exposure, "sampling_ratio": km, "lattice": list(plan.lattice.shape),
            "board": "board.json"}
    (folder / "truth" / "raw.json").write_text(json.dumps(info, indent=2) + "\n")
    writer.write_acquisition_json(folder, video="video.mkv", plane=plan.plane, transfer="srgb",
                                  extra={"phone_a": {"video": "phone_a.mkv",
                                                     "calibration": "calibration.mkv",
                                                     "board": "board.json"}})
    paths = {k: str(folder / v) for k, v in
             {"folder": ".", "acquisition": "acquisition.json", "video": "video.mkv",
              "phone_a": "phone_a.mkv", "calibration": "calibration.mkv", "board": "board.json",
              "truth": "truth.zarr", "truth_poses": "truth/poses_true.csv"}.items()}
    return {**info, "paths": paths}

