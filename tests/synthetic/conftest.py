"""Shared fixtures: hand-made test scenes and one small simulated acquisition."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.synthetic.scenes import Scene
from ltmstore.synthetic.simulate import plan_simulation, simulate_acquisition

PITCH = 1e-3  # 1 mm pixels for the hand-made scenes


def uniform_scene(height: np.ndarray, *, albedo: float = 0.5, spec: float = 0.0,
                  roughness: float = 1.0, metallic: float = 0.0) -> Scene:
    """A scene of one material over the given height field."""
    shape = height.shape
    return Scene(height=height, albedo=np.full((*shape, 3), albedo),
                 spec_color=np.full((*shape, 3), spec), roughness=np.full(shape, roughness),
                 metallic=np.full(shape, metallic), pixel_size=PITCH, name="test")


@pytest.fixture(scope="session")
def lambertian() -> Scene:
    """A flat matte grey patch (the specular lobe is negligible at roughness 1 and F0 = 0)."""
    return uniform_scene(np.zeros((16, 16)))


@pytest.fixture(scope="session")
def block_scene() -> Scene:
    """A flat matte floor, 48 x 48 mm, with a 6 mm high block at rows 10-37, columns 24-35."""
    height = np.zeros((48, 48))
    height[10:38, 24:36] = 6e-3
    return uniform_scene(height)


SIM_ARGS = {"scene": "relief", "path_density": 8.0, "seed": 3, "size": 32, "lattice": (8, 8)}


@pytest.fixture(scope="session")
def simulation(tmp_path_factory) -> dict:
    """One small simulated acquisition (relief, 32 x 32 pixels, 8 x 8 truth lattice)."""
    out = tmp_path_factory.mktemp("sim") / "acq"
    return simulate_acquisition(out, progress=False, **SIM_ARGS)


@pytest.fixture(scope="session")
def simulation_plan():
    """The plan behind :func:`simulation` (same arguments, so the same trajectory and noise)."""
    return plan_simulation(**SIM_ARGS)
