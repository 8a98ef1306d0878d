"""The web planes' JPEG quality (:mod:`ltmstore.share.jpeg_quality`): the lowest quality whose
JPEG costs at most half a decibel, and the window it is judged on."""

from __future__ import annotations

import numpy as np

from ltmstore.share import jpeg_quality as jq


def _images(codes: np.ndarray) -> np.ndarray:
    """Two 'lights': each shows one of the two RGB planes."""
    return np.stack([codes[:, :, :3], codes[:, :, 3:]])


def _store(codes: np.ndarray, seed: int) -> np.ndarray:
    """``ltm relight``'s images: the planes' own plus an error of about 3 levels."""
    noise = np.random.default_rng(seed).normal(0, 3, _images(codes).shape)
    return np.clip(np.round(_images(codes) + noise), 0, 255).astype(np.uint8)


def test_smooth_planes_keep_the_first_quality():
    """Planes of flat 8 x 8 blocks lose almost nothing at 95: it is kept, the only one tried."""
    rng = np.random.default_rng(1)
    codes = np.repeat(np.repeat(rng.integers(40, 216, (8, 10, 6), dtype=np.uint8), 8, 0), 8, 1)
    quality, record = jq.choose(codes, _images, _store(codes, 2))
    assert quality == 95 and list(record["loss_db"]) == [95]
    assert 0.05 < record["loss_db"][95] < 0.25  # measured 0.144


def test_noise_planes_take_the_highest_and_say_what_each_cost():
    """Planes of pixel noise lose more than the bound at every quality but the highest: it is
    taken, and every quality's cost is recorded, decreasing with the quality."""
    codes = np.random.default_rng(3).integers(0, 256, (64, 80, 6), dtype=np.uint8)
    quality, record = jq.choose(codes, _images, _store(codes, 4))
    losses = list(record["loss_db"].values())
    assert quality == 100 and list(record["loss_db"]) == list(jq.QUALITIES)
    assert losses == sorted(losses, reverse=True)  # measured 4.65, 2.39, 1.37, 0.27
    assert min(losses[:-1]) > 1.0 and 0.1 < losses[-1] <= jq.MAX_LOSS_DB


def test_round_trip_at_100_is_close():
    codes = np.random.default_rng(5).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    decoded = jq.round_trip(codes, 100)
    assert decoded.shape == codes.shape and np.abs(decoded.astype(int) - codes).mean() < 2


def test_the_window_is_central_aligned_and_bounded():
    rows, cols = jq.window((3000, 500))
    assert (rows.start, rows.stop) == (976, 2000) and rows.start % jq.BLOCK == 0
    assert (cols.start, cols.stop) == (0, 500)
    assert jq.window((1030, 1030)) == (slice(0, 1024), slice(0, 1024))
