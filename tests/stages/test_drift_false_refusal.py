"""No false refusals (issue 63 item 6): a drift-free capture is never refused as drifting.

The simulator's own captures (no drift) over a spread of scenes, sizes, path lengths and seeds
go through ingest's first pass and its drift rule (:func:`ltmstore.stages.phone._drift_decision`);
the same frames with a real drift (an exposure wave, the simulator's auto exposure: applied to
each frame's block means, which a gain multiplies exactly) are still refused. The icon is the
hard case: its gold's highlights are sharper in the light's position than the drift model's
grid, so its misfit and its drift estimate's noise are the largest (before issue 63 most of its
captures were refused, among them ``ltm simulate --scene icon --size 32 --seed 1``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ltmstore.core.errors import LtmError

# (scene, size, seed, path density): 6-17 s captures, the icon at 16-32 px the most
SPREAD = [("icon", 16, 0, 10.0), ("icon", 16, 1, 27.0), ("icon", 24, 0, 27.0),
          ("icon", 24, 3, 14.0), ("icon", 32, 1, 14.0), ("canvas", 16, 3, 27.0),
          ("relief", 24, 2, 10.0)]


def _first_pass(folder):
    """Block means, times and the light of every frame, as ingest's first pass has them."""
    from ltmstore.capture.acquisition import load_acquisition, load_poses
    from ltmstore.core.transfer import transfer_lut
    from ltmstore.stages.frames import lights_at
    from ltmstore.stages.phone import scan_video

    acq = load_acquisition(folder)
    scan = scan_video(acq.video, transfer_lut(acq.transfer, bits=8), allow_dropped=False)
    t = scan.index / scan.fps
    lights = lights_at(t, poses=load_poses(acq.poses), plane=acq.plane,
                       z_tolerance=0.05 * acq.plane.height, time_offset=acq.time_offset,
                       view_plane=None)
    return scan, t, lights, acq.plane


@pytest.fixture(scope="module")
def spread(tmp_path_factory):
    from ltmstore.synthetic.simulate import simulate_acquisition

    root = tmp_path_factory.mktemp("spread")
    out = {}
    for scene, size, seed, density in SPREAD:
        folder = root / f"{scene}{size}_{seed}_{density:g}"
        simulate_acquisition(folder, scene=scene, size=size, seed=seed, path_density=density,
                             truth=False, progress=False)
        out[scene, size, seed, density] = _first_pass(folder)
    return out


def _decide(scan, t, lights, plane, gains=None):
    from ltmstore.capture.drift import estimate_drift
    from ltmstore.stages.phone import _drift_decision

    blocks = scan.blocks if gains is None else scan.blocks * gains[:, None, :]
    estimate = estimate_drift(blocks, t, lights.r, lights.s, lights.z, lights.valid, plane)
    return _drift_decision(estimate)


def test_drift_free_captures_are_never_refused(spread):
    refused, records = [], []
    for key, (scan, t, lights, plane) in spread.items():
        try:
            gains, record = _decide(scan, t, lights, plane)
        except LtmError as exc:
            refused.append((key, str(exc)))
            continue
        assert gains is None and not record["corrected"], (key, record)
        records.append(record)
    assert refused == [], refused  # the false-refusal rate: 0 of 7 (5 of 7 before issue 63)
    amplitude = np.array([r["rms_log_gain"] for r in records])
    ratio = amplitude / np.array([r["stderr_log_gain"] for r in records])
    # measured: RMS log gain at most 0.025 (icon, 16 px), at most 0.97 standard errors (canvas)
    assert amplitude.max() < 0.035 and ratio.max() < 1.2, (amplitude, ratio)
    assert max(r["residual"] for r in records) < 0.045  # measured 0.039 (icon, 16 px)


def _wave(n: int, fps: float, amplitude: float) -> np.ndarray:
    log_gain = amplitude * np.sin(2 * np.pi * np.arange(n) / fps / 7.0)
    return np.exp(log_gain)[:, None] * np.ones(3)


def _auto_exposure(scan) -> np.ndarray:
    """The simulator's auto exposure metering every frame's luminance after a dark lead."""
    from ltmstore.core.dims import LUMA
    from ltmstore.synthetic.phone_effects import AutoExposure

    lum = (scan.blocks @ LUMA).mean(axis=1)
    ae = AutoExposure(scan.fps)
    series = np.concatenate([np.full(30, 0.2 * np.median(lum)), lum])
    return np.array([ae.step(v) for v in series])[30:, None] * np.ones(3)


@pytest.mark.parametrize("key", [("icon", 16, 1, 27.0), ("icon", 24, 3, 14.0),
                                 ("canvas", 16, 3, 27.0)])
def test_real_drift_is_still_refused_or_corrected(spread, key):
    """A 25 % exposure wave and the simulator's auto exposure on the same frames: corrected
    where the path measures them (the canvas's 17 s scribble: the wave), refused otherwise."""
    scan, t, lights, plane = spread[key]
    errors = {}
    for name, gains in (("wave", _wave(len(t), scan.fps, 0.25)), ("ae", _auto_exposure(scan))):
        try:
            corrected, record = _decide(scan, t, lights, plane, gains)
        except LtmError as exc:
            assert "AE/AWB lock" in str(exc)
            continue
        assert corrected is not None and record["corrected"], (key, name, record)
        lit = np.asarray(lights.valid)
        err = np.log(corrected[lit] / gains[lit])
        errors[name] = float(np.sqrt(np.mean((err - err.mean()) ** 2)))
    # the canvas's wave: measured 0.018 off the true log gain (RMS over the lit frames)
    assert errors.get("wave", 0.0) < 0.025, errors


def test_the_issues_capture_ingests(tmp_path):
    """``ltm simulate acq --scene icon --size 32 --seed 1`` then ``ltm ingest``: refused before
    issue 63 (RMS 1.2 %, 'cannot be measured to better than 5.3 %'), ingested unchanged now."""
    from pipeline_helpers import run_ltm

    sim = run_ltm("simulate", tmp_path / "acq", "--scene", "icon", "--size", "32", "--seed", "1")
    assert sim.returncode == 0, sim.stderr
    done = run_ltm("ingest", tmp_path / "acq", tmp_path / "s.zarr")
    assert done.returncode == 0, done.stderr
    drift = json.loads(done.stdout)["drift"]
    assert drift["judged"] and not drift["corrected"], drift
    # measured: RMS 0.012 against a threshold of 0.111 (four standard errors)
    assert drift["rms_log_gain"] < 0.02 < drift["threshold"], drift
