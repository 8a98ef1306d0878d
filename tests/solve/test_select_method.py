"""``auto`` on a near-light lattice: the method with the lowest held-out error, smaller on a tie."""

from __future__ import annotations

import numpy as np

from ltmstore.solve import Geometry
from ltmstore.solve.ptm import ptm_basis
from ltmstore.solve.select import AUTO_METHODS, choose_method


def batch(values_of, n=24, shape=(12, 12), observed=0.4, seed=0):
    geometry = Geometry.from_shape(shape)
    rng = np.random.default_rng(seed)
    coef = rng.normal(size=(n, 6))
    full = values_of(geometry, coef).reshape(n, *shape)
    mask = rng.random(shape) < observed
    return np.where(mask, full, np.nan), geometry


def test_a_ptm_scene_chooses_ptm():
    samples, geometry = batch(lambda g, c: c @ ptm_basis(g.directions()).T + 5)
    choice = choose_method(samples, geometry, seed=1)
    assert choice.label == "ptm", choice.errors
    assert set(choice.errors) == {label for label, _, _ in AUTO_METHODS}


def test_a_sharp_scene_leaves_the_global_fits():
    def sharp(g, c):
        d = g.directions()
        lobe = np.exp(-np.sum((d - d[40]) ** 2, axis=1) / 0.03)
        return (1 + np.abs(c[:, :1])) * lobe + 0.1
    samples, geometry = batch(sharp, observed=0.7)
    choice = choose_method(samples, geometry, seed=2)
    assert choice.label not in ("ptm", "hsh2"), choice.errors
