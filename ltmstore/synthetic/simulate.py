"""Simulated handheld acquisitions with ground truth: ``ltm simulate``.

A run is planned first (:func:`plan_simulation`: scene, plane, lattice, true trajectory, tracker
record, video timing; all seeded), then executed (:func:`simulate_acquisition`), which writes an
acquisition folder (ARCHITECTURE.md section 3.1) plus the ground truth ``truth.zarr``::

    OUT/acquisition.json   transfer "srgb", plus {"simulation": {...}}
    OUT/video.mkv          FFV1 lossless (video.mp4, mp4v, with ``lossy``), 30 fps, sRGB uint8
    OUT/poses.csv          the tracker's irregular, noisy reports; t = 0 at the first frame
    OUT/truth.zarr         ltm (y, x, r, s) linear luminance and ltm_rgb (y, x, r, s, color)

Frames are rendered at the *true* light position (excursions out of the plane included), scaled
by one exposure constant, given mild sensor noise, clipped and sRGB-encoded. The truth is in the
same linear units as the frames before encoding (rendered radiance x exposure), i.e. what an
ingest that inverts the sRGB transfer recovers. ``acquisition.json`` is written last, so an
interrupted run never looks like a complete acquisition folder.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from ltmstore.dims import COLOR, COLOR_CHANNELS, LTM, LTM_RGB, LUMA, Lattice, Plane, R, S, X, Y
from ltmstore.errors import LtmError
from ltmstore.store import complete_stage, create_variable, new_store, write_coord
from ltmstore.synthetic import writer
from ltmstore.synthetic.render import iter_frames, render_ltm
from ltmstore.synthetic.scenes import Scene, make_scene
from ltmstore.synthetic.trajectory import (
    Trajectory,
    check_path_density,
    sampling_ratio,
    scribble,
    track,
)
from ltmstore.transfer import encode

PLANE = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)  # a 40 cm square, 30 cm above
DEFAULT_PATH_DENSITY = 27.0  # 1/m: K/M about 0.29 on a 32 x 32 lattice (the paper's ratio)
EXPOSURE_PEAK = 0.9  # the brightest ground-truth value maps to this (linear)
READ_NOISE = 0.002  # sensor noise: sigma^2 = READ_NOISE^2 + SHOT_NOISE * value (linear units)
SHOT_NOISE = 2.5e-5  # ... so sigma is about 0.5 % of full scale at the top of the range
VIDEO_MARGIN = 0.1  # s: the video starts this long after the hand and stops this long before
TRACKER_NOISE = 0.0003  # m: standard deviation of the tracker noise (the paper: 0.31 mm RMS)
TRACKER_SKEW = 0.1  # s: the tracker record starts/stops up to this much before/after the video
OUTPUTS = ("acquisition.json", "poses.csv", "video.mkv", "video.mp4", "truth.zarr")


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

    @property
    def frame_times(self) -> np.ndarray:
        """Times of the video frames on the hand's clock."""
        return self.video_start + np.arange(self.frame_count) / writer.FPS

    def frame_lights(self) -> np.ndarray:
        """True light positions ``(frame_count, 3)`` at the frame times."""
        return np.column_stack(self.trajectory.at(self.frame_times)[:3])


def plan_simulation(*, scene: str = "canvas", path_density: float = DEFAULT_PATH_DENSITY,
                    seed: int = 0, size: int = 128, delta_rs: float | None = None,
                    lattice: tuple[int, int] = (32, 32), plane: Plane = PLANE) -> SimulationPlan:
    """Plan a simulated acquisition (cheap: no rendering). See :func:`simulate_acquisition`."""
    density = check_path_density(path_density)
    the_scene = make_scene(scene, size=size, seed=seed)
    grid = _lattice(plane, delta_rs, lattice)
    path = scribble(plane, path_density=density, seed=seed)
    video_start = min(VIDEO_MARGIN, path.duration / 4)
    frame_count = int((path.duration - 2 * video_start) * writer.FPS) + 1
    skew = np.random.default_rng([seed, 404]).uniform(-TRACKER_SKEW, TRACKER_SKEW, 2)
    video_stop = video_start + (frame_count - 1) / writer.FPS
    tracker = track(path, seed=seed, noise=TRACKER_NOISE, start=video_start + skew[0],
                    stop=video_stop + skew[1])
    return SimulationPlan(scene=the_scene, plane=plane, lattice=grid, trajectory=path,
                          tracker=tracker, video_start=video_start, frame_count=frame_count,
                          seed=seed, path_density=density)


def _lattice(plane: Plane, delta_rs: float | None, shape: tuple[int, int]) -> Lattice:
    if delta_rs is not None:
        return Lattice.from_delta(plane, delta_rs)
    if len(tuple(shape)) != 2:
        raise LtmError(f"lattice {shape!r} must be two cell counts (R, S), e.g. (32, 32)")
    return Lattice.from_plane(plane, shape)


def simulate_acquisition(out: str | os.PathLike, *, scene: str = "canvas",
                         path_density: float = DEFAULT_PATH_DENSITY, seed: int = 0,
                         lossy: bool = False, size: int = 128, delta_rs: float | None = None,
                         lattice: tuple[int, int] = (32, 32), plane: Plane = PLANE,
                         truth: bool = True, overwrite: bool = False,
                         progress: bool = True) -> dict:
    """Simulate a handheld acquisition of a synthetic painting, with its ground truth.

    Parameters
    ----------
    out : path
        Output folder (created; must be empty unless ``overwrite``).
    scene : {"canvas", "icon", "relief"}
    path_density : float
        Trajectory length per unit plane area, 1/m (default 27: K/M about 0.29 on 32 x 32).
    seed : int
    lossy : bool
        Write ``video.mp4`` (mp4v) instead of lossless ``video.mkv`` (FFV1).
    size : int
        Image side in pixels.
    delta_rs : float, optional
        Ground-truth lattice cell size; overrides ``lattice``.
    lattice : (int, int)
        Ground-truth lattice ``(R, S)`` over the plane.
    plane : Plane
        The illumination plane (default: a 40 cm square 30 cm above the object).
    truth : bool
        Write ``truth.zarr``. Without it (large benchmarks) the exposure comes from a lattice
        of a quarter the resolution, and the LTM is never held in memory.
    overwrite : bool
        Replace the outputs of an earlier simulation in ``out``.
    progress : bool
        Show progress bars.

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
    plan = plan_simulation(scene=scene, path_density=path_density, seed=seed, size=size,
                           delta_rs=delta_rs, lattice=lattice, plane=plane)
    folder = _prepare_folder(Path(out), overwrite=overwrite)
    try:
        return _execute(plan, folder, lossy=lossy, truth=truth, progress=progress)
    except OSError as exc:
        raise LtmError(f"cannot write simulation into {str(folder)!r}: {exc.strerror or exc}") \
            from exc


def _execute(plan: SimulationPlan, folder: Path, *, lossy: bool, truth: bool,
             progress: bool) -> dict:
    km = sampling_ratio(*plan.frame_lights()[:, :2].T, plan.lattice)
    if truth:
        ltm = render_ltm(plan.scene, plan.lattice, plan.plane.height, progress=progress)
        exposure = EXPOSURE_PEAK / float(ltm.max())
        ltm *= np.float32(exposure)
        write_truth(folder / "truth.zarr", plan, ltm, exposure=exposure, sampling_ratio=km)
        del ltm
    else:
        coarse = Lattice.from_plane(plan.plane, [max(1, n // 4) for n in plan.lattice.shape])
        exposure = EXPOSURE_PEAK / float(render_ltm(plan.scene, coarse, plan.plane.height).max())
    video = folder / writer.video_name(lossy)
    frames = tqdm(video_frames(plan, exposure=exposure), total=plan.frame_count,
                  disable=not progress, desc="video", unit="frame")
    n = writer.write_video(video, frames, fps=writer.FPS)
    tk = plan.tracker
    writer.write_poses(folder / "poses.csv", tk.t - plan.video_start, tk.r, tk.s, tk.z)
    info = _simulation_info(plan, exposure, km)
    writer.write_acquisition_json(folder, video=video.name, plane=plan.plane, transfer="srgb",
                                  extra={"simulation": info})
    paths = {"folder": folder, "acquisition": folder / "acquisition.json", "video": video,
             "poses": folder / "poses.csv"}
    if truth:
        paths["truth"] = folder / "truth.zarr"
    return {**info, "frames": n, "duration_s": n / writer.FPS,
            "paths": {k: str(v) for k, v in paths.items()}}


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


def _prepare_folder(folder: Path, *, overwrite: bool) -> Path:
    """Create ``folder`` or check that it may be written; with ``overwrite`` clear old outputs."""
    if folder.exists() and not folder.is_dir():
        raise LtmError(f"output {str(folder)!r} exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()):
        if not overwrite:
            raise LtmError(f"output folder {str(folder)!r} is not empty; pass --overwrite to "
                           "replace an earlier simulation there")
        for name in OUTPUTS:
            target = folder / name
            if target.is_dir():
                shutil.rmtree(target)
            elif target.exists():
                target.unlink()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LtmError(f"cannot create output folder {str(folder)!r}: {exc.strerror or exc}") \
            from exc
    if not os.access(folder, os.W_OK):
        raise LtmError(f"output folder {str(folder)!r} is not writable")
    return folder


def video_frames(plan: SimulationPlan, *, exposure: float) -> Iterator[np.ndarray]:
    """The video's frames, ``(H, W, 3)`` sRGB uint8, rendered at the true light positions.

    Deterministic for a plan (the sensor noise is seeded by ``plan.seed``).
    """
    rng = np.random.default_rng([plan.seed, 303])
    for frame in iter_frames(plan.scene, plan.frame_lights()):
        linear = frame.astype(np.float64) * exposure
        sigma = np.sqrt(READ_NOISE**2 + SHOT_NOISE * np.clip(linear, 0.0, None))
        noisy = linear + sigma * rng.standard_normal(linear.shape)
        yield encode(noisy, "srgb")


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
        units = {"units": "linear frame value (rendered radiance x exposure, before sRGB)"}
        lum = create_variable(group, LTM, (Y, X, R, S), (h, w, nr, ns),
                              chunks=(min(h, 64), min(w, 64), nr, ns), attrs=units)
        lum[...] = truth_rgb @ LUMA.astype(np.float32)
        rgb = create_variable(group, LTM_RGB, (Y, X, R, S, COLOR), truth_rgb.shape,
                              chunks=(min(h, 32), min(w, 32), nr, ns, 3), attrs=units)
        rgb[...] = truth_rgb
        info = {"plane": plan.plane.to_json(), "lattice": plan.lattice.to_json(),
                "exposure": exposure, "scene": plan.scene.name, "seed": plan.seed,
                "path_density": plan.trajectory.path_density(plan.plane),
                "sampling_ratio": sampling_ratio}
        group.attrs.update(info)
        complete_stage(group, "truth", info)
