"""Baseline reconstruction methods against cases with known answers."""

import numpy as np
import pytest

from ltmstore.core.errors import LtmError
from ltmstore.core.operators import SensingOperator
from ltmstore.solve import METHODS, Geometry, get_method
from ltmstore.solve.hsh import hsh_basis, legendre
from ltmstore.solve.masks import group_by_mask, per_view
from ltmstore.solve.ptm import ptm_basis

BASELINES = ["omp", "cubic", "kernel", "svt", "ptm", "hsh", "rbf"]
LATTICE = (12, 12)
GEOMETRY = Geometry.from_shape(LATTICE)


def random_mask(shape, fraction, rng):
    return rng.random(shape) < fraction


def observe(truth, mask):
    return np.where(mask, truth, np.nan)


def relative_error(truth, estimate, where=Ellipsis):
    return np.linalg.norm((estimate - truth)[where]) / np.linalg.norm(truth[where])


def planes(n, rng, geometry=GEOMETRY):
    """LTFs affine in the cell position ``(r, s)``: ``a + b r + c s``."""
    coef = rng.standard_normal((n, 3)) + [3, 0, 0]
    pos = geometry.positions()
    return (coef[:, :1] + coef[:, 1:] @ pos.T).reshape(n, *geometry.shape)


def in_basis(basis, n, rng):
    """LTFs that are random combinations of the columns of ``basis (M, B)``."""
    return (rng.standard_normal((n, basis.shape[1])) @ basis.T).reshape(n, *LATTICE)


def test_all_baselines_are_registered():
    for name in BASELINES:
        assert get_method(name) is METHODS[name]


# --- shared helpers -------------------------------------------------------------------------


def test_group_by_mask_partitions_rows_by_identical_masks():
    rng = np.random.default_rng(0)
    masks = random_mask((3, 4, 5), 0.5, rng)
    rows = masks[[0, 1, 0, 2, 1, 0]]
    groups = list(group_by_mask(rows))
    assert sorted(np.concatenate([r for _, r in groups]).tolist()) == list(range(6))
    assert len(groups) == 3
    for cells, members in groups:
        assert (rows.reshape(6, -1)[members] == cells).all()
    (cells, members), = group_by_mask(masks[[1, 1, 1]])  # one shared mask: one group
    assert members.tolist() == [0, 1, 2] and (cells == masks[1].ravel()).all()


def test_per_view_runs_the_light_method_once_per_view():
    rng = np.random.default_rng(1)
    samples = rng.random((2, 4, 5, 3, 2))
    geometry = Geometry.from_shape((4, 5, 3, 2))
    calls = []

    def tag(rows, geometry2d):
        calls.append((rows.shape, geometry2d.shape))
        return rows * 2

    out = per_view(samples, geometry, tag)
    assert calls == [((12, 4, 5), (4, 5))]
    np.testing.assert_array_equal(out, samples * 2)


# --- known answers --------------------------------------------------------------------------


@pytest.mark.parametrize("shared", [True, False])
def test_ptm_is_exact_on_a_biquadratic_in_the_light_direction(shared):
    rng = np.random.default_rng(2)
    truth = in_basis(ptm_basis(GEOMETRY.directions()), 16, rng)
    shape = LATTICE if shared else truth.shape
    estimate = get_method("ptm")(observe(truth, random_mask(shape, 0.3, rng)), GEOMETRY)
    assert relative_error(truth, estimate) < 1e-5


@pytest.mark.parametrize("order", [2, 3])
def test_hsh_is_exact_on_its_own_basis(order):
    rng = np.random.default_rng(3)
    basis = hsh_basis(GEOMETRY.directions(), order)
    assert basis.shape[1] == (order + 1) ** 2
    truth = in_basis(basis, 16, rng)
    estimate = get_method("hsh")(observe(truth, random_mask(LATTICE, 0.4, rng)), GEOMETRY,
                                 order=order)
    assert relative_error(truth, estimate) < 1e-5


def test_hsh_basis_is_orthonormal_on_the_hemisphere():
    """Gautron et al.'s normalisation: a midpoint rule over (theta, phi) gives the identity."""
    theta = (np.arange(200) + 0.5) * (np.pi / 2) / 200
    phi = (np.arange(400) + 0.5) * 2 * np.pi / 400
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.column_stack([(np.sin(t) * np.cos(p)).ravel(), (np.sin(t) * np.sin(p)).ravel(),
                            np.cos(t).ravel()])
    basis = hsh_basis(dirs, 3)
    area = (np.sin(t) * (np.pi / 2 / 200) * (2 * np.pi / 400)).ravel()
    gram = basis.T @ (basis * area[:, None])
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-3)


def test_legendre_is_scipys_lpmv():
    """The NumPy recurrence behind hsh_basis against SciPy's associated Legendre functions."""
    from scipy.special import lpmv

    x = np.linspace(-1, 1, 2001)
    for degree in range(5):
        for order in range(degree + 1):
            np.testing.assert_allclose(legendre(order, degree, x), lpmv(order, degree, x),
                                       rtol=1e-12, atol=1e-13)  # measured: 1e-15 for l <= 3


def test_svt_recovers_a_rank_two_matrix_from_half_of_its_entries():
    rng = np.random.default_rng(4)
    n = 32
    truth = (rng.standard_normal((n, 2)) @ rng.standard_normal((2, np.prod(LATTICE))))
    truth = truth.reshape(n, *LATTICE)
    estimate = get_method("svt")(observe(truth, random_mask(truth.shape, 0.5, rng)), GEOMETRY)
    assert relative_error(truth, estimate) < 1e-2


def test_svt_lattice_layout_completes_separable_ltfs_under_a_shared_mask():
    """Rank-1 LTFs ``f(r) g(s)``: each R x S lattice is a rank-1 matrix."""
    rng = np.random.default_rng(5)
    truth = np.einsum("nr,ns->nrs", rng.random((8, 12)) + 0.5, rng.random((8, 12)) + 0.5)
    mask = random_mask(LATTICE, 0.5, rng)
    samples = observe(truth, mask)
    estimate = get_method("svt")(samples, GEOMETRY, layout="lattice")
    assert relative_error(truth, estimate) < 1e-2
    # the tile layout cannot fill cells that no pixel observed: they stay zero
    tile = get_method("svt")(samples, GEOMETRY)
    assert np.all(tile[:, ~mask] == 0)


def test_cubic_is_exact_on_a_plane_inside_the_hull_and_nearest_outside():
    rng = np.random.default_rng(6)
    truth = planes(8, rng)
    mask = random_mask(LATTICE, 0.4, rng)
    mask[[0, -1], 5] = mask[5, [0, -1]] = False
    estimate = get_method("cubic")(observe(truth, mask), GEOMETRY)
    from scipy.spatial import Delaunay

    pos = GEOMETRY.positions()
    inside = (Delaunay(pos[mask.ravel()]).find_simplex(pos) >= 0).reshape(LATTICE)
    assert inside.sum() > 60 and not inside.all()
    assert relative_error(truth, estimate, (slice(None), inside)) < 1e-6
    nearest = np.linalg.norm(pos[~inside.ravel(), None] - pos[None, mask.ravel()], axis=2)
    expected = truth.reshape(8, -1)[:, mask.ravel()][:, nearest.argmin(axis=1)]
    # ties between equally near cells may pick either: compare where the nearest is unique
    d = np.sort(nearest, axis=1)
    unique = d[:, 1] - d[:, 0] > 1e-9
    np.testing.assert_allclose(estimate[:, ~inside][:, unique], expected[:, unique], rtol=1e-6)


def test_cubic_needs_a_two_dimensional_lattice():
    with pytest.raises(LtmError, match="needs a 2-D lattice"):
        get_method("cubic")(np.zeros((1, 3, 3, 2, 2)), Geometry.from_shape((3, 3, 2, 2)))


@pytest.mark.parametrize("order", [1, 2])
def test_kernel_regression_is_exact_on_a_plane(order):
    rng = np.random.default_rng(7)
    truth = planes(8, rng)
    samples = observe(truth, random_mask(truth.shape, 0.5, rng))
    estimate = get_method("kernel")(samples, GEOMETRY, order=order)
    assert relative_error(truth, estimate) < 1e-6


def test_kernel_regression_of_order_zero_is_exact_on_a_constant():
    rng = np.random.default_rng(8)
    truth = np.broadcast_to(rng.random((8, 1, 1)) + 0.5, (8, *LATTICE))
    samples = observe(truth, random_mask(LATTICE, 0.1, rng))
    estimate = get_method("kernel")(samples, GEOMETRY, order=0, bandwidth=0.5)
    assert relative_error(truth, estimate) < 1e-6


def test_kernel_regression_drops_order_where_the_fit_would_extrapolate():
    """Observed along one line only: across it no slope is known, so every cell falls back to a
    Nadaraya-Watson average, inside the range of the data."""
    rng = np.random.default_rng(14)
    truth = planes(4, rng) + rng.random((4, *LATTICE))
    mask = np.zeros(LATTICE, bool)
    mask[3] = True
    estimate = get_method("kernel")(observe(truth, mask), GEOMETRY)
    line = truth[:, 3]
    assert np.all(estimate >= line.min(axis=1)[:, None, None] - 1e-6)
    assert np.all(estimate <= line.max(axis=1)[:, None, None] + 1e-6)


def test_kernel_regression_works_on_a_six_dimensional_lattice():
    rng = np.random.default_rng(9)
    geometry = Geometry.from_shape((5, 5, 3, 3))
    pos = geometry.positions()
    truth = (1 + pos @ rng.standard_normal((4, 3))).T.reshape(3, 5, 5, 3, 3)
    samples = observe(truth, random_mask(truth.shape, 0.6, rng))
    estimate = get_method("kernel")(samples, geometry, order=1)
    assert relative_error(truth, estimate) < 1e-6


@pytest.mark.parametrize("space", ["directions", "positions"])
def test_rbf_interpolates_the_data_and_reproduces_a_plane(space):
    rng = np.random.default_rng(10)
    coords = (GEOMETRY.directions()[:, :2] if space == "directions"
              else GEOMETRY.positions())
    coef = rng.standard_normal((8, 3)) + [2, 0, 0]
    truth = (coef[:, :1] + coef[:, 1:] @ coords.T).reshape(8, *LATTICE)
    samples = observe(truth, random_mask(truth.shape, 0.4, rng))
    estimate = get_method("rbf")(samples, GEOMETRY, space=space)
    assert relative_error(truth, estimate) < 1e-5
    # any data, not just a plane, is interpolated at the observed cells
    noisy = np.where(np.isfinite(samples), rng.random(samples.shape), np.nan)
    out = get_method("rbf")(noisy, GEOMETRY, space=space)
    observed = np.isfinite(noisy)
    np.testing.assert_allclose(out[observed], noisy[observed], atol=1e-5)


def sparse_ltfs(n, lattice, sparsity, rng):
    """LTFs with exactly ``sparsity`` non-zero low-frequency DCT coefficients."""
    coef = np.zeros((n, int(np.prod(lattice))))
    low = np.flatnonzero(np.add.outer(*(np.arange(k) for k in lattice)).ravel() < 8)
    for row in coef:
        row[rng.choice(low, sparsity, replace=False)] = rng.standard_normal(sparsity)
    return SensingOperator(np.ones(lattice, bool)).idct(coef.reshape(n, *lattice))


@pytest.mark.parametrize("params", [{}, {"tol": 1e-8}])
def test_omp_recovers_an_exactly_sparse_ltf(params):
    rng = np.random.default_rng(11)
    lattice, sparsity = (16, 16), 4
    truth = sparse_ltfs(6, lattice, sparsity, rng)
    m = int(np.prod(lattice))
    mask = np.zeros(m, bool)
    mask[rng.choice(m, int(2 * sparsity * np.log(m)), replace=False)] = True
    samples = observe(truth, mask.reshape(lattice))
    estimate = get_method("omp")(samples, Geometry.from_shape(lattice), **params)
    assert relative_error(truth, estimate) < 1e-4


# --- robustness, every method ---------------------------------------------------------------


def awkward_batch(rng):
    """Smooth LTFs with per-pixel masks: a pixel with none, one with 1 to 5 cells, full ones."""
    pos = GEOMETRY.positions()
    lobes = 1 / (1.5 + ((pos[None] - rng.uniform(-0.5, 0.5, (10, 1, 2))) ** 2).sum(-1)) ** 1.5
    truth = lobes.reshape(10, *LATTICE)
    mask = random_mask(truth.shape, 0.3, rng)
    mask[0] = False
    for row, k in zip(range(1, 6), [1, 2, 3, 4, 5], strict=True):
        mask[row] = False
        mask[row].flat[rng.choice(mask[row].size, k, replace=False)] = True
    mask[6, 4, :] = True  # one pixel with all its cells on one line (collinear)
    mask[6, :4] = mask[6, 5:] = False
    mask[7] = True  # fully observed
    return truth, observe(truth, mask)


@pytest.mark.parametrize("name", BASELINES)
def test_every_method_survives_awkward_masks(name):
    rng = np.random.default_rng(12)
    truth, samples = awkward_batch(rng)
    out = get_method(name)(samples, GEOMETRY)
    assert out.shape == samples.shape and out.dtype == np.float32
    assert np.isfinite(out).all()
    assert np.all(out[0] == 0)  # nothing observed: zeros
    if name in {"cubic", "rbf"}:  # interpolating methods keep the data
        observed = np.isfinite(samples)
        np.testing.assert_allclose(out[observed], samples[observed], rtol=1e-5)


@pytest.mark.parametrize("name", ["omp", "kernel", "svt", "ptm", "hsh", "rbf"])
def test_every_method_handles_a_six_dimensional_lattice(name):
    rng = np.random.default_rng(13)
    geometry = Geometry.from_shape((5, 5, 2, 3))
    samples = observe(rng.random((3, 5, 5, 2, 3)), random_mask((3, 5, 5, 2, 3), 0.5, rng))
    out = get_method(name)(samples, geometry)
    assert out.shape == samples.shape and out.dtype == np.float32
    assert np.isfinite(out).all()


@pytest.mark.parametrize(("name", "params", "match"), [
    ("omp", {"n_nonzero_coefs": 0}, "positive integer"),
    ("kernel", {"order": 3}, "must be 0, 1 or 2"),
    ("kernel", {"bandwidth": -1.0}, "positive number of cells"),
    ("svt", {"tau": 0.0}, "tau 0.0 must be a positive number"),
    ("svt", {"layout": "cube"}, "layout 'cube' is unknown"),
    ("hsh", {"order": -1}, "non-negative integer"),
    ("rbf", {"kernel": "sinc"}, "kernel 'sinc' is unknown"),
    ("rbf", {"space": "angles"}, "space 'angles' is unknown"),
])
def test_bad_parameters_are_clear_errors(name, params, match):
    with pytest.raises(LtmError, match=match):
        get_method(name)(np.full((1, *LATTICE), 1.0), GEOMETRY, **params)
