"""Video + poses -> store: decoding, linearisation, poses, chroma, rejections and bad inputs."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest
import xarray as xr
import zarr
from ingest_helpers import (
    EXPECTED,
    GAINS,
    PLANE,
    H,
    N,
    W,
    expected_chroma,
    expected_luminance,
    frame_times,
    make_acquisition,
    r_of,
    s_of,
    tree_hashes,
)

from ltmstore.capture.acquisition import Poses
from ltmstore.capture.video import transfer_lut
from ltmstore.core.errors import LtmError
from ltmstore.core.store import open_group, open_store, stages
from ltmstore.stages.frames import MAX_POSE_GAP_S, FrameSink, chroma_decision, lights_at
from ltmstore.stages.ingest import Z_TOLERANCE_FRACTION, ingest

CHUNK = 16  # does not divide N: the last block is partial


@pytest.fixture(scope="module")
def acq_dir(tmp_path_factory):
    return make_acquisition(tmp_path_factory.mktemp("acq") / "acq")


@pytest.fixture(scope="module")
def ingested(acq_dir, tmp_path_factory):
    """(store path, report, input hashes before) of the FFV1 acquisition."""
    before = tree_hashes(acq_dir)
    store = tmp_path_factory.mktemp("store") / "store.zarr"
    report = ingest(acq_dir, store, progress=False, chunk_frames=CHUNK)
    return store, report, before


@pytest.fixture(scope="module")
def ds(ingested):
    return xr.open_zarr(ingested[0], consolidated=False).load()


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_transfer_lut():
    srgb = transfer_lut("srgb")
    np.testing.assert_allclose(srgb[[0, 10, 128, 255]],
                               [0.0, 10 / 255 / 12.92, ((128 / 255 + 0.055) / 1.055) ** 2.4, 1.0],
                               rtol=1e-6)
    assert np.all(np.diff(srgb) > 0)
    np.testing.assert_allclose(transfer_lut("linear"), np.arange(256) / 255, rtol=1e-6)
    with pytest.raises(LtmError, match="transfer 'gamma' is unknown"):
        transfer_lut("gamma")


def test_frame_sink_streams_by_block(tmp_path):
    """Frames reach the store one block of ``chunk_frames`` at a time, not all at the end."""
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w", zarr_format=3)
    sink = FrameSink(group, transfer="linear", chunk_frames=2)
    frame = np.full((3, 4, 3), 51, np.uint8)
    sizes = []
    for i in range(5):
        sink.add(frame, i != 1, source=f"frame {i}")
        sizes.append(group["frames"].shape[0])
    assert sizes == [0, 2, 2, 4, 4]
    with pytest.raises(LtmError, match=r"frame 5 is 5x3 pixels; expected 4x3"):
        sink.add(np.zeros((3, 5, 3), np.uint8), True, source="frame 5")
    sink.finish(np.arange(5.0))
    assert group["frames"].shape == (5, 3, 4) and group["frames"].dtype == np.float16
    np.testing.assert_allclose(group["frames"][...], 0.2, rtol=2**-11)  # float16
    np.testing.assert_allclose(group["chroma"][...], 0.0, atol=1e-6)


@pytest.mark.parametrize("chunk, held, spilled", [(4, 1, True), (4, 3, True), (16, 10, False)])
def test_frame_sink_spills_when_few_frames_are_held(tmp_path, chunk, held, spilled):
    """Holding only a few frames (large photographs: fewer than ``SPILL_BELOW``), the sink
    spills them in bands of rows and writes ``frames`` and ``frame_chroma`` in whole chunks at
    the end: the same arrays, chunked as if every chunk had been held, and no spill left in the
    store. Holding more, it writes chunks as deep as what it holds."""
    rng = np.random.default_rng(5)
    ycc = rng.uniform([0.05, -0.1, -0.1], [0.9, 0.1, 0.1], (23, 5, 300, 3)).astype(np.float32)
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w", zarr_format=3)
    sink = FrameSink(group, transfer="linear", chunk_frames=chunk, held_frames=held)
    for frame in ycc:
        sink.add(np.zeros((5, 300, 3), np.uint8), True, source="f", ycc=frame)
        assert ("spilled_frames" in group) == spilled and ("frames" in group) != spilled
    sink.finish(np.arange(23.0))
    assert sorted(group.array_keys()) == ["channel", "chroma", "chroma_spread", "frame_chroma",
                                          "frames", "t", "x", "y"]
    depth = chunk if spilled else held
    assert group["frames"].chunks == (depth, 5, 256)
    assert group["frame_chroma"].chunks == (1, depth, 5, 256)
    np.testing.assert_array_equal(group["frames"][...], ycc[..., 0].astype(np.float16))
    np.testing.assert_array_equal(group["frame_chroma"][...],
                                  np.moveaxis(ycc[..., 1:], -1, 0).astype(np.float16))
    assert group["frames"].attrs["long_name"] == "linear luminance Y (BT.601 weights)"


@pytest.mark.parametrize("expected_frames", [None, 6], ids=["compiled", "numpy"])
def test_frame_sink_sums_as_numpy_does(tmp_path, expected_frames):
    """The per-frame pass, compiled (a capture of unknown length) or NumPy's (a short one,
    summed in float32), gives the stored planes, chroma sums and moments over the valid frames
    (NaN as unobserved) and brightness that plain NumPy gives, NaN pixels included."""
    rng = np.random.default_rng(3)
    ycc = rng.uniform([0.05, -0.1, -0.1], [0.9, 0.1, 0.1], (6, 5, 7, 3)).astype(np.float32)
    ycc[2, 1:3, 4] = np.nan  # registered frames leave unobserved pixels NaN
    valid = np.array([True, True, True, False, True, True])
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w", zarr_format=3)
    sink = FrameSink(group, transfer="linear", chunk_frames=4, expected_frames=expected_frames)
    for frame, ok in zip(ycc, valid, strict=True):
        sink.add(np.zeros((5, 7, 3), np.uint8), bool(ok), source="f", ycc=frame)
    decision = sink.finish(np.arange(6.0))
    assert ("numba" in type(sink._accumulate).__module__) == (expected_frames is None)
    np.testing.assert_array_equal(group["frames"][...], ycc[..., 0].astype(np.float16))
    np.testing.assert_array_equal(group["frame_chroma"][...],
                                  np.moveaxis(ycc[..., 1:], -1, 0).astype(np.float16))
    np.testing.assert_allclose(sink.brightness, np.nanmean(ycc[..., 0], axis=(1, 2)), rtol=1e-6)
    y, cb, cr = np.moveaxis(np.nan_to_num(ycc[valid]).astype(np.float64), -1, 0)
    # a capture of known, short length sums in float32: 3.2e-6 at most here (float64: 1e-6)
    np.testing.assert_allclose(group["chroma"][...],
                               np.stack([cb.sum(0) / y.sum(0), cr.sum(0) / y.sum(0)], -1),
                               rtol=1e-6 if expected_frames is None else 1e-5)
    residual = [np.maximum((c * c).sum(0) - (c * y).sum(0) ** 2 / (y * y).sum(0), 0)
                for c in (cb, cr)]
    np.testing.assert_allclose(group["chroma_spread"][...],
                               np.sqrt(np.stack(residual, -1) / (y * y).sum(0)[..., None]),
                               rtol=1e-5, atol=1e-7)
    assert decision["variation"] == pytest.approx(
        np.sqrt(sum(r.sum() for r in residual) / (y * y).sum()), rel=1e-6)


def test_layout(ds):
    assert dict(ds.sizes) == {"t": N, "y": H, "x": W, "channel": 2}
    assert ds.frames.dims == ("t", "y", "x") and ds.frames.dtype == np.float16
    assert ds.chroma.dims == ("y", "x", "channel") and ds.chroma.dtype == np.float32
    for name in ("pose_r", "pose_s", "pose_z"):
        assert ds[name].dims == ("t",) and ds[name].dtype == np.float64
    assert ds.pose_valid.dtype == bool
    assert list(ds.channel.values) == ["cb", "cr"]
    np.testing.assert_array_equal(ds.y, np.arange(H))
    np.testing.assert_array_equal(ds.x, np.arange(W))
    assert "pose_p" not in ds


def test_chunks(ingested):
    lazy = xr.open_zarr(ingested[0], consolidated=False)
    assert lazy.frames.encoding["chunks"] == (CHUNK, H, W)
    assert lazy.frames.encoding.get("shards") is None


def test_open_store(ingested):
    ds = open_store(ingested[0])
    assert ds.frames.shape == (N, H, W)
    assert ds.attrs["acquisition"]["plane"] == PLANE.to_json()


def test_time_coordinate(ds):
    np.testing.assert_allclose(ds.t, frame_times(), rtol=0, atol=1e-12)


def test_frames_round_trip(ds):
    """Lossless video: linear luminance within 8-bit sRGB quantisation, frames in order."""
    expected = expected_luminance()
    np.testing.assert_allclose(ds.frames.values, expected, rtol=0.02, atol=2e-3)
    means = ds.frames.mean(("y", "x")).values
    np.testing.assert_array_equal(np.argsort(means), np.argsort(GAINS))


def test_pose_interpolation(ds):
    t = frame_times()
    known = (t >= 0.49) & (t <= 1.51)
    np.testing.assert_allclose(ds.pose_r.values[known], r_of(t[known]), atol=1e-7)
    np.testing.assert_allclose(ds.pose_s.values[known], s_of(t[known]), atol=1e-7)
    assert np.isnan(ds.pose_r.values[~known]).all()


def test_rejections(ingested, ds):
    _, report, _ = ingested
    assert {k: report[k] for k in EXPECTED} == EXPECTED
    valid = np.zeros(N, bool)
    valid[15:30] = True
    valid[37:41] = True
    np.testing.assert_array_equal(ds.pose_valid.values, valid)
    z = ds.pose_z.values
    np.testing.assert_allclose(z[30:37], 1.2 * PLANE.height)
    np.testing.assert_allclose(z[valid], PLANE.height)
    assert (ds.pose_r.values[41:46] > PLANE.r[1]).all()


def test_chroma_ratio(ds):
    np.testing.assert_allclose(ds.chroma.values, expected_chroma(), atol=0.01)


def test_constant_colour_is_illumination_invariant(ds, ingested):
    assert ds.chroma_spread.values.max() < 0.02
    decision = ingested[1]["chroma"]
    assert decision["invariant"] and decision["variation"] < 0.02


def test_invariant_colour_keeps_no_frame_chroma(acq_dir, ingested, tmp_path):
    """Only a colour LTM reads each frame's chroma: removed where the colour is invariant, so a
    forced colour LTM is refused with the way out; --keep-chroma keeps it."""
    from ltmstore.stages.reconstruct import reconstruct

    store, report, _ = ingested
    assert report["chroma"]["frames_kept"] is False and not (store / "frame_chroma").exists()
    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    with pytest.raises(LtmError, match=r"no per-frame chroma for a colour LTM; ingest found its "
                       r"colour illumination invariant \(variation 0\.0\d\d <= 0\.05\) and "
                       r"kept none; ltm ingest --keep-chroma keeps it$"):
        reconstruct(copy, color=True, progress=False)
    assert tree_hashes(copy) == tree_hashes(store)  # nothing written
    kept = ingest(acq_dir, tmp_path / "kept.zarr", progress=False, keep_chroma=True)
    assert kept["chroma"]["frames_kept"] is True
    assert (tmp_path / "kept.zarr" / "frame_chroma").is_dir()


def test_chroma_that_changes_with_the_light_needs_a_colour_ltm():
    energy = np.full((4, 4), 2.0)
    assert chroma_decision(np.zeros((2, 4, 4)), energy)["invariant"]
    decision = chroma_decision(np.full((2, 4, 4), 0.02), energy)  # 10 % colour error per channel
    assert not decision["invariant"]
    assert decision["variation"] == pytest.approx(np.sqrt(0.04 / 2.0))


def test_provenance(acq_dir, ingested):
    store, report, _ = ingested
    group_attrs = open_store(store).attrs
    acq = group_attrs["acquisition"]
    assert acq["sha256"] == {"video": sha256(acq_dir / "video.mkv"),
                             "poses": sha256(acq_dir / "poses.csv")}
    assert acq["transfer"] == "srgb" and acq["fps"] == 30.0 and acq["frame_size"] == [H, W]
    assert acq["video"] == "video.mkv" and acq["poses"] == "poses.csv"
    record = stages(open_group(store))["ingest"]
    assert record["complete"] is True
    assert record["rejected"] == EXPECTED["rejected"]
    assert record["z_tolerance"] == pytest.approx(Z_TOLERANCE_FRACTION * PLANE.height)
    assert report["store"] == str(store)
    assert record["seconds"] == report["seconds"] and record["timings"] == report["timings"]
    assert report["timings"]["frames"] > 0  # 60 frames decoded and written: milliseconds
    assert report["seconds"] >= sum(report["timings"].values()) - 2e-3  # parts rounded to 1 ms


def test_inputs_unchanged(acq_dir, ingested):
    assert tree_hashes(acq_dir) == ingested[2]


def test_existing_store_refused_then_overwritten(acq_dir, ingested, tmp_path):
    store = tmp_path / "copy.zarr"
    shutil.copytree(ingested[0], store)
    with pytest.raises(LtmError, match="already exists; pass --overwrite"):
        ingest(acq_dir, store, progress=False)
    report = ingest(acq_dir, store, overwrite=True, progress=True, z_tolerance=0.2)
    assert report["rejected"]["out_of_plane"] == 0
    assert report["n_valid"] == EXPECTED["n_valid"] + EXPECTED["rejected"]["out_of_plane"]
    frames = open_store(store).frames  # stored in float16, served in float32 as stored
    assert frames.encoding["chunks"] == (32, H, W) and frames.encoding["dtype"] == np.float16
    assert frames.dtype == np.float32 and float(frames.mean()) == pytest.approx(
        float(np.mean(zarr.open_array(store / "frames")[...], dtype=np.float64)), rel=1e-6)


def test_mp4(tmp_path):
    """Lossy mp4v: per-frame mean luminance close to the truth, frames in order."""
    folder = make_acquisition(tmp_path / "acq", video="video.mp4")
    report = ingest(folder, tmp_path / "s.zarr", progress=False)
    assert {k: report[k] for k in EXPECTED} == EXPECTED
    ds = xr.open_zarr(tmp_path / "s.zarr", consolidated=False)
    np.testing.assert_allclose(ds.frames.mean(("y", "x")).values,
                               expected_luminance().mean(axis=(1, 2)), rtol=0.05)
    np.testing.assert_allclose(ds.chroma.mean(("y", "x")).values,
                               expected_chroma().mean(axis=(0, 1)), atol=0.03)


def test_linear_transfer(tmp_path):
    folder = make_acquisition(tmp_path / "acq", transfer="linear")
    ingest(folder, tmp_path / "s.zarr", progress=False)
    ds = xr.open_zarr(tmp_path / "s.zarr", consolidated=False)
    np.testing.assert_allclose(ds.frames.values, expected_luminance(), rtol=0.02, atol=3e-3)


def test_time_offset(tmp_path):
    folder = make_acquisition(tmp_path / "acq", extra={"time_offset": 0.2})
    report = ingest(folder, tmp_path / "s.zarr", progress=False)
    ds = xr.open_zarr(tmp_path / "s.zarr", consolidated=False)
    t = frame_times()
    known = (t >= 0.69) & (t <= 1.71)
    np.testing.assert_allclose(ds.pose_r.values[known], r_of(t[known] - 0.2), atol=1e-7)
    assert report["rejected"]["beyond_poses"] == N - known.sum()


def test_a_long_gap_in_the_poses_is_not_bridged():
    """Frames inside a pose gap longer than MAX_POSE_GAP_S get no guessed light; short gaps
    (tracker dropouts) are interpolated."""
    tp = np.concatenate([np.arange(0, 1, 0.02), [1.1], np.arange(2, 3, 0.02)])  # 0.9 s lost
    poses = Poses(t=tp, r=tp * 0.01, s=np.zeros_like(tp), z=np.full_like(tp, PLANE.height))
    t = np.arange(0, 2.9, 1 / 30)
    lights = lights_at(t, poses, plane=PLANE, z_tolerance=0.01)
    lost = (t > 1.1) & (t < 2.0)
    assert 1.1 - 0.98 < MAX_POSE_GAP_S < 2.0 - 1.1
    np.testing.assert_array_equal(lights.beyond_poses, lost)
    np.testing.assert_allclose(lights.r[~lost], t[~lost] * 0.01, atol=1e-12)
    assert np.isnan(lights.r[lost]).all()


def test_view_poses(tmp_path):
    """6D: p, q interpolated and written; frames whose camera leaves the view plane rejected."""
    folder = make_acquisition(tmp_path / "acq", view=True,
                              extra={"view_plane": {"p": [0.0, 0.1], "q": [-1.0, 1.0]}})
    report = ingest(folder, tmp_path / "s.zarr", progress=False)
    ds = xr.open_zarr(tmp_path / "s.zarr", consolidated=False)
    np.testing.assert_allclose(ds.pose_p.values[15:46], 0.1 * frame_times()[15:46], atol=1e-7)
    extra = int(((0.1 * frame_times()[15:41] > 0.1) & ~np.isin(np.arange(15, 41),
                                                               np.arange(30, 37))).sum())
    assert report["rejected"]["outside_bounds"] == EXPECTED["rejected"]["outside_bounds"] + extra
    assert extra > 0
    assert open_store(tmp_path / "s.zarr").attrs["acquisition"]["view_plane"]["p"] == [0.0, 0.1]


def test_view_plane_without_view_poses(tmp_path):
    folder = make_acquisition(tmp_path / "acq", extra={"view_plane": {"p": [0, 1], "q": [0, 1]}})
    with pytest.raises(LtmError, match="declares a view_plane but the poses have no p, q"):
        ingest(folder, tmp_path / "s.zarr", progress=False)


def test_too_few_valid_frames(tmp_path):
    plane = {"r": [0.45, 0.6], "s": [-0.5, 0.5], "height": 0.5}  # r > 0.45 only near the end
    folder = make_acquisition(tmp_path / "acq", extra={"plane": plane})
    store = tmp_path / "s.zarr"
    with pytest.raises(LtmError, match=r"only \d of 60 frames are valid \(rejected: .*"
                                       r"'outside_bounds': \d+, 'occluded': 0\}\); "
                                       r"expected at least 8"):
        ingest(folder, store, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["acq"]


@pytest.mark.parametrize("value, match", [(0, "chunk_frames 0 must be a positive integer"),
                                          (2.5, "chunk_frames 2.5 must be a positive integer")])
def test_bad_chunk_frames(acq_dir, tmp_path, value, match):
    with pytest.raises(LtmError, match=match):
        ingest(acq_dir, tmp_path / "s.zarr", progress=False, chunk_frames=value)
    assert not list(tmp_path.iterdir())


def test_bad_z_tolerance(acq_dir, tmp_path):
    with pytest.raises(LtmError, match="z_tolerance -1 must be a non-negative number"):
        ingest(acq_dir, tmp_path / "s.zarr", progress=False, z_tolerance=-1)


@pytest.fixture
def broken(acq_dir, tmp_path):
    """A copy of the acquisition whose video file is replaced by ``content``."""
    def make(content: bytes):
        folder = tmp_path / "acq"
        shutil.copytree(acq_dir, folder)
        (folder / "video.mkv").write_bytes(content)
        return folder
    return make


@pytest.mark.parametrize("content", [np.random.default_rng(1).bytes(5000), b"not a video\n",
                                     b""])
def test_not_a_video(broken, tmp_path, content):
    with pytest.raises(LtmError, match="video '.*video.mkv' cannot be decoded: FFmpeg cannot "
                                       "open it"):
        ingest(broken(content), tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists()


def test_truncated_video(acq_dir, broken, tmp_path):
    data = (acq_dir / "video.mkv").read_bytes()
    with pytest.raises(LtmError, match=r"cannot be decoded: it ends after \d+ of the 60 frames"):
        ingest(broken(data[: len(data) // 2]), tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists()


def test_poses_error_propagates(acq_dir, tmp_path):
    folder = tmp_path / "acq"
    shutil.copytree(acq_dir, folder)
    (folder / "poses.csv").write_text("t,r,s,z\n0,0,0,0.5\n")
    with pytest.raises(LtmError, match="1 pose sample"):
        ingest(folder, tmp_path / "s.zarr", progress=False)


def test_acquisition_json_error_propagates(acq_dir, tmp_path):
    folder = tmp_path / "acq"
    shutil.copytree(acq_dir, folder)
    meta = json.loads((folder / "acquisition.json").read_text())
    (folder / "acquisition.json").write_text(json.dumps({**meta, "video": "../video.mkv"}))
    with pytest.raises(LtmError, match="leaves the folder"):
        ingest(folder, tmp_path / "s.zarr", progress=False)


def test_frame_sink_converts_bands_on_threads_as_whole_frames(tmp_path, monkeypatch):
    """A large photograph is converted and summed in bands of rows, two threads at once, each
    in its own arrays: the stored frames, chroma and spread are those of one band to float32
    rounding (OpenCV's vectorised conversion rounds a row's tail otherwise than its body, so
    where a band ends can move the last bit)."""
    import ltmstore.stages.frames as frames_module

    rng = np.random.default_rng(7)
    rgb = rng.integers(0, 256, (5, 37, 11, 3), dtype=np.uint8)

    def ingest(name: str) -> tuple[zarr.Group, FrameSink]:
        group = zarr.open_group(str(tmp_path / name), mode="w", zarr_format=3)
        sink = FrameSink(group, transfer="srgb", chunk_frames=2)
        for i, frame in enumerate(rgb):
            sink.add(frame, i != 3, source="f")
        sink.finish(np.arange(5.0))
        return group, sink

    whole, one = ingest("whole.zarr")
    monkeypatch.setattr(frames_module, "BAND_PIXELS", 2 * 4 * 11)  # bands of 4 rows, 2 at once
    banded, bands = ingest("banded.zarr")
    for name in ("frames", "frame_chroma"):  # float16: one step of its rounding at most
        np.testing.assert_allclose(banded[name][...], whole[name][...], rtol=2**-10)
    for name in ("chroma", "chroma_spread"):
        # atol: float32 rounding of sums of order 1 (measured 1.09e-6 on an AMD EPYC, in a
        # value of 0.0099 that those sums nearly cancel to; 1e-7 had held on Intel CPUs)
        np.testing.assert_allclose(banded[name][...], whole[name][...], rtol=1e-6, atol=2e-6)
    np.testing.assert_allclose(bands.brightness, one.brightness, rtol=1e-6)
    assert np.ptp(whole["chroma"][...]) > 0.1  # coloured: the chroma is compared, not zeros
