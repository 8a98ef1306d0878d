"""Issue 30, item 5: the pages of ``ltm capture`` in a real browser.

Two headless Chromiums with fake cameras play a simulated raw capture (phone A's video of the
board, camera B's video; :mod:`capture_pages_helpers`) into phone A's and camera B's pages
served by the real ``ltm capture`` process. The path phone A's page draws must be the
simulation's true LED path (within the tracker's error), the coverage it shows what
``ltm reconstruct`` counts on the finished folder, and that folder must go through
``ltm sync``, ``ltm ingest`` and ``ltm reconstruct``. Skipped without Chromium exactly as the
viewer's browser tests (``browser.chromium_path``; a failure in CI).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from browser import chromium_path
from capture_pages_helpers import A_EVERY, LATTICE, run_capture, simulate
from pipeline_helpers import run_ltm

from ltmstore.capture.acquisition import load_acquisition, load_poses
from ltmstore.capture.live import LIVE_MAX_GAP_S, path_samples
from ltmstore.core.binning import bin_positions
from ltmstore.core.dims import Lattice, Plane
from ltmstore.stages.phone import LOCK_ADVICE


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    """One capture through both pages; what they hold at the end, the folder, the truth."""
    chromium_path()  # skip (or fail in CI) before simulating anything
    work = tmp_path_factory.mktemp("pages")
    sim = work / "sim"
    info = simulate(sim)
    folder = work / "acq"
    return {**run_capture(sim, folder, work), "folder": folder, "sim": sim, "info": info}


@pytest.fixture(scope="module")
def reconstructed(captured, tmp_path_factory):
    """``ltm sync``, ``ltm ingest``, ``ltm reconstruct`` on the finished folder, as printed."""
    folder = captured["folder"]
    store = tmp_path_factory.mktemp("store") / "store.zarr"
    steps = {"sync": run_ltm("sync", folder),
             "ingest": run_ltm("ingest", folder, store),
             "reconstruct": run_ltm("reconstruct", store, "--lattice",
                                    "x".join(map(str, LATTICE)), "--method", "cubic")}
    return steps, store


def true_frames(sim):
    """The true LED positions of the frames phone A's fake camera plays, on phone A's clock."""
    true = load_poses(sim / "truth" / "poses_true.csv")
    keep = slice(None, None, A_EVERY)
    return np.column_stack([true.t[keep], true.r[keep], true.s[keep], true.z[keep]])


def best_shift(path: np.ndarray, truth: np.ndarray) -> float:
    """The clock shift (page time + shift = truth time) that lays the drawn path on the true
    one: least RMS distance to the true path interpolated at the shifted times."""
    ends = truth[0, 0] - path[0, 0], truth[-1, 0] - path[-1, 0]
    # the shifts that keep the path within the truth; a path a little longer than the truth
    # (phone A's recording starts after its first live frame) is searched around its ends
    shifts = np.arange(min(ends) - 0.25, max(ends) + 0.25, 0.002)
    rms = [np.mean((np.interp(path[:, 0] + c, truth[:, 0], truth[:, 1]) - path[:, 1]) ** 2
                   + (np.interp(path[:, 0] + c, truth[:, 0], truth[:, 2]) - path[:, 2]) ** 2)
           for c in shifts]
    return float(shifts[int(np.argmin(rms))])


def test_both_pages_finish_and_camera_b_loses_nothing(captured):
    a, b = captured["a"], captured["b"]
    assert a["state"] in ("finished", "closed") and b["state"] in ("finished", "closed"), \
        (a["error"], b["error"], captured["messages"])
    assert "finished" in (a["state"], b["state"])  # the second page to stop ended the capture
    assert captured["returncode"] == 0  # the server ends itself once the capture is finished
    assert a["resolution"] == [640, 360] and a["torch"] == "manual"  # no torch on a fake camera
    # camera B was offline 2.5 s: pieces waited and were retried, and all arrived
    assert b["retries"] >= 1
    assert b["recorded"] == b["acked"] >= 5 and b["bytes"] == b["bytesAcked"] > 0
    assert b["queued"] == 0 and b["mime"].startswith("video/webm")
    assert b["finish"]["frames"] > 0.8 * 30 * b["seconds"]  # the whole recording joined
    # the fake camera offers no manual exposure: the page says so plainly
    assert b["locks"]["exposure"] == "auto"
    assert "cannot lock the exposure" in captured["exposure"]


def test_drawn_path_is_the_true_path(captured):
    """Every point phone A's page drew is a frame's true LED position within the tracker's
    error, in order, at its capture time (after the best clock shift): measured RMS 0.23 mm,
    largest 0.58 mm, time lags within 5 ms idle and 9 ms beside eight busy processes, of the
    67 ms frame interval. The page draws each frame in its own video-frame callback, timed by
    the camera's capture time: it drew it after that callback, and a frame that arrived in
    between went out with its predecessor's time (a CI run: one point of 20 lagged 66 ms).
    Drawn in the callback, Chromium still paired one point of 35 with its neighbour's time
    (-64.5 ms) in a suite run of 2026-12-06: the callback does not guarantee that the frame
    drawn is the one its metadata describes, so a point may lag one frame interval, no more,
    and at most one in twenty."""
    path = np.array(captured["a"]["path"])
    truth = true_frames(captured["sim"])
    # How many points the page draws in its 5 s depends on the machine's load (one frame in
    # flight at a time): 11 in a clean-clone suite run beside the other xdist worker's tests.
    assert len(path) >= 8 and captured["a"]["placed"] == captured["a"]["answered"]
    assert np.all(np.diff(path[:, 0]) > 0)
    shift = best_shift(path, truth)
    errors, lags = [], []
    for t, *led in path:
        near = np.flatnonzero(np.abs(truth[:, 0] - (t + shift)) < 0.1)
        distance = np.linalg.norm(truth[near, 1:] - led, axis=1)
        errors.append(distance.min())
        lags.append(truth[near[np.argmin(distance)], 0] - (t + shift))
    errors_mm = 1e3 * np.array(errors)
    assert np.sqrt(np.mean(errors_mm**2)) < 0.5 and errors_mm.max() < 1.5, errors_mm
    # timed by the camera's capture time: within 9 ms beside eight busy processes (by the
    # compositor's frame time, up to 79 ms under load); a point sent with its predecessor's
    # time lags a whole frame interval, 67 ms (the fake camera's 15 frames per s). Measured from
    # their median: the shift is fitted to the positions, and a clean-clone suite run's lags
    # all lay 12-34 ms (median 25) after it, the fake camera's content behind its timestamps
    lags = np.abs(np.array(lags) - np.median(lags))
    neighbours = np.abs(lags - 1 / 15) < 0.015
    assert np.all((lags < 0.03) | neighbours), lags
    assert neighbours.sum() <= max(1, len(lags) // 20), lags
    assert captured["a"]["overtaken"] <= 0.1 * captured["a"]["sent"], captured["a"]


def test_folder_holds_phone_as_whole_video_tracked(captured):
    """poses.csv is phone A's recorded video tracked whole: every frame of it (the live frames
    were 3-5 per s here), and every point drawn is one of its positions (the same camera frame
    sent live as JPEG and recorded as VP8, after the clock shift between the page's clock and
    the video's): measured RMS 0.14 mm, largest 0.27 mm (0.49 beside three busy processes)."""
    a = captured["a"]
    path = np.array(a["path"])
    acq = load_acquisition(captured["folder"])
    poses = load_poses(acq.poses)
    finish = a["finish"]
    assert finish["video"] == "phone_a.webm" and finish["fps"] == 15  # the fake camera's rate
    assert (captured["folder"] / "phone_a.webm").is_file()
    assert a["recording"]["recorded"] == a["recording"]["acked"] >= 4
    assert finish["placed_frames"] == len(poses) >= 0.9 * finish["frames"]
    assert len(poses) >= len(path) and np.all(np.diff(poses.t) > 0)  # live: 3-15 frames per s
    assert np.median(np.diff(poses.t)) == pytest.approx(1 / 15, abs=5e-3)  # its own times
    dense = np.column_stack([poses.t, poses.r, poses.s, poses.z])
    shift = best_shift(path, dense)
    errors_mm = []
    for t, *led in path:  # the same camera frame, sent live (JPEG) and recorded (VP8)
        near = np.abs(dense[:, 0] - (t + shift)) < 0.15
        errors_mm.append(1e3 * np.linalg.norm(dense[near, 1:] - led, axis=1).min())
    errors_mm = np.array(errors_mm)
    # under load the recorder may drop a frame the page sent live (or the tracker leave one
    # unplaced, as placed_frames allows): a point beside such a gap in the recorded video's
    # times has no frame to match (the LED moves 15 mm a frame here; a suite run beside a
    # benchmark missed one point of 35, RMS 2.5 mm), so it is counted, not scored
    times = dense[:, 0]
    at = np.clip(np.searchsorted(times, path[:, 0] + shift), 1, len(times) - 1)
    beside_gap = np.diff(times)[at - 1] > 1.5 / finish["fps"]
    assert beside_gap.sum() <= 0.1 * len(path), (beside_gap.sum(), len(path))
    scored = errors_mm[~beside_gap]
    assert np.sqrt(np.mean(scored**2)) < 0.5 and scored.max() < 1.5, errors_mm


def test_shown_coverage_is_the_servers_and_the_folders(captured):
    """The page shows the server's final coverage (phone A's whole video at camera B's frames,
    the clocks aligned as `ltm sync` aligns them); the finished folder records the same K, M;
    the count shown live was the live frames' (bridged) by the server's rule."""
    a = captured["a"]
    last = a["last"]["coverage"]
    shown, target = captured["shown"], a["config"]["target_km"]
    # JavaScript's toFixed rounds a half up, Python's format to even (45/144 = 0.3125): the
    # numbers shown are compared to their rounding, not as strings
    km, of_target = shown["km"].removeprefix("K/M ").split(" of ")
    assert abs(float(km) - last["k_over_m"]) <= 5e-4 + 1e-12 and float(of_target) == target
    assert shown["cells"] == f"{last['covered']} of {last['cells']} covered"
    snr, spread = shown["snr"].split(" dB ± ")
    assert abs(float(snr) - a["last"]["expected_snr_db"]) <= 0.05 + 1e-12
    assert abs(float(spread) - a["last"]["expected_snr_spread_db"]) <= 0.05 + 1e-12
    assert shown["frames"] == f"{a['placed']} placed of {a['answered']}"
    assert shown["warning"] is None  # all placed
    assert (shown["enough"] is not None) == a["last"]["enough"]
    # the shaded cells are those counted
    assert len(a["coveredCells"]) == last["covered"] >= 8
    assert last["cells"] == LATTICE[0] * LATTICE[1]
    # the count shown live is the drawn path's by the live rule (45 of 45 cells, run alone).
    # How near it comes to the final count depends on the load, how many live frames the page
    # got: 42 vs 39, 44 vs 38, 40 vs 52, 45 vs 38 cells, and 26 vs 47 in a CI run; no bound
    live, drawn = a["liveCoverage"], live_cells(a["path"], a["config"], captured["b"])
    assert live["covered"] == drawn.sum(), (live, drawn.sum())
    record = load_acquisition(captured["folder"]).raw["capture"]
    assert (record["K"], record["M"]) == (last["covered"], last["cells"])


def test_shown_coverage_is_what_reconstruct_counts(captured, reconstructed):
    """The folder syncs, ingests and reconstructs, and K, M, K/M phone A's page shows are those
    ``ltm reconstruct`` records."""
    steps, store = reconstructed
    if steps["ingest"].returncode == 2 and LOCK_ADVICE in steps["ingest"].stderr:
        # Chromium's fake camera plays its file on a timer that stalls on a loaded machine: its
        # frames then no longer follow the light path, and ingest rightly refuses them with its
        # advice to lock exposure: a misfit a fixed exposure cannot explain (1.7-3.9 % under load
        # in CI and here) or a drift it cannot measure (1.3 %, once, in the whole suite's run of
        # 2026-11-27). Run alone, it passed every time. Not a pass: an xfail.
        pytest.xfail("camera B's fake camera stalled under load: " + steps["ingest"].stderr)
    for name, proc in steps.items():
        assert proc.returncode == 0, (name, proc.stderr[-2000:])
    from ltmstore.core.store import stages

    record = stages(zarr.open_group(store, mode="r"))["resample"]
    last = captured["a"]["last"]["coverage"]
    assert (last["covered"], last["cells"]) == (record["K"], record["M"])
    assert last["k_over_m"] == pytest.approx(record["sampling_ratio"])


def live_cells(path: list, config: dict, b: dict) -> np.ndarray:
    """The cells the live path covers by the server's rule for live frames: the drawn LED
    positions sampled at camera B's rate, gaps up to LIVE_MAX_GAP_S bridged, within the
    plane and its height tolerance."""
    t, *led = np.array(path).T
    r, s, z = path_samples(t, np.column_stack(led), b["finish"]["fps"], LIVE_MAX_GAP_S,
                           keep_samples=True).T
    plane = Plane.from_json(config["plane"])
    valid = (np.abs(z - plane.height) <= config["height_tolerance"]) & plane.contains(r, s)
    return bin_positions(Lattice.from_plane(plane, tuple(config["lattice"])), (r, s),
                         valid).observed


def scripted_tracker(size):
    """A tracker that places the light in five cells, then holds it 5 cm too high, then loses
    it: the page's "enough" and both warnings, in a few seconds."""
    from ltmstore.capture.track import FramePose

    frames = iter(range(10**6))

    def track(gray, t):
        i = next(frames)
        if i < 5:
            return FramePose(t, np.array([-0.15 + 0.07 * i, 0.1, 0.3]), 40, 0.2, 1.0, "ok")
        if i < 10:
            return FramePose(t, np.array([0.1, 0.1, 0.35]), 40, 0.2, 1.0, "ok")
        return FramePose(t, np.full(3, np.nan), 0, np.nan, np.nan, "no_board")

    return track


def test_page_says_enough_and_warns(tmp_path):
    """'Enough' once the target K/M is reached; a warning off the plane's height, another when
    the tracker loses the light (the fake camera's own pattern; a scripted tracker)."""
    import threading

    from browser import Browser
    from capture_pages_helpers import VIEWPORT

    from ltmstore.capture.live import LiveConfig, LiveSession
    from ltmstore.capture.live_server import make_server

    plane = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)
    config = LiveConfig(plane=plane, lattice=LATTICE, target_km=4 / 144, height_tolerance=0.015)
    session = LiveSession(tmp_path / "acq", config, scripted_tracker)
    server = make_server(session)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    text = "document.getElementById('{}').hidden ? null : document.getElementById('{}').textContent"
    try:
        with Browser(*VIEWPORT, args=("--use-fake-device-for-media-stream",
                                      "--use-fake-ui-for-media-stream")) as page:
            page.goto(server.url("/a"))
            page.evaluate("document.getElementById('start').click()")
            page.wait_for("(window.ltmCapture.last || {}).warning === 'height'")
            assert page.evaluate(text.format("enough", "enough")).startswith("ENOUGH")
            assert "Off the plane's height" in page.evaluate(text.format("warning", "warning"))
            page.wait_for("(window.ltmCapture.last || {}).warning === 'lost'")
            assert page.evaluate(text.format("warning", "warning")) == \
                "Light lost: keep the board in phone A's view."
            state = page.evaluate("JSON.parse(JSON.stringify(window.ltmCapture))")
            assert state["placed"] == 10 and len(state["path"]) == 10  # the height ones drawn
            # but not counted. Covered: the 5 placed cells and those the path crosses between
            # them where ingest's rule samples it (camera B's 30 Hz grid between tracked
            # positions at most LIVE_MAX_GAP_S apart): 9 when the fake camera's frames come
            # evenly, fewer when two come within one grid step or further apart than the gap
            # (both seen under the suite's load). The page shows what the session counts.
            covered = session.binning().k
            assert 5 <= covered <= 9, covered
            page.wait_for(f"window.ltmCapture.coveredCells.length === {covered}", timeout=5)
    finally:
        server.shutdown()
        server.server_close()


def test_phone_a_opens_the_ultra_wide_lens_or_the_one_picked(tmp_path):
    """Phone A's page prefers a back ultra-wide lens (by the label the browser gives it), keeps
    a camera picked in its list for the next Start, and lists every camera once one is open
    (three fake cameras; a scripted tracker)."""
    import threading

    from browser import Browser
    from capture_pages_helpers import VIEWPORT

    from ltmstore.capture.live import LiveConfig, LiveSession
    from ltmstore.capture.live_server import make_server

    plane = Plane(r=(-0.2, 0.2), s=(-0.2, 0.2), height=0.3)
    config = LiveConfig(plane=plane, lattice=LATTICE, target_km=0.5, height_tolerance=0.015)
    server = make_server(LiveSession(tmp_path / "acq", config, scripted_tracker))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    labels = [{"deviceId": "m", "label": "Back Camera"}, {"deviceId": "f", "label": "Front Camera"},
              {"deviceId": "f5", "label": "Front Ultra Wide Camera"},
              {"deviceId": "u", "label": "Back Ultra Wide Camera"},
              {"deviceId": "a", "label": "camera2 0, facing back"}]
    try:
        with Browser(*VIEWPORT, args=("--use-fake-device-for-media-stream=device-count=3",
                                      "--use-fake-ui-for-media-stream")) as page:
            page.goto(server.url("/a"))
            pick = "ltm.preferredCamera({}, {})"
            assert page.evaluate(pick.format(json.dumps(labels), "null")) == "u"
            assert page.evaluate(pick.format(json.dumps(labels[:3] + labels[4:]), "null")) is None
            assert page.evaluate(pick.format(json.dumps(labels), '"a"')) == "a"
            assert page.evaluate(pick.format(json.dumps(labels), '"gone"')) == "u"
            page.evaluate("document.getElementById('start').click()")
            page.wait_for("window.ltmCapture.state === 'running'")
            # no label says ultra-wide: the browser's own back camera, all three listed
            assert page.evaluate("window.ltmCapture.camera") == "fake_device_0"
            options = page.evaluate("[...document.getElementById('camera').options]"
                                    ".map((o) => o.text)")
            assert options == ["fake_device_0", "fake_device_1", "fake_device_2"]
            page.evaluate("(() => { const s = document.getElementById('camera');"
                          " s.selectedIndex = 2; s.dispatchEvent(new Event('change')); })()")
            page.goto(server.url("/a"))  # the choice outlives the page
            page.wait_for("document.getElementById('camera').options.length === 3")
            assert page.evaluate("document.getElementById('camera').selectedOptions[0].text") \
                == "fake_device_2"
            page.evaluate("document.getElementById('start').click()")
            page.wait_for("window.ltmCapture.state === 'running'")
            assert page.evaluate("window.ltmCapture.camera") == "fake_device_2"
    finally:
        server.shutdown()
        server.server_close()
