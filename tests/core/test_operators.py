import numpy as np
import pytest

from ltmstore.core.operators import SensingOperator, dot_test


@pytest.mark.parametrize("lattice", [(8, 8), (6, 10), (4, 5, 3, 3)])
@pytest.mark.parametrize("shared", [True, False])
def test_adjoint_passes_dot_test(lattice, shared):
    rng = np.random.default_rng(1)
    shape = (5, *lattice)
    mask = rng.random(lattice if shared else shape) < 0.3
    op = SensingOperator(mask, ndim=len(lattice))
    assert dot_test(op, shape) < 1e-12


def test_dense_matrix_matches_fast_transform():
    rng = np.random.default_rng(2)
    op = SensingOperator(np.ones((4, 6), bool))
    f = rng.standard_normal((4, 6))
    assert np.allclose(op.matrix((4, 6)) @ f.ravel(), op.idct(f).ravel())


def test_transform_is_orthonormal():
    op = SensingOperator(np.ones((5, 7), bool))
    h = op.matrix((5, 7))
    assert np.allclose(h.T @ h, np.eye(35))
