from unittest.mock import patch

import dask.array as da
import numpy as np
import zarr
from hypothesis import given, settings
from hypothesis import strategies as st

from ltmstore.core.binning import cell_means, revisited, segments
from ltmstore.core.dims import Lattice, Plane
from ltmstore.stages import resample
from ltmstore.stages.resample import bin_frames, bin_positions, path_length

PLANE = Plane(r=(0.0, 4.0), s=(0.0, 2.0), height=1.0)


def test_binning_is_the_mean_of_each_cell_on_hand_made_samples():
    lattice = Lattice.from_plane(PLANE, (4, 2))  # unit cells
    r = np.array([0.5, 0.6, 3.9, 1.0, 2.5, 9.0])
    s = np.array([0.5, 0.1, 1.9, 1.5, 0.5, 0.5])
    valid = np.array([True, True, True, True, False, True])
    frames = np.arange(6 * 2 * 3, dtype=np.float32).reshape(6, 2, 3)
    binning = bin_positions(lattice, (r, s), valid)
    out = bin_frames(da.from_array(frames), binning, block_frames=2, tile=(1, 2)).compute()
    expected = np.full((2, 3, 4, 2), np.nan, np.float32)
    expected[..., 0, 0] = (frames[0] + frames[1]) / 2
    expected[..., 3, 1] = frames[2]
    expected[..., 1, 1] = frames[3]  # r = 1.0 starts cell 1
    np.testing.assert_allclose(out, expected)
    assert binning.k == 3 and binning.m == 8 and binning.ratio == 3 / 8
    assert binning.count[0, 0] == 2 and binning.count.sum() == 4


def test_each_cell_belongs_to_the_second_that_took_most_of_its_frames():
    lattice = Lattice.from_plane(PLANE, (4, 2))  # unit cells
    r = np.array([0.5, 0.5, 0.5, 1.5, 1.5, 3.5, 0.5])
    s = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 1.5, 0.5])
    times = 10.0 + np.array([0.1, 1.2, 1.3, 1.9, 2.05, 3.5, 0.2])  # the video starts at 10 s
    valid = np.array([True, True, True, True, True, True, False])
    segment = segments(bin_positions(lattice, (r, s), valid), times, 1.0)
    expected = np.full(8, -1)
    expected[[0, 2, 7]] = [1, 1, 3]  # (0, 0): two frames in second 1, one in 0; (1, 0): a tie
    np.testing.assert_array_equal(segment, expected)
    empty = bin_positions(lattice, (r, s), np.zeros(7, bool))
    assert (segments(empty, times, 1.0) == -1).all()


def test_cell_means_average_each_cells_frames():
    lattice = Lattice.from_plane(PLANE, (4, 2))  # unit cells
    r = np.array([0.5, 0.7, 3.5, 0.5])
    s = np.array([0.5, 0.5, 1.5, 0.5])
    binning = bin_positions(lattice, (r, s), np.array([True, True, True, False]))
    means = cell_means(binning, r, np.array([1.0, 2.0, 5.0, 100.0]))  # the last one not used
    assert means.shape == (8, 2)
    np.testing.assert_allclose(means[[0, 7]], [[0.6, 1.5], [3.5, 5.0]])
    assert np.isnan(np.delete(means, [0, 7], axis=0)).all()


def test_revisited_counts_the_cells_beside_another_second_of_the_path():
    apart = np.array([[0, 0, 0, 1, 1, 1], [-1] * 6, [2, 2, 2, 3, 3, 3]])
    assert revisited(apart) == 4 / 12  # only where a sweep turns to its next second
    beside = apart.copy()
    beside[1] = 4  # a pass between the two sweeps, in another second
    assert revisited(beside) == 1.0
    assert revisited(np.full((3, 3), -1)) == 0.0


def test_upper_plane_edge_belongs_to_last_cell():
    lattice = Lattice.from_plane(PLANE, (4, 2))
    assert lattice.cell_index(np.array([4.0]), np.array([2.0]))[0] == 7
    assert lattice.cell_index(np.array([-1e-9]), np.array([1.0]))[0] == -1


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 9), st.integers(1, 9), st.integers(1, 40), st.integers(1, 7),
       st.integers(0, 2**31 - 1), st.booleans())
def test_binning_matches_a_loop_for_any_block_size(nr, ns, nt, chunk, seed, long_video):
    """One pass per tile, or (``long_video``: the tile's frames over the bytes of one task)
    partial sums of ``chunk`` frames added by Dask."""
    rng = np.random.default_rng(seed)
    lattice = Lattice.from_plane(PLANE, (nr, ns))
    r, s = rng.uniform(-0.5, 4.5, nt), rng.uniform(-0.5, 2.5, nt)
    frames = rng.random((nt, 2, 2)).astype(np.float32)
    binning = bin_positions(lattice, (r, s))
    with patch.object(resample, "TILE_FRAMES_BYTES", 0 if long_video else 2**20):
        lazy = bin_frames(da.from_array(frames), binning, block_frames=chunk, tile=(2, 1))
    layers = " ".join(lazy.dask.layers)
    assert ("_block_sums" in layers) == long_video and ("_tile_means" in layers) != long_video
    out = lazy.compute()
    sums, counts = np.zeros((2, 2, nr * ns)), np.zeros(nr * ns)
    for f, c in zip(frames, binning.cell, strict=True):
        if c >= 0:
            sums[..., c] += f
            counts[c] += 1
    with np.errstate(invalid="ignore"):
        expected = (sums / counts).reshape(2, 2, nr, ns)
    np.testing.assert_allclose(out, expected, rtol=1e-5)
    assert binning.count.sum() == counts.sum()


def test_path_length_skips_invalid_steps():
    r, s = np.array([0.0, 1.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0, 3.0])
    assert path_length(r, s) == 4.0
    assert path_length(r, s, valid=np.array([True, True, False, True])) == 1.0


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 6), st.integers(1, 30), st.integers(0, 2**31 - 1), st.booleans(),
       st.booleans())
def test_a_region_resampled_from_the_store_is_bin_frames(n, nt, seed, long_video, channel):
    """:func:`resample.resample_region` (a reconstruct task: its frames read from the store, in
    one block or, ``long_video``, blocks of 3 frames whose sums add) writes the region's
    samples as :func:`bin_frames`, of the luminance or of one chroma channel."""
    rng = np.random.default_rng(seed)
    lattice = Lattice.from_plane(PLANE, (n, n))
    binning = bin_positions(lattice, (rng.uniform(-0.5, 4.5, nt), rng.uniform(-0.5, 2.5, nt)))
    frames = rng.random((2, nt, 6, 5)).astype(np.float16)  # (channel, t, y, x)
    stored = frames if channel else frames[1]
    source = zarr.create_array(zarr.storage.MemoryStore(), shape=stored.shape,
                               chunks=(1, 4, 4, 4)[-stored.ndim:], dtype=np.float16)
    source[...] = stored
    samples = zarr.create_array(zarr.storage.MemoryStore(), shape=(6, 5, n, n),
                                chunks=(2, 2, n, n), dtype=np.float32, fill_value=-1.0)
    where = (slice(2, 6), slice(0, 4))
    with patch.object(resample, "REGION_FRAMES_BYTES", 4 * 16 * 3 if long_video else 2**20):
        resample.resample_region(where, frames=source, samples=samples, cells=binning.cell,
                                 count=binning.count.reshape(-1).astype(np.float32),
                                 channel=1 if channel else None)
    expected = bin_frames(da.from_array(frames[1].astype(np.float32)), binning).compute()
    np.testing.assert_allclose(samples[where], expected[where], rtol=1e-6)
    assert (samples[:2] == -1).all() and (samples[:, 4:] == -1).all()  # nothing outside
