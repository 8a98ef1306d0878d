"""Simulated raw two-phone capture: ``ltm simulate --raw``, phones as they are.

Phone A is waved over the painting; its LED is the light and its camera films, by default, the
painting itself hung on a plain wall, lit by that LED (``--board``: a ChArUco board laid in the
object plane around the painting, as phone A's tracking target). Phone B films the painting from
a fixed position. Each phone effect of :mod:`ltmstore.synthetic.phone_effects` (lens distortion,
rolling shutter, motion blur, camera B's auto exposure and white balance, ambient light with a
1 s LED-off lead, the LED's angular fall-off, H.264) is on unless switched off (``--effects``).
Nothing but the videos is written for the pipeline (no poses file, no clock offset, no
intrinsics): ``ltm calibrate``, ``ltm track``, ``ltm sync`` and ``ltm ingest`` have to recover
them. Layout::

    OUT/acquisition.json   video B, plane, transfer, phone A's files; poses "poses.csv"
                           (written by `ltm track`); with distortion "camera_calibration":
                           "intrinsics_b.json" (written by `ltm calibrate calibration_b.mkv`)
    OUT/video.mp4|mkv      camera B: the painting lit by the LED (H.264 .mp4 with h264 on)
    OUT/phone_a.mp4|mkv    phone A: the painting (or the board) seen from the phone's pose
    OUT/calibration.mkv    phone A: still views of board.json from varied angles
    OUT/calibration_b.mkv  camera B: still views of board_b.json (with distortion on)
    OUT/painting.jpg       boardless: the user's front-on photograph of the painting, cropped to
                           its edges, at the detail phone A sees (``ltm track --painting``'s map)
    OUT/board.json/.png    phone A's board: the A0 tracking board (--board) or an A4 page
    OUT/board_b.json/.png  a coarse A4 board for camera B's calibration
    OUT/truth/             intrinsics.json (phone A, with its distortion), intrinsics_b.json,
                           poses_true.csv (true LED and its axis at phone A's frames, on
                           video B's clock),
                           camera_b.csv (per frame of video B: LED on, AE gain, white-balance
                           gains, phone A's optical axis), raw.json (true clock offset, LED
                           offset, painting width, every effect and its strength);
                           and OUT/truth.zarr: the LED held level, no ambient, drift or distortion

Geometry: plane coordinates ``(r, s, z)`` centred on the painting (and the board:
:meth:`BoardSpec.to_plane`); phone A's camera looks down, its image ``x`` axis along ``r``
turned by a slowly wandering yaw, with small smooth tilts; the LED sits at ``led_offset``
(camera axes: x right, y down, z along the optical axis) from the camera centre and shines along
the optical axis. Phone A's clock starts ``time_offset`` seconds after phone B's (``t_B = t_A +
time_offset``, the ``acquisition.json`` convention). Before the hand's scribble starts (the LED-off
lead) the phone holds still at the scribble's start.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
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
from ltmstore.core.transfer import linear_to_srgb
from ltmstore.synthetic import writer
from ltmstore.synthetic.camera_b import CameraBTimeline, camera_b_frames
from ltmstore.synthetic.phone_effects import (
    AMBIENT,
    BLUR_SAMPLES,
    DISTORTION_A,
    DISTORTION_B,
    LED_EXPONENT,
    READOUT_S,
    SHUTTER_OFF_S,
    SHUTTER_OFF_SAMPLES,
    SHUTTER_S,
    PhoneEffects,
    camera_b_matrix,
    h264_bitrate,
    parse_effects,
)
from ltmstore.synthetic.phone_view import LedLighting, PhoneView, PlaneTexture, wall_with_painting
from ltmstore.synthetic.render import GGX, MISMATCHED, Shading, render_ltm
from ltmstore.synthetic.scenes import SCENES, Scene, scene_albedo
from ltmstore.synthetic.simulate import (
    DEFAULT_PATH_DENSITY,
    EXPOSURE_PEAK,
    PLANE,
    SimulationPlan,
    plan_simulation,
    write_truth,
)

CAMERA_SIZE = (1280, 720)
FOCAL_PX = 1000.0  # at 1280 px wide: a 65 degree horizontal field of view
# The painting's physics (simulate_raw's shading): the product's own, or one it does not assume
RAW_SHADINGS = {"ggx": GGX, "mismatched": MISMATCHED}
SHADING_NAMES = tuple(RAW_SHADINGS)
LED_OFFSET = (0.012, 0.0, 0.0)  # metres, camera axes
BOARD_PAPER = "A0"  # 1189 x 841 mm: the camera sees the board everywhere over the 40 cm plane
BOARD_SQUARE_MM = 30.0
TEXTURE_PX_PER_M = 5000.0  # board texture resolution (0.2 mm per pixel; see board_px_per_m)
OPTICS_BLUR_PX = 0.8  # Gaussian sigma of the lens blur, pixels at 1280 wide
NOISE_DN = 2.0  # read noise, 8-bit code values
SHOT_DN = 0.02  # shot noise variance per code value
YAW_WANDER_DEG = 20.0
TILT_DEG = 2.0  # standard deviation of the phone's tilt
CALIBRATION_VIEWS = 30
OFFSET_RANGE = (0.2, 0.5)  # seconds, magnitude of the clock offset (random sign)
BOARD_B_SQUARES = (6, 4)  # camera B's calibration board: 46 mm squares on an A4 page
CAMERA_B_CALIBRATION_M = (0.6, 0.8)  # camera B's distance from it (the board fills the frame)
WALL_PX_PER_M = 3000.0  # boardless texture: 0.33 mm per texel (phone A sees 0.3 mm per pixel)
PAINTING_DETAIL_PX = 600  # the painting's own detail phone A sees (one per wall texel at 20 cm)
PHOTOGRAPH = "painting.jpg"  # the front-on photograph a user takes of the painting (boardless)
PHOTO_BLUR_PX = 0.7
WALL_EXTENT_M = 0.5  # the wall texture spans +-0.5 m: all that phone A sees over the plane
OUTPUTS = ("acquisition.json", "video.mkv", "video.mp4", "phone_a.mkv", "phone_a.mp4",
           "calibration.mkv", "calibration_b.mkv", PHOTOGRAPH, "board.json", "board.png",
           "board_b.json", "board_b.png", "truth", "truth.zarr", "poses.csv", "poses.frames.csv",
           "intrinsics.json", "intrinsics_b.json")


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


def rotation(axis: int, angle: float) -> np.ndarray:
    """The rotation by ``angle`` (radians) about coordinate axis ``axis`` (0, 1, 2)."""
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
    return np.stack([rotation(2, a) @ rotation(0, b) @ rotation(1, c) @ DOWN
                     for a, b, c in zip(yaw, tx, ty, strict=True)])


class BoardView:
    """Render phone A's view of the board (with the painting pasted at its centre)."""

    def __init__(self, spec: BoardSpec, camera: PhoneCamera, albedo: np.ndarray | None = None,
                 object_width: float = 0.2) -> None:
        self.spec, self.camera = spec, camera
        self.texture = board_texture(spec, albedo, object_width).albedo
        w, h = camera.size
        u, v = np.meshgrid(np.arange(w) - w / 2, np.arange(h) - h / 2)
        self.falloff = ((1 + (u * u + v * v) / camera.focal_px**2) ** -2).astype(np.float32)
        ppm = board_px_per_m(spec)
        self.scale = np.array([[1 / ppm, 0, 0.5 / ppm], [0, 1 / ppm, 0.5 / ppm], [0, 0, 1]])

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


def phone_poses(plan: SimulationPlan, camera: PhoneCamera):
    """``poses(times) -> (camera centres, camera axes, LED positions)`` on the hand's clock
    (before the trajectory starts the hand holds still at its start)."""
    def poses(times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        led = np.column_stack(plan.trajectory.at(times)[:3])
        r_wc = phone_orientation_at(times, plan.seed)
        return led_to_camera(led, r_wc, camera.led_offset), r_wc, led

    return poses


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



def calibration_frames(view: PhoneView, seed: int, n: int = CALIBRATION_VIEWS, *,
                       height: tuple[float, float] = (0.28, 0.45), spread: float = 0.15,
                       aim: float | None = None) -> Iterator[np.ndarray]:
    """Still views of a board from varied positions and angles (tilts up to ~35 degrees):
    camera centres ``height`` above the board, within ``spread`` of its centre, looking at a
    point within ``aim`` of it (default ``2 / 3`` of ``spread``)."""
    rng = np.random.default_rng([seed, 707])
    aim_scale = 2 / 3 if aim is None else aim / spread
    for _ in range(n):
        centre = np.array([*rng.uniform(-spread, spread, 2), rng.uniform(*height)])
        target = np.array([*rng.uniform(-spread, spread, 2) * aim_scale, 0.0])
        z = target - centre
        z /= np.linalg.norm(z)
        roll = rng.uniform(-0.5, 0.5)
        hint = np.array([np.sin(roll), -np.cos(roll), 0.0])
        y = hint - z * (hint @ z)
        y /= np.linalg.norm(y)
        r_wc = np.column_stack([np.cross(y, z), y, z])
        yield view.still(centre, r_wc, rng)


def write_calibration_video(path: Path, view: PhoneView, seed: int, n: int, *,
                            height: tuple[float, float], spread: float,
                            aim: float | None = None) -> Path:
    """``n`` still views of a board (:func:`calibration_frames`) filmed by ``view`` into the
    video ``path``, as :func:`simulate_raw` films each phone's calibration."""
    writer.write_video(path, _grey(calibration_frames(view, seed, n, height=height,
                                                      spread=spread, aim=aim)))
    return path


def board_px_per_m(spec: BoardSpec) -> float:
    """The board texture's resolution: the nearest to :data:`TEXTURE_PX_PER_M` with a whole
    number of texels per square.

    OpenCV draws a ChArUco board's squares on whole pixels, so at a fractional number of texels
    per square (camera B's 46.1 mm squares at 5000 px/m: 230.5) each corner is rounded by up to
    half a texel (0.1 mm) away from the geometry the board's JSON reports; at a whole number the
    drawn board is that geometry exactly (its physical size unchanged).

    Parameters
    ----------
    spec : BoardSpec
        The board.

    Returns
    -------
    float
        Texels per metre (exactly :data:`TEXTURE_PX_PER_M` where the squares already hold a
        whole number, e.g. 30 mm squares).
    """
    return round(spec.square_length * TEXTURE_PX_PER_M) / spec.square_length


def board_texture(spec: BoardSpec, albedo: np.ndarray | None = None,
                  object_width: float = 0.2) -> PlaneTexture:
    """The board (the painting pasted at its centre when ``albedo`` is given), centred on the
    plane origin, evenly lit, at :func:`board_px_per_m` (its corners where ``spec`` puts
    them)."""
    ppm = board_px_per_m(spec)
    tex = board_image(spec, ppm).astype(np.float32) / 255
    if albedo is not None:
        side = round(object_width * ppm)
        patch = cv2.resize(np.asarray(albedo, np.float32), (side, side),
                           interpolation=cv2.INTER_LINEAR)
        y0, x0 = (tex.shape[0] - side) // 2, (tex.shape[1] - side) // 2
        tex[y0:y0 + side, x0:x0 + side] = np.clip(patch, 0, 1)
    w, h = spec.size
    return PlaneTexture(cv2.GaussianBlur(tex, (0, 0), 0.7), None, -w / 2, h / 2, ppm, 0.45)


def simulate_raw(out: str | os.PathLike, *, scene: str = "canvas",
                 path_density: float = DEFAULT_PATH_DENSITY, seed: int = 0, size: int = 128,
                 lattice: tuple[int, int] = (32, 32), camera: PhoneCamera | None = None,
                 time_offset: float | None = None, calibration_views: int = CALIBRATION_VIEWS,
                 truth: bool = True, overwrite: bool = False, progress: bool = True,
                 board: bool = False, effects: str | PhoneEffects | None = "all",
                 shading: str = "ggx") -> dict:
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
        Frames of each calibration video (0: none).
    truth : bool
        Write ``truth.zarr``.
    overwrite : bool
        Replace an earlier simulation in ``out``.
    progress : bool
        Show progress bars.
    board : bool
        Phone A films the A0 ChArUco board around the painting (default: the painting alone,
        on a plain wall, lit by the phone's LED).
    effects : str or PhoneEffects
        ``"all"`` (default), ``"none"`` or a comma list of
        :data:`~ltmstore.synthetic.phone_effects.EFFECTS`.
    shading : {"ggx", "mismatched"}
        The painting's physics: the renderer's own (GGX, what the product's physical model
        assumes), or :data:`~ltmstore.synthetic.render.MISMATCHED`'s (a Beckmann lobe, a 2 %
        floor, a clear coat) with the LED's beam left to ``effects``.

    Returns
    -------
    dict
        ``frames``, ``time_offset``, ``led_offset``, ``camera``, ``effects``, ``paths`` and the
        video B simulation info.
    """
    camera = camera or PhoneCamera()
    fx = parse_effects(effects)
    plan = plan_simulation(scene=scene, path_density=path_density, seed=seed, size=size,
                           lattice=lattice, plane=PLANE)
    if time_offset is None:
        rng = np.random.default_rng([seed, 808])
        time_offset = float(rng.choice([-1, 1]) * rng.uniform(*OFFSET_RANGE))
    folder = writer.prepare_folder(Path(out), OUTPUTS, overwrite=overwrite)
    if shading not in RAW_SHADINGS:
        raise LtmError(f"shading {shading!r} must be one of {', '.join(RAW_SHADINGS)}")
    setup = RawSetup(plan, camera, fx, board, float(time_offset), calibration_views, progress,
                     RAW_SHADINGS[shading])
    try:
        return _execute(setup, folder, truth)
    except OSError as exc:
        raise LtmError(f"cannot write simulation into {str(folder)!r}: {exc.strerror or exc}") \
            from exc


@dataclass(frozen=True, eq=False)
class RawSetup:
    """What one raw simulation is made of (see :func:`simulate_raw`)."""

    plan: SimulationPlan
    camera: PhoneCamera
    effects: PhoneEffects
    board: bool
    offset: float
    calibration_views: int
    progress: bool
    shading: Shading = GGX  # the painting's physics (the LED's beam is an effect)

    @property
    def dist_a(self) -> tuple[float, float]:
        return DISTORTION_A if "distortion" in self.effects else (0.0, 0.0)

    @property
    def dist_b(self) -> tuple[float, float]:
        return DISTORTION_B if "distortion" in self.effects else (0.0, 0.0)

    @property
    def painting_width(self) -> float:
        return self.plan.scene.shape[1] * self.plan.scene.pixel_size

    def ext(self) -> str:
        return ".mp4" if "h264" in self.effects else ".mkv"

    def timeline(self) -> tuple[np.ndarray, CameraBTimeline]:
        """Camera B's frames (the LED-off lead first) and phone A's frame times, hand clock."""
        plan, lead = self.plan, self.effects.lead_s
        n = plan.frame_count + int(round(lead * writer.FPS))
        times = plan.video_start - lead + np.arange(n) / writer.FPS
        r_wc = phone_orientation_at(times, plan.seed)
        line = CameraBTimeline(times, np.column_stack(plan.trajectory.at(times)[:3]),
                               times >= plan.video_start - 1e-9, r_wc[:, :, 2])
        return times + self.offset, line

    def led_on(self, times: np.ndarray) -> np.ndarray:
        return (times >= self.plan.video_start - 1e-9).astype(np.float64)

    def phone_view(self, texture: PlaneTexture, lit: bool, *, moving: bool = True,
                   distance: float = PLANE.height) -> PhoneView:
        fx = self.effects
        lighting = None if not lit else LedLighting(
            exponent=LED_EXPONENT if "led-falloff" in fx else 0.0,
            ambient=AMBIENT if "ambient" in fx else 0.0, height=self.plan.plane.height)
        blur = moving and "motion-blur" in fx
        return PhoneView(self.camera.matrix, self.dist_a, self.camera.size, texture, lighting,
                         readout_s=READOUT_S if moving and "rolling-shutter" in fx else 0.0,
                         shutter_s=SHUTTER_S if blur else SHUTTER_OFF_S if moving else 0.0,
                         samples=BLUR_SAMPLES if blur else SHUTTER_OFF_SAMPLES if moving else 1,
                         distance=distance)


def _execute(setup: RawSetup, folder: Path, truth: bool) -> dict:
    plan, fx = setup.plan, setup.effects
    (folder / "truth").mkdir(exist_ok=True)
    boards = _write_boards(setup, folder)
    times_a, line = setup.timeline()
    _write_phone_a(setup, folder, boards["a"], times_a)
    shading = replace(setup.shading, led_exponent=LED_EXPONENT if "led-falloff" in fx else 0.0)
    ltm = render_ltm(plan.scene, plan.lattice, plan.plane.height, progress=setup.progress,
                     shading=shading)
    exposure = EXPOSURE_PEAK / float(ltm.max())
    km = plan.sampling_ratio()
    if truth:
        ltm *= np.float32(exposure)
        write_truth(folder / "truth.zarr", plan, ltm, exposure=exposure, sampling_ratio=km)
    del ltm
    n = _write_camera_b(setup, folder, boards["b"], line, exposure)
    t0 = plan.video_start - fx.lead_s  # camera B's first frame, hand clock
    _write_true_poses(folder / "truth" / "poses_true.csv", times_a - t0,
                      plan.trajectory.at(times_a)[:3], phone_orientation_at(times_a, plan.seed))
    Intrinsics(setup.camera.size, setup.camera.matrix, np.array([*setup.dist_a, 0, 0, 0])) \
        .write(folder / "truth" / "intrinsics.json")
    info = _raw_info(setup, n, exposure, km)
    (folder / "truth" / "raw.json").write_text(json.dumps(info, indent=2) + "\n")
    _write_acquisition(setup, folder, boards)
    paths = {k: str(folder / v) for k, v in
             {"folder": ".", "acquisition": "acquisition.json", "video": "video" + setup.ext(),
              "phone_a": "phone_a" + setup.ext(), "calibration": "calibration.mkv",
              "board": "board.json", "truth": "truth.zarr",
              "truth_poses": "truth/poses_true.csv"}.items()}
    if "distortion" in fx:
        paths.update(calibration_b=str(folder / "calibration_b.mkv"),
                     board_b=str(folder / boards["b_name"]))
    if not setup.board:
        paths["photograph"] = str(folder / PHOTOGRAPH)
    return {**info, "paths": paths}


def _write_true_poses(path: Path, t: np.ndarray, led: tuple, r_wc: np.ndarray) -> None:
    """``poses_true.csv``: the LED's position and its axis (phone A's optical axis, the LED
    shines along it) at phone A's frames, header ``t,r,s,z,axis_r,axis_s,axis_z``."""
    np.savetxt(path, np.column_stack([t, *led, r_wc[:, :, 2]]), delimiter=",",
               header="t,r,s,z,axis_r,axis_s,axis_z", comments="", fmt="%.9g")


def _write_boards(setup: RawSetup, folder: Path) -> dict:
    """``board.json`` (phone A's: the A0 tracking board, or an A4 calibration page without
    ``board``) and, for camera B's calibration, a coarse A4 board ``board_b.json``."""
    spec = board_spec(BOARD_PAPER if setup.board else "A4", square_mm=BOARD_SQUARE_MM)
    spec_b = board_spec("A4", squares=BOARD_B_SQUARES)
    for name, sp in (("board", spec), ("board_b", spec_b)):
        (folder / f"{name}.json").write_text(json.dumps(sp.to_json(), indent=2) + "\n")
        cv2.imwrite(str(folder / f"{name}.png"), page_image(sp, dpi=50))
    return {"a": spec, "b": spec_b, "b_name": "board_b.json"}


def _phone_a_texture(setup: RawSetup, spec: BoardSpec) -> PlaneTexture:
    albedo = painting_detail(setup.plan.scene) @ LUMA
    if setup.board:
        return board_texture(spec, albedo, setup.painting_width)
    return wall_with_painting(albedo, setup.painting_width, ppm=WALL_PX_PER_M,
                              extent=WALL_EXTENT_M, seed=setup.plan.seed)


def painting_detail(scene: Scene) -> np.ndarray:
    """The painting's albedo ``(h, w, 3)`` as phone A sees it: a built-in scene rebuilt at
    :data:`PAINTING_DETAIL_PX` (phone A, close up, resolves what camera B's pixels average),
    a custom scene as it is."""
    if scene.name not in SCENES or scene.shape[1] >= PAINTING_DETAIL_PX:
        return scene.albedo
    return scene_albedo(scene.name, PAINTING_DETAIL_PX)


def _write_phone_a(setup: RawSetup, folder: Path, spec: BoardSpec, times: np.ndarray) -> None:
    if setup.calibration_views:
        height = (0.28, 0.45) if setup.board else (0.18, 0.3)
        still = setup.phone_view(board_texture(spec), False, moving=False,
                                 distance=sum(height) / 2)
        write_calibration_video(folder / "calibration.mkv", still, setup.plan.seed,
                                setup.calibration_views, height=height,
                                spread=0.15 if setup.board else 0.06)
    texture = _phone_a_texture(setup, spec)
    if not setup.board:
        _write_photograph(folder / PHOTOGRAPH, texture.painting(), setup.plan.seed)
    view = setup.phone_view(texture, not setup.board)
    poses, rng = phone_poses(setup.plan, setup.camera), np.random.default_rng([setup.plan.seed,
                                                                                606])
    frames = (view.frame(t, poses, rng, setup.led_on) for t in
              tqdm(times, disable=not setup.progress, desc="phone A", unit="frame"))
    _write(setup, folder / ("phone_a" + setup.ext()), _grey(frames), setup.camera.size)


def _write_photograph(path: Path, albedo: np.ndarray, seed: int) -> None:
    """The user's front-on photograph of the painting, cropped to its edges (``ltm track
    --painting``'s map): room light falling off by 15 % across it, exposed to put white at 90 %,
    lens blur, sensor noise, JPEG at quality 90."""
    h, w = albedo.shape
    ramp = 1.0 - 0.15 * np.linspace(0, 1, w)[None, :] - 0.05 * np.linspace(0, 1, h)[:, None]
    img = cv2.GaussianBlur((0.9 * albedo * ramp).astype(np.float32), (0, 0), PHOTO_BLUR_PX)
    code = 255 * linear_to_srgb(np.clip(img, 0, 1))
    code += np.random.default_rng([seed, 909]).normal(0, NOISE_DN, code.shape)
    cv2.imwrite(str(path), np.clip(np.round(code), 0, 255).astype(np.uint8),
                [cv2.IMWRITE_JPEG_QUALITY, 90])


def _grey(frames):
    return (cv2.cvtColor(f, cv2.COLOR_GRAY2RGB) for f in frames)


def _write(setup: RawSetup, path: Path, frames, size: tuple[int, int]) -> int:
    if path.suffix == ".mp4":
        return writer.write_h264(path, frames, fps=writer.FPS,
                                 bitrate=h264_bitrate(size, writer.FPS))
    return writer.write_video(path, frames, fps=writer.FPS)


def _write_camera_b(setup: RawSetup, folder: Path, spec_b: BoardSpec, line: CameraBTimeline,
                    exposure: float) -> int:
    plan = setup.plan
    h, w = plan.scene.shape
    matrix = camera_b_matrix((w, h))
    if "distortion" in setup.effects and setup.calibration_views:
        view = PhoneView(matrix, setup.dist_b, (w, h), board_texture(spec_b), None,
                         distance=sum(CAMERA_B_CALIBRATION_M) / 2)
        write_calibration_video(folder / "calibration_b.mkv", view, plan.seed + 1,
                                max(setup.calibration_views, 12),
                                height=CAMERA_B_CALIBRATION_M, spread=0.35, aim=0.03)
    Intrinsics((w, h), matrix, np.array([*setup.dist_b, 0, 0, 0])) \
        .write(folder / "truth" / "intrinsics_b.json")
    records: list = []
    frames = tqdm(camera_b_frames(plan, line, exposure=exposure, effects=setup.effects,
                                  records=records, shading=setup.shading),
                  total=len(line.times),
                  disable=not setup.progress, desc="phone B", unit="frame")
    n = _write(setup, folder / ("video" + setup.ext()), frames, (w, h))
    t = line.times - line.times[0]
    np.savetxt(folder / "truth" / "camera_b.csv",
               np.column_stack([t, line.led_on, np.asarray(records), line.axes]), delimiter=",",
               header="t,led_on,gain,wb_r,wb_g,wb_b,axis_r,axis_s,axis_z", comments="",
               fmt="%.9g")
    return n


def _raw_info(setup: RawSetup, n: int, exposure: float, km: float) -> dict:
    plan, camera = setup.plan, setup.camera
    return {"time_offset": setup.offset, "led_offset": list(camera.led_offset),
            "camera": {"size": list(camera.size), "focal_px": camera.focal_px,
                       "dist_coeffs": [*setup.dist_a, 0, 0, 0]},
            "camera_b": {"intrinsics": "truth/intrinsics_b.json",
                         "dist_coeffs": [*setup.dist_b, 0, 0, 0],
                         "drift": "truth/camera_b.csv"},
            "fps": writer.FPS, "frames": n, "scene": plan.scene.name, "seed": plan.seed,
            "shading": next(k for k, v in RAW_SHADINGS.items() if v == setup.shading),
            "exposure": exposure, "sampling_ratio": km, "lattice": list(plan.lattice.shape),
            "board": "board.json", "tracking": "board" if setup.board else "painting",
            "painting_width_m": setup.painting_width, "led_off_lead_s": setup.effects.lead_s,
            "effects": setup.effects.to_json(), "poses_true": "truth/poses_true.csv",
            "truth": "LED held level (axis straight down), no ambient, no drift, no distortion"}


def _write_acquisition(setup: RawSetup, folder: Path, boards: dict) -> None:
    phone_a = {"video": "phone_a" + setup.ext(), "calibration": "calibration.mkv",
               "board": "board.json"}
    if not setup.board:
        phone_a.update(painting=PHOTOGRAPH, painting_width=setup.painting_width)
    extra = {"phone_a": phone_a}
    if "distortion" in setup.effects:
        extra["camera_calibration"] = "intrinsics_b.json"
        extra["camera_b"] = {"calibration": "calibration_b.mkv", "board": boards["b_name"]}
    writer.write_acquisition_json(folder, video="video" + setup.ext(), plane=setup.plan.plane,
                                  transfer="srgb", extra=extra)
