"""The web export's PCA (:func:`ltmstore.share.pca_web.principal`) against NumPy's SVD, on
both of its ways: the covariance decomposed whole (few values a pixel) and scikit-learn's
randomized SVD (many)."""

import numpy as np
import pytest

from ltmstore.share.pca_web import EIGH_MAX_VALUES, principal


def planted(pixels: int, values: int, rank: int, seed: int = 0) -> np.ndarray:
    """Display-like values ``(pixels, values)``: ``rank`` directions of falling strength, a
    little noise and an offset."""
    rng = np.random.default_rng(seed)
    basis = np.linalg.qr(rng.standard_normal((values, rank)))[0]
    weights = rng.standard_normal((pixels, rank)) / (1 + np.arange(rank))
    noise = 1e-3 * rng.standard_normal((pixels, values))
    return (weights @ basis.T + noise + 0.5).astype(np.float32)


@pytest.mark.parametrize("values", [EIGH_MAX_VALUES - 24, EIGH_MAX_VALUES + 24])
def test_the_planes_keep_what_the_svds_keep(values):
    """The leading eigenvectors, largest first, leave the sample's residual of its leading
    right singular vectors (each vector alone may turn a little within close pairs: 1 - cos up
    to 4e-7, with BLAS's threads)."""
    sample = planted(600, values, rank=12)
    mean, vectors = principal(sample, 9)
    np.testing.assert_allclose(mean, sample.mean(axis=0, dtype=np.float64), atol=1e-6)
    centred = (sample - sample.mean(axis=0)).astype(np.float64)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    best = np.sum((centred - centred @ vt[:9].T @ vt[:9]) ** 2)
    kept = np.sum((centred - centred @ vectors @ vectors.T) ** 2)
    assert vectors.shape == (values, 9)
    assert kept / best - 1 < 5e-11  # measured 4e-13 (whole) and 6-7e-12 (randomized)
    assert np.all(np.diff(np.sum((centred @ vectors) ** 2, axis=0)) < 0)  # largest first


def test_fewer_pixels_than_planes_leave_the_rest_empty():
    mean, vectors = principal(planted(5, 64, rank=3), 9)
    assert vectors.shape == (64, 9)
    assert np.all(vectors[:, 5:] == 0) and np.all(np.linalg.norm(vectors[:, :5], axis=0) > 0.99)
