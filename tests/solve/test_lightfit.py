"""Far-light fits at exact directions: exactness, the closed-form leave-one-out, the choice."""

from __future__ import annotations

import numpy as np

from ltmstore.core.lights import elevation_azimuth
from ltmstore.solve.lightfit import Model, candidates, choose, loo_operator, relit
from ltmstore.solve.ptm import ptm_basis


def dome(n_rings: int = 4, per_ring: int = 12) -> np.ndarray:
    el = np.repeat(np.linspace(15, 75, n_rings), per_ring)
    az = np.tile(np.linspace(0, 360, per_ring, endpoint=False), n_rings) + el
    return np.vstack([elevation_azimuth(el, az), [[0, 0, 1]]])


def test_ptm_is_exact_on_biquadratic_data():
    train, query = dome(), elevation_azimuth([20, 50, 85], [10, 200, 300])
    coef = np.random.default_rng(0).normal(size=(6, 5))
    values = ptm_basis(train) @ coef + 10  # positive
    np.testing.assert_allclose(relit(values, train, query, Model("ptm")),
                               ptm_basis(query) @ coef + 10, rtol=1e-9)


def test_closed_form_leave_one_out_matches_refitting():
    train = dome()
    values = np.random.default_rng(1).random((len(train), 7))
    for model in (Model("hsh2"), Model("rbf:0.3:0.01")):
        closed = loo_operator(model.hat(train)) @ values
        brute = np.array([values[i] - model.weights(np.delete(train, i, 0), train[i:i + 1])
                          @ np.delete(values, i, 0) for i in range(len(train))])[:, 0]
        np.testing.assert_allclose(closed, brute, rtol=1e-6, atol=1e-9)


def test_rbf_far_from_every_light_tends_to_a_constant_inside_the_data():
    train = dome()
    values = np.random.default_rng(2).random((len(train), 3))
    far = relit(values, train, np.array([[0.0, 0.0, -1.0], [0, 0.01, -1]]), Model("rbf:0.2:0.01"))
    np.testing.assert_allclose(far[0], far[1], rtol=1e-6)
    assert (values.min(axis=0) < far[0]).all() and (far[0] < values.max(axis=0)).all()


def test_choice_prefers_the_smaller_model_on_a_tie():
    train = dome()
    values = ptm_basis(train) @ np.random.default_rng(3).normal(size=(6, 50))
    model, errors = choose(values, train)
    assert model.name == "ptm", errors  # HSH3 and PTM both fit exactly; PTM is smaller
    assert set(errors) == {m.name for m in candidates()}


def test_choice_follows_the_data():
    train = dome()
    sharp = np.exp(-np.sum((train - [0.5, 0, np.sqrt(0.75)]) ** 2, axis=1) / 0.02)[:, None]
    model, _ = choose(sharp * np.ones((1, 4)), train)
    assert model.family == "rbf"


def test_weights_of_the_same_lights_are_computed_once_and_cannot_be_changed():
    from ltmstore.solve.lightfit import _cached_weights

    train, query = dome(), elevation_azimuth([20, 50, 85], [10, 200, 300])
    model = Model("hsh3+rbf:0.3:0.01")
    _cached_weights.cache_clear()
    first = model.weights(train, query)
    again = model.weights(train.copy(), np.asfortranarray(query))  # the same values
    assert again is first
    # the HSH + RBF model asked for its RBF part once: two entries, no second computation
    assert _cached_weights.cache_info().misses == 2
    assert not first.flags.writeable
    np.testing.assert_array_equal(first, model._weights(train, query))
    assert model.weights(train[:-1], query).shape == (3, len(train) - 1)  # other lights: anew
