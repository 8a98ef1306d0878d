"""Simulated handheld acquisitions with ground truth: ``ltm simulate``.

A run is planned first (:func:`plan_simulation`: scene, plane, lattice, true trajectory, tracker
record, video timing; all seeded), then executed (:func:`simulate_acquisition`), which writes an
acquisition folder (ARCHITECTURE.md section 3.1) plus the ground truth ``truth.zarr``::

    OUT/acquisition.json   transfer "srgb", the object's extent "object", {"simulation": {...}}
    OUT/video.mkv          FFV1 lossless (video.mp4, mp4v, with ``lossy``), 30 fps, sRGB uint8
    OUT/poses.csv          the tracker's irregular, noisy reports; t = 0 at the first frame
    OUT/truth.zarr         ltm (y, x, r, s) linear luminance and ltm_rgb (y, x, r, s, color)

A 6D simulation (``view=True``, ``ltm simulate --6d``) also moves camera B: it scribbles over a
view plane parallel to the object (:data:`VIEW_PLANE`), looking at the object's centre through a
pinhole (:class:`~ltmstore.capture.register.ViewRig`, declared in ``acquisition.json`` under
``view_plane``). Each frame is the rectified view of :meth:`render.rectified` (raised features
shift with the camera: parallax) projected into the camera's frame by the plane-induced
homography; ``poses.csv`` gains the ``p, q`` columns and ``truth.zarr`` holds the 6D luminance
LTM ``ltm (y, x, r, s, p, q)`` of the rectified views.

Frames are rendered at the *true* light position (excursions out of the plane included), scaled
by one exposure constant, given mild sensor noise, clipped and sRGB-encoded. The truth is in the
same linear units as the frames before encoding (rendered radiance x exposure), i.e. what an
ingest that inverts the sRGB transfer recovers. ``acquisition.json`` is written last, so an
interrupted run never looks like a complete acquisition folder.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.register import Intrinsics, ObjectGrid, ViewRig, render_camera_frame
from ltmstore.core.dims import (
    COLOR,
    COLOR_CHANNELS,
    LIGHT_DIMS,
    LTM,
    LTM_RGB,
    LUMA,
    VIEW_DIMS,
    Lattice,
    Plane,
    R,
    S,
    X,
    Y,
)
from ltmstore.core.errors import LtmError
from ltmstore.core.paths import check_simulation_folder
from ltmstore.core.store import complete_stage, create_variable, new_store, write_coord
from ltmstore.core.transfer import encode
from ltmstore.synthetic import writer
from ltmstore.synthetic.render import (
    PinholeCamera,
    _Renderer,
    iter_frames,
    render_ltm,
    render_ltm_6d,
)
from ltmstore.synthetic.scenes import Scene, make_scene
from ltmstore.synthetic.trajectory import (
    Trajectory,
    check_path_density,
    sampling_ratio,
    scribble,
    track,
)

PLANE = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)  # a 40 cm square, 30 cm above
# what a scene takes to render per pixel (measured: 240-283 B/px at 512 px over the three
# scenes' builders), with room for the frames; and a float64 RGB truth LTM per lattice cell
SCENE_BYTES_PER_PIXEL = 512
TRUTH_BYTES_PER_CELL = 24
MAX_VIDEO_FRAMES = 1_000_000  # a light path of up to 9 h of video at 30 frames/s
DEFAULT_PATH_DENSITY = 27.0  # 1/m: K/M about 0.29 on a 32 x 32 lattice (the paper's ratio)
EXPOSURE_PEAK = 0.9  # the brightest ground-truth value maps to this (linear)
READ_NOISE = 0.002  # sensor noise: sigma^2 = READ_NOISE^2 + SHOT_NOISE * value (linear units)
SHOT_NOISE = 2.5e-5  # ... so sigma is about 0.5 % of full scale at the top of the range
VIDEO_MARGIN = 0.1  # s: the video starts this long after the hand and stops this long before
TRACKER_NOISE = 0.0003  # m: standard deviation of the tracker noise (the paper: 0.31 mm RMS)
TRACKER_SKEW = 0.1  # s: the tracker record starts/stops up to this much before/after the video
OUTPUTS = ("acquisition.json", "poses.csv", "video.mkv", "video.mp4", "truth.zarr")
TRUTH_UNITS = {"units": "linear frame value (rendered radiance x exposure, before sRGB)"}
# 6D: camera B scribbles over a 20 cm square 45 cm above the object, looking at its centre.
VIEW_PLANE = Plane(r=(-0.1, 0.1), s=(-0.1, 0.1), height=0.45)
DEFAULT_LATTICE_6D = (12, 12, 6, 6)
DEFAULT_PATH_DENSITY_6D = 160.0  # 1/m: K/M near the paper's 0.166 on the default 6D lattice
SPEED_6D = 0.5  # m/s: mean light speed in 6D (more distinct (light, view) cells per frame)
VIEW_SPEED = 0.15  # m/s: mean camera speed on the view plane
CAMERA_FRAME = 1.55  # camera frame side, in object-grid pixels (the object overfills it a bit)
CAMERA_ZOOM = 1.6  # the object spans this many times its grid size in the central view


def view_rig(scene: Scene, view_plane: Plane = VIEW_PLANE) -> ViewRig:
    """Camera B for a scene: a square frame a bit larger than the object in the central view,
    looking at the object's centre from the view plane's height."""
    h, w = scene.shape
    side = 2 * int(round(CAMERA_FRAME * max(h, w) / 2))  # even: FFV1 and most codecs
    focal = CAMERA_ZOOM * w * view_plane.height / (w * scene.pixel_size)
    intr = Intrinsics(fx=focal, fy=focal, cx=(side - 1) / 2, cy=(side - 1) / 2, width=side,
                      height=side)
    return ViewRig(intrinsics=intr, distance=view_plane.height,
                   grid=ObjectGrid((h, w), scene.pixel_size), look_at=(0.0, 0.0))


@dataclass(frozen=True, eq=False)
class SimulationPlan:
    """Everything a simulated acquisition is made of, before any rendering.

    Times of ``trajectory`` and ``tracker`` are on the hand's clock; the video's first frame is
    at ``video_start`` on that clock (``t = 0`` of the acquisition folder).
    """

    scene: Scene
    plane: Plane
    lattice: Lattice
    trajectory: Trajectory
    tracker: Trajectory
    video_start: float
    frame_count: int
    seed: int
    path_density: float
    view_plane: Plane | None = None
    rig: ViewRig | None = None

    @property
    def frame_times(self) -> np.ndarray:
        """Times of the video frames on the hand's clock."""
        return self.video_start + np.arange(self.frame_count) / writer.FPS

    def frame_lights(self) -> np.ndarray:
        """True light positions ``(frame_count, 3)`` at the frame times."""
        return np.column_stack(self.trajectory.at(self.frame_times)[:3])

    def frame_views(self) -> np.ndarray:
        """True camera positions ``(frame_count, 2)`` at the frame times (6D plans)."""
        return np.column_stack(self.trajectory.at(self.frame_times)[3:5])

    def view_plane_json(self) -> dict:
        """``view_plane`` of ``acquisition.json`` (6D plans): the ``p, q`` ranges and the rig."""
        return {"p": list(self.view_plane.r), "q": list(self.view_plane.s), **self.rig.to_json()}

    def sampling_ratio(self) -> float:
        """``K / M`` of the frames on the truth lattice (4-D for a 6D plan)."""
        lights = self.frame_lights()[:, :2].T
        if self.view_plane is None:
            return sampling_ratio(*lights, self.lattice)
        cells = self.lattice.cell_index(*lights, *self.frame_views().T)
        return np.unique(cells[cells >= 0]).size / self.lattice.size


def plan_simulation(*, scene: str | Scene = "canvas", path_density: float = DEFAULT_PATH_DENSITY,
                    seed: int = 0, size: int = 128, delta_rs: float | None = None,
                    lattice: tuple[int, ...] = (32, 32), plane: Plane = PLANE,
                    view: bool = False, view_plane: Plane = VIEW_PLANE,
                    view_speed: float = VIEW_SPEED, speed: float = 0.25) -> SimulationPlan:
    """Plan a simulated acquisition (cheap: no rendering). See :func:`simulate_acquisition`."""
    density = check_path_density(path_density)
    check_scale(seed=seed, size=size, path_density=density, speed=speed, plane=plane)
    the_scene = scene if isinstance(scene, Scene) else make_scene(scene, size=size, seed=seed)
    views = view_plane if view else None
    grid = _lattice(plane, delta_rs, lattice, views)
    path = scribble(plane, path_density=density, seed=seed, speed=speed, view=views,
                    view_speed=view_speed)
    video_start = min(VIDEO_MARGIN, path.duration / 4)
    frame_count = int((path.duration - 2 * video_start) * writer.FPS) + 1
    skew = np.random.default_rng([seed, 404]).uniform(-TRACKER_SKEW, TRACKER_SKEW, 2)
    video_stop = video_start + (frame_count - 1) / writer.FPS
    tracker = track(path, seed=seed, noise=TRACKER_NOISE, start=video_start + skew[0],
                    stop=video_stop + skew[1])
    return SimulationPlan(scene=the_scene, plane=plane, lattice=grid, trajectory=path,
                          tracker=tracker, video_start=video_start, frame_count=frame_count,
                          seed=seed, path_density=density, view_plane=views,
                          rig=view_rig(the_scene, view_plane) if view else None)


def check_scale(*, seed: int, size: int, path_density: float, speed: float,
                plane: Plane) -> None:
    """Refuse, before anything is allocated, a seed that is not a whole number from 0, a scene
    larger than this machine's memory (:data:`SCENE_BYTES_PER_PIXEL`) or a light path longer than
    :data:`MAX_VIDEO_FRAMES` frames; each with one line naming the value and the limit."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise LtmError(f"--seed {seed!r} must be a whole number from 0 (a random seed)")
    if isinstance(size, numbers.Integral) and size > 0:
        largest = math.isqrt(memory_bytes() // SCENE_BYTES_PER_PIXEL)
        if size > largest:
            need = size_text(size ** 2 * SCENE_BYTES_PER_PIXEL)
            raise LtmError(f"--size {size} asks for about {need} to render the scene; this "
                           f"machine has {size_text(memory_bytes())} of memory: at most --size "
                           f"{largest}")
    frames = path_density * plane_area(plane) / speed * writer.FPS  # the path's length / speed
    if not frames <= MAX_VIDEO_FRAMES:
        longest = MAX_VIDEO_FRAMES * path_density / frames
        raise LtmError(f"--path-density {path_density:g} asks for a light path of about "
                       f"{frames:.3g} video frames; expected at most {MAX_VIDEO_FRAMES:,} "
                       f"(--path-density up to about {longest:.4g})")


def check_truth_memory(size: int, lattice: tuple[int, ...]) -> None:
    """Refuse a true LTM (float64 RGB at every pixel and lattice cell) larger than this
    machine's memory, naming its size and the largest ``--size`` that fits."""
    per_pixel = TRUTH_BYTES_PER_CELL * math.prod(lattice)
    if isinstance(size, numbers.Integral) and size > 0 and size ** 2 * per_pixel > memory_bytes():
        raise LtmError(f"--size {size} with a {'x'.join(map(str, lattice))} truth lattice "
                       f"asks for about {size_text(size ** 2 * per_pixel)} for truth.zarr's "
                       f"LTM; this machine has {size_text(memory_bytes())} of memory: at most "
                       f"--size {math.isqrt(memory_bytes() // per_pixel)}")


def memory_bytes() -> int:
    """This machine's physical memory."""
    import psutil

    return int(psutil.virtual_memory().total)


def plane_area(plane: Plane) -> float:
    (r0, r1), (s0, s1) = plane.r, plane.s
    return abs((r1 - r0) * (s1 - s0))


def size_text(n: float) -> str:
    """``n`` bytes as ``12.3 GiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} TiB"


def _lattice(plane: Plane, delta_rs: float | None, shape: tuple[int, ...],
             view_plane: Plane | None = None) -> Lattice:
    if view_plane is not None:
        if delta_rs is not None:
            light = Lattice.from_delta(plane, delta_rs)
            views = Lattice.from_delta(view_plane, delta_rs)
            shape = (*light.shape, *views.shape)
        if len(tuple(shape)) != 4 or min(shape) < 1:
            raise LtmError(f"6D lattice {shape!r} must be four cell counts (R, S, P, Q), "
                           "e.g. (12, 12, 6, 6)")
        return Lattice(bounds=(plane.r, plane.s, view_plane.r, view_plane.s),
                       shape=tuple(int(n) for n in shape), dims=(*LIGHT_DIMS, *VIEW_DIMS))
    if delta_rs is not None:
        return Lattice.from_delta(plane, delta_rs)
    if len(tuple(shape)) != 2:
        raise LtmError(f"lattice {shape!r} must be two cell counts (R, S), e.g. (32, 32)")
    return Lattice.from_plane(plane, shape)


def simulate_acquisition(out: str | os.PathLike, *, scene: str | Scene = "canvas",
                         path_density: float | None = None, seed: int = 0,
                         lossy: bool = False, size: int = 128, delta_rs: float | None = None,
                         lattice: tuple[int, ...] | None = None, plane: Plane = PLANE,
                         truth: bool = True, overwrite: bool = False,
                         progress: bool = True, view: bool = False,
                         view_plane: Plane = VIEW_PLANE, view_speed: float = VIEW_SPEED,
                         speed: float | None = None) -> dict:
    """Simulate a handheld acquisition of a synthetic painting, with its ground truth.

    Parameters
    ----------
    out : path
        Output folder (created; must be empty unless ``overwrite``).
    scene : {"canvas", "icon", "relief"} or Scene
    path_density : float, optional
        Trajectory length per unit plane area, 1/m (default 27: K/M about 0.29 on 32 x 32;
        6D: :data:`DEFAULT_PATH_DENSITY_6D`).
    seed : int
    lossy : bool
        Write ``video.mp4`` (mp4v) instead of lossless ``video.mkv`` (FFV1).
    size : int
        Image side in pixels.
    delta_rs : float, optional
        Ground-truth lattice cell size; overrides ``lattice``.
    lattice : tuple of int, optional
        Ground-truth lattice ``(R, S)`` over the plane (default 32 x 32), or ``(R, S, P, Q)``
        in 6D (default :data:`DEFAULT_LATTICE_6D`).
    plane : Plane
        The illumination plane (default: a 40 cm square 30 cm above the object).
    truth : bool
        Write ``truth.zarr``. Without it (large benchmarks) the exposure comes from a lattice
        of a quarter the resolution, and the LTM is never held in memory.
    overwrite : bool
        Replace the outputs of an earlier simulation in ``out``.
    progress : bool
        Show progress bars.
    view : bool
        A 6D acquisition: camera B moves over ``view_plane`` too (see the module docstring).
    view_plane : Plane
        Where camera B moves; its ``height`` is the camera's distance from the object.
    view_speed, speed : float
        Mean camera and light speeds (plane units per second); the light's defaults to 0.25
        (4D) or :data:`SPEED_6D`.

    Returns
    -------
    dict
        ``frames``, ``duration_s``, ``path_density`` (achieved), ``sampling_ratio`` (K/M of the
        frames on the truth lattice), ``exposure``, ``tracker_reports``, ``lattice``,
        ``delta_rs``, ``scene``, ``seed`` and ``paths`` (folder, acquisition, video, poses,
        truth).

    Raises
    ------
    LtmError
        Unknown scene, non-positive path density, bad lattice, an output folder that is not
        empty (without ``overwrite``) or cannot be written.
    """
    if path_density is None:
        path_density = DEFAULT_PATH_DENSITY_6D if view else DEFAULT_PATH_DENSITY
    if lattice is None:
        lattice = DEFAULT_LATTICE_6D if view else (32, 32)
    if speed is None:
        speed = SPEED_6D if view else 0.25
    # every refusal before the scene is rendered: the values, then the folder
    check_scale(seed=seed, size=size, path_density=check_path_density(path_density),
                speed=speed, plane=plane)
    if truth:
        check_truth_memory(size, _lattice(plane, delta_rs, lattice,
                                          view_plane if view else None).shape)
    check_simulation_folder(out, overwrite)  # never a folder of someone else's files
    plan = plan_simulation(scene=scene, path_density=path_density, seed=seed, size=size,
                           delta_rs=delta_rs, lattice=lattice, plane=plane, view=view,
                           view_plane=view_plane, view_speed=view_speed, speed=speed)
    folder = writer.prepare_folder(Path(out), OUTPUTS, overwrite=overwrite)
    try:
        return _execute(plan, folder, lossy=lossy, truth=truth, progress=progress)
    except OSError as exc:
        raise LtmError(f"cannot write simulation into {str(folder)!r}: {exc.strerror or exc}") \
            from exc


def _execute(plan: SimulationPlan, folder: Path, *, lossy: bool, truth: bool,
             progress: bool) -> dict:
    km = plan.sampling_ratio()
    if truth:
        ltm = _render_truth(plan, plan.lattice, progress=progress)
        exposure = EXPOSURE_PEAK / float(ltm.max())
        ltm *= np.float32(exposure)
        write = write_truth if plan.view_plane is None else write_truth_6d
        write(folder / "truth.zarr", plan, ltm, exposure=exposure, sampling_ratio=km)
        del ltm
    else:
        coarse = replace(plan.lattice, shape=tuple(max(1, n // 4) for n in plan.lattice.shape))
        exposure = EXPOSURE_PEAK / float(_render_truth(plan, coarse).max())
    video = folder / writer.video_name(lossy)
    make_frames = video_frames if plan.view_plane is None else video_frames_6d
    frames = tqdm(make_frames(plan, exposure=exposure), total=plan.frame_count,
                  disable=not progress, desc="video", unit="frame")
    n = writer.write_video(video, frames, fps=writer.FPS)
    tk = plan.tracker
    writer.write_poses(folder / "poses.csv", tk.t - plan.video_start, tk.r, tk.s, tk.z, tk.p,
                       tk.q)
    info = _simulation_info(plan, exposure, km)
    h, w = plan.scene.shape
    half = (w * plan.scene.pixel_size / 2, h * plan.scene.pixel_size / 2)
    extra = {"object": {"x": [-half[0], half[0]], "y": [-half[1], half[1]]}, "simulation": info}
    if plan.view_plane is not None:
        info.update(view_lattice=list(plan.lattice.shape[2:]),
                    view_speed_note="camera B scribbles over view_plane, looking at the "
                                    "object centre")
        extra = {"view_plane": plan.view_plane_json(), **extra}
    writer.write_acquisition_json(folder, video=video.name, plane=plan.plane, transfer="srgb",
                                  extra=extra)
    paths = {"folder": folder, "acquisition": folder / "acquisition.json", "video": video,
             "poses": folder / "poses.csv"}
    if truth:
        paths["truth"] = folder / "truth.zarr"
    return {**info, "frames": n, "duration_s": n / writer.FPS,
            "paths": {k: str(v) for k, v in paths.items()}}


def _render_truth(plan: SimulationPlan, lattice: Lattice, *, progress: bool = False) -> np.ndarray:
    """The plan's ground-truth LTM on ``lattice``: RGB ``(y, x, r, s, color)``, or 6D luminance
    ``(y, x, r, s, p, q)``."""
    if plan.view_plane is None:
        return render_ltm(plan.scene, lattice, plan.plane.height, progress=progress)
    return render_ltm_6d(plan.scene, lattice, plan.plane.height,
                         distance=plan.view_plane.height, progress=progress)


def _sensor(linear: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Read and shot noise on a linear frame (float64), then sRGB uint8."""
    sigma = np.sqrt(READ_NOISE**2 + SHOT_NOISE * np.clip(linear, 0.0, None))
    return encode(linear + sigma * rng.standard_normal(linear.shape), "srgb")


def video_frames_6d(plan: SimulationPlan, *, exposure: float) -> Iterator[np.ndarray]:
    """Camera B's frames, ``(h, w, 3)`` sRGB uint8: the rectified view at the true light and
    camera positions, projected into the camera's frame (black around the object), with noise.
    """
    rng = np.random.default_rng([plan.seed, 303])
    renderer = _Renderer(plan.scene)
    rig = plan.rig
    for light, (p, q) in zip(plan.frame_lights(), plan.frame_views(), strict=True):
        renderer.set_camera(PinholeCamera(p, q, rig.distance, rig.intrinsics.fx))
        rectified = renderer.rectified(light) * np.float32(exposure)
        yield _sensor(render_camera_frame(rectified, rig, p, q).astype(np.float64), rng)


def write_truth_6d(path: Path, plan: SimulationPlan, ltm: np.ndarray, *, exposure: float,
                   sampling_ratio: float) -> None:
    """Write the 6D ground truth ``ltm (y, x, r, s, p, q)`` (luminance) atomically."""
    h, w = ltm.shape[:2]
    with new_store(path, overwrite=True) as group:
        write_coord(group, Y, np.arange(h))
        write_coord(group, X, np.arange(w))
        for name, values in plan.lattice.coords().items():
            write_coord(group, name, values, units=plan.plane.unit)
        lum = create_variable(group, LTM, (Y, X, *plan.lattice.dims), ltm.shape,
                              chunks=(min(h, 16), min(w, 16), *plan.lattice.shape),
                              attrs=TRUTH_UNITS)
        lum[...] = ltm
        _complete_truth(group, plan, exposure, sampling_ratio)


def _complete_truth(group, plan: SimulationPlan, exposure: float, sampling_ratio: float) -> None:
    """Record the truth's provenance in its store (attributes and the ``truth`` stage)."""
    view = {} if plan.view_plane is None else {"view_plane": plan.view_plane_json()}
    info = {"plane": plan.plane.to_json(), "lattice": plan.lattice.to_json(), **view,
            "exposure": exposure, "scene": plan.scene.name, "seed": plan.seed,
            "path_density": plan.trajectory.path_density(plan.plane),
            "sampling_ratio": sampling_ratio}
    group.attrs.update(info)
    complete_stage(group, "truth", info)


def _simulation_info(plan: SimulationPlan, exposure: float, km: float) -> dict:
    return {
        "scene": plan.scene.name, "seed": plan.seed, "size": plan.scene.shape[0],
        "path_density_requested": plan.path_density,
        "path_density": plan.trajectory.path_density(plan.plane),
        "sampling_ratio": km, "lattice": list(plan.lattice.shape),
        "delta_rs": list(plan.lattice.deltas), "exposure": exposure,
        "tracker_reports": len(plan.tracker.t), "tracker_noise": TRACKER_NOISE,
        "noise": {"read": READ_NOISE, "shot": SHOT_NOISE},
    }


def video_frames(plan: SimulationPlan, *, exposure: float) -> Iterator[np.ndarray]:
    """The video's frames, ``(H, W, 3)`` sRGB uint8, rendered at the true light positions.

    Deterministic for a plan (the sensor noise is seeded by ``plan.seed``).
    """
    rng = np.random.default_rng([plan.seed, 303])
    for frame in iter_frames(plan.scene, plan.frame_lights()):
        yield _sensor(frame.astype(np.float64) * exposure, rng)


def write_truth(path: Path, plan: SimulationPlan, truth_rgb: np.ndarray, *, exposure: float,
                sampling_ratio: float) -> None:
    """Write the ground-truth LTM store (``ltm`` luminance and ``ltm_rgb``) atomically."""
    h, w, nr, ns, _ = truth_rgb.shape
    with new_store(path, overwrite=True) as group:
        write_coord(group, Y, np.arange(h))
        write_coord(group, X, np.arange(w))
        write_coord(group, R, plan.lattice.centres(0), units=plan.plane.unit)
        write_coord(group, S, plan.lattice.centres(1), units=plan.plane.unit)
        write_coord(group, COLOR, np.array(COLOR_CHANNELS, dtype=np.dtypes.StringDType()))
        lum = create_variable(group, LTM, (Y, X, R, S), (h, w, nr, ns),
                              chunks=(min(h, 64), min(w, 64), nr, ns), attrs=TRUTH_UNITS)
        lum[...] = truth_rgb @ LUMA.astype(np.float32)
        rgb = create_variable(group, LTM_RGB, (Y, X, R, S, COLOR), truth_rgb.shape,
                              chunks=(min(h, 32), min(w, 32), nr, ns, 3), attrs=TRUTH_UNITS)
        rgb[...] = truth_rgb
        _complete_truth(group, plan, exposure, sampling_ratio)
