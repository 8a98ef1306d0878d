"""Issue 63 item 3: camera B's lens through ``ltm calibrate``, old flags against the chosen model.

For each lens, the simulator's calibration video is written as ``ltm simulate --raw`` writes it
(:func:`ltmstore.synthetic.raw.calibration_frames` through :class:`PhoneView`, with the lens's
true radial distortion) and calibrated two ways:

``old``
    what ``ltm calibrate`` did before: :func:`cv2.calibrateCamera` with only ``CALIB_FIX_K3``,
    on the same detected views;
``new``
    the real ``ltm calibrate`` command (a subprocess), which chooses the lens model by the
    reprojection error of views left out of the fit.

Each is scored at frame level: an ideal frame (the canvas scene's albedo, linear) distorted
through the true lens as the simulator does (bilinear :func:`cv2.remap` of
:func:`~ltmstore.synthetic.phone_effects.distortion_maps`), undistorted with the calibrated
intrinsics as ``ltm ingest`` does (:class:`~ltmstore.capture.undistort.Undistorter`, bicubic),
SNR in dB against the ideal frame 24 px in from the border; the same with the true intrinsics is
the ceiling. ``map_error_px`` is the displacement between the calibrated and the true
undistortion maps over that region (content-free), and the parameter errors are against truth.

Lenses: camera B at ``--size`` (720: f = 1620 px, k1 = -0.15, the simulator's camera B and its
A4 board of 6 x 4 squares, seeds 1-3; seed 1 is the calibration video of ``simulate_raw`` with
seed 0), a wide lens (phone A's ultrawide focal, 540 px on 1280 x 720, k1 = -0.10, k2 = 0.03,
phone A's A4 calibration page), the wide lens with its principal point 20 px right and 10 px up,
and camera B again with the board's texture at a whole number of texels per square (230 instead
of the simulator's 230.5, which OpenCV draws with +-0.5 texel = +-0.1 mm corner errors): the
diagnostic of where the old flags' error comes from.

``views_sweep``: the model chosen from 10, 12, 20 and 30 views of each lens, with each
candidate's held-out RMS over the best (the rule keeps the simplest within ``+ min(0.1 px,
best)``, i.e. a ratio under 2 and a gain under 0.1 px).

Run::

    nice -n 10 python bench/calibration_frames.py      # -> bench/results/calibration_frames.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ltmstore.capture.board import (
    BoardDetector,
    board_image,
    board_spec,
    load_board,
    video_frames,
)
from ltmstore.capture.calibrate import (
    CALIB_CORNERS,
    Intrinsics,
    calibrate_views,
    load_intrinsics,
)
from ltmstore.capture.undistort import Undistorter
from ltmstore.synthetic.phone_effects import DISTORTION_B, camera_b_matrix, distortion_maps
from ltmstore.synthetic.phone_view import PhoneView, PlaneTexture
from ltmstore.synthetic.raw import (
    BOARD_B_SQUARES,
    BOARD_SQUARE_MM,
    CAMERA_B_CALIBRATION_M,
    board_texture,
    write_calibration_video,
)
from ltmstore.synthetic.scenes import scene_albedo

LTM = str(Path(sys.executable).parent / "ltm")
MARGIN = 24


@dataclass(frozen=True)
class Lens:
    """One simulated lens and the calibration video that films it."""

    name: str
    size: tuple[int, int]
    matrix: np.ndarray
    dist: tuple[float, float]
    board: str  # "b": camera B's 6 x 4 A4 board; "a": phone A's A4 page of 30 mm squares
    seed: int
    views: int = 20
    whole_texels: bool = False  # board texture at a whole number of texels per square


def lenses(size: int) -> list[Lens]:
    """The lenses measured (see the module docstring)."""
    kb = camera_b_matrix((size, size))
    wide = np.array([[540.0, 0, 639.5], [0, 540.0, 359.5], [0, 0, 1]])
    shifted = wide + np.array([[0, 0, 20.0], [0, 0, -10.0], [0, 0, 0]])
    out = [Lens(f"camera_b_{size}_seed{s}", (size, size), kb, DISTORTION_B, "b", s)
           for s in (1, 2, 3)]
    out += [Lens(f"wide_seed{s}", (1280, 720), wide, (-0.10, 0.03), "a", s) for s in (0, 1)]
    out.append(Lens("wide_off_centre", (1280, 720), shifted, (-0.10, 0.03), "a", 0))
    out.append(Lens(f"camera_b_{size}_seed1_whole_texel_board", (size, size), kb, DISTORTION_B,
                    "b", 1, whole_texels=True))
    return out


def write_video(lens: Lens, folder: Path) -> Path:
    """The calibration video and the board spec JSON (as ``simulate_raw`` writes them)."""
    if lens.board == "b":
        spec, height, spread, aim = board_spec("A4", squares=BOARD_B_SQUARES), \
            CAMERA_B_CALIBRATION_M, 0.35, 0.03
    else:
        spec, height, spread, aim = board_spec("A4", square_mm=BOARD_SQUARE_MM), \
            (0.18, 0.3), 0.06, None
    texture = whole_texel_texture(spec) if lens.whole_texels else board_texture(spec)
    view = PhoneView(lens.matrix, lens.dist, lens.size, texture, None, distance=sum(height) / 2)
    (folder / "board.json").write_text(json.dumps(spec.to_json(), indent=2) + "\n")
    return write_calibration_video(folder / "calibration.mkv", view, lens.seed, lens.views,
                                   height=height, spread=spread, aim=aim)


def whole_texel_texture(spec) -> PlaneTexture:
    """:func:`board_texture` at the resolution nearest 5000 px/m with a whole number of texels
    per square (the diagnostic variant)."""
    ppm = round(spec.square_length * 5000.0) / spec.square_length
    tex = board_image(spec, ppm).astype(np.float32) / 255
    w, h = spec.size
    return PlaneTexture(cv2.GaussianBlur(tex, (0, 0), 0.7), None, -w / 2, h / 2, ppm, 0.45)


def old_flags(video: Path, board: Path, size: tuple[int, int]) -> Intrinsics:
    """The calibration before item 3: every view with enough corners, only ``CALIB_FIX_K3``."""
    detector = BoardDetector(load_board(board))
    obj, img = [], []
    for _i, _t, gray in video_frames(video):
        o, p, _ = detector.detect(gray)
        if len(o) >= CALIB_CORNERS:
            obj.append(o)
            img.append(p)
    rms, matrix, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None,
                                                  flags=cv2.CALIB_FIX_K3)
    return Intrinsics(size, matrix, dist.ravel(), float(rms))


def ltm_calibrate(video: Path, board: Path) -> tuple[Intrinsics, dict, str, float]:
    """``ltm calibrate`` as a user runs it: intrinsics, the file's report, its summary line."""
    out = video.parent / "intrinsics.json"
    start = time.perf_counter()
    proc = subprocess.run([LTM, "calibrate", str(video), "--board", str(board), "-o", str(out),
                           "--overwrite"], capture_output=True, text=True, check=True)
    seconds = time.perf_counter() - start
    report = json.loads(out.read_text())["calibration"]
    return load_intrinsics(out), report, proc.stdout.strip(), seconds


class FrameCheck:
    """The ideal frame through the true lens, and how a calibration undoes it."""

    def __init__(self, lens: Lens) -> None:
        w, h = lens.size
        self.ideal = scene_albedo("canvas", max(w, h))[:h, :w].astype(np.float32)
        self.true_maps = undistort_maps(self.truth(lens))
        self.distorted = cv2.remap(self.ideal, *distortion_maps(lens.matrix, lens.dist,
                                                                lens.size),
                                   cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    @staticmethod
    def truth(lens: Lens) -> Intrinsics:
        return Intrinsics(lens.size, lens.matrix, np.array([*lens.dist, 0, 0, 0]))

    def score(self, intr: Intrinsics) -> dict:
        """Frame SNR (dB) and the undistortion map's displacement from the true one (px)."""
        undo = Undistorter(intr, "calibration")
        m = np.s_[MARGIN:-MARGIN, MARGIN:-MARGIN]
        err = self.ideal[m] - undo.apply(self.distorted)[m]
        (ux, uy), (tx, ty) = undistort_maps(intr), self.true_maps
        shift = np.hypot(ux[m] - tx[m], uy[m] - ty[m])
        return {"frame_snr_db": round(float(10 * np.log10(np.sum(self.ideal[m] ** 2)
                                                         / np.sum(err ** 2))), 2),
                "map_error_px": {"max": round(float(shift.max()), 3),
                                 "rms": round(float(np.sqrt(np.mean(shift ** 2))), 3)}}


def undistort_maps(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Where each undistorted pixel is read from, as :class:`Undistorter` computes it."""
    return cv2.initUndistortRectifyMap(intr.matrix, intr.distortion, None, intr.matrix,
                                       intr.image_size, cv2.CV_32FC1)


def parameters(intr: Intrinsics, lens: Lens) -> dict:
    """The calibration's parameters and their errors against the truth."""
    k, d = np.asarray(intr.matrix), np.asarray(intr.distortion, np.float64)
    true = {"fx": lens.matrix[0, 0], "fy": lens.matrix[1, 1], "cx": lens.matrix[0, 2],
            "cy": lens.matrix[1, 2], "k1": lens.dist[0], "k2": lens.dist[1], "p1": 0.0,
            "p2": 0.0}
    got = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "k1": d[0], "k2": d[1],
           "p1": d[2], "p2": d[3]}
    return {"values": {n: round(float(v), 5) for n, v in got.items()},
            "errors": {n: round(float(got[n] - true[n]), 5) for n in true},
            "reprojection_rms_px": round(float(intr.rms_px), 4)}


def measure(lens: Lens, work: Path) -> dict:
    """One lens: video, both calibrations, their frame checks and parameter errors."""
    folder = work / lens.name
    folder.mkdir(parents=True, exist_ok=True)
    video = write_video(lens, folder)
    check = FrameCheck(lens)
    old = old_flags(video, folder / "board.json", lens.size)
    new, report, line, seconds = ltm_calibrate(video, folder / "board.json")
    return {"lens": lens.name, "image_size": list(lens.size),
            "true": {"matrix": lens.matrix.tolist(), "k1_k2": list(lens.dist)},
            "views": lens.views, "seed": lens.seed, "whole_texel_board": lens.whole_texels,
            "true_intrinsics": check.score(FrameCheck.truth(lens)),
            "old": {**check.score(old), **parameters(old, lens)},
            "new": {**check.score(new), **parameters(new, lens),
                    "lens_model": report["lens_model"],
                    "heldout_rms_px": report["heldout_rms_px"],
                    "lens_models": report["lens_models"], "summary": line,
                    "ltm_calibrate_s": round(seconds, 1)}}


def sweep(lens: Lens, work: Path, counts: tuple[int, ...] = (10, 12, 20, 30)) -> list[dict]:
    """The model chosen (:func:`calibrate_views`, as ``ltm calibrate``) from ``counts`` views of
    ``lens``: how close each choice is to the rule's limits."""
    rows = []
    for n in counts:
        lens_n = replace(lens, views=n)
        folder = work / f"{lens.name}_{n}"
        folder.mkdir(parents=True, exist_ok=True)
        video = write_video(lens_n, folder)
        detector = BoardDetector(load_board(folder / "board.json"))
        views = [(o, p) for o, p, _ in (detector.detect(g) for _i, _t, g in video_frames(video))
                 if len(o) >= CALIB_CORNERS]
        intr, report = calibrate_views(views, lens.size)
        scores = {m: v["heldout_rms_px"] for m, v in report["lens_models"].items()}
        best = min(scores.values())
        rows.append({"lens": lens.name, "views": n, "lens_model": report["lens_model"],
                     **FrameCheck(lens).score(intr), "heldout_rms_px": scores,
                     "ratio_to_best": {m: round(v / best, 3) for m, v in scores.items()}})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=int, default=720, help="camera B side, pixels")
    parser.add_argument("--out", default="bench/results/calibration_frames.json")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for lens in lenses(args.size):
            rows.append(measure(lens, Path(tmp)))
            r = rows[-1]
            print(f"{r['lens']}: true {r['true_intrinsics']['frame_snr_db']} dB, old "
                  f"{r['old']['frame_snr_db']} dB, new {r['new']['frame_snr_db']} dB "
                  f"({r['new']['lens_model']})", flush=True)
        views = [row for lens in lenses(args.size) for row in sweep(lens, Path(tmp))]
    result = {"command": "nice -n 10 python bench/calibration_frames.py", "rows": rows,
              "views_sweep": views, "opencv": cv2.__version__}
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
