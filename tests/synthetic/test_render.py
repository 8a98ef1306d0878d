"""Physics of the renderer and the built-in scenes."""

from __future__ import annotations

import numpy as np
import pytest

from ltmstore.core.dims import Lattice, Plane
from ltmstore.core.errors import LtmError
from ltmstore.synthetic.render import (
    LOBES,
    MISMATCHED,
    PinholeCamera,
    Shading,
    _distribution,
    is_occluded,
    render_frame,
    render_frames,
    render_ltm,
)
from ltmstore.synthetic.scenes import SCENES, make_scene

from .conftest import PITCH, uniform_scene

PIXEL = (8, 8)  # in the 16 x 16 Lambertian patch: X = +0.5 mm, Y = -0.5 mm


def _centre(scene, yx):
    x, y = scene.pixel_centres()
    return np.array([x[yx], y[yx], scene.height[yx]])


def _value(scene, light, yx=PIXEL, camera=None):
    return float(render_frame(scene, light, camera=camera)[yx][1])


def test_inverse_square_law(lambertian):
    p = _centre(lambertian, PIXEL)
    heights = np.array([0.05, 0.1, 0.2, 0.4])
    values = np.array([_value(lambertian, p + [0, 0, z]) for z in heights])
    np.testing.assert_allclose(values / values[0], (heights[0] / heights) ** 2, rtol=0.01)
    np.testing.assert_allclose(values, 0.5 / np.pi / heights**2, rtol=0.01)


@pytest.mark.parametrize("azimuth", [0.0, 2.0])
def test_cosine_law(lambertian, azimuth):
    p = _centre(lambertian, PIXEL)
    angles = np.radians([0, 20, 40, 60, 75])
    d = 0.3
    lights = [p + d * np.array([np.sin(a) * np.cos(azimuth), np.sin(a) * np.sin(azimuth),
                                np.cos(a)]) for a in angles]
    values = np.array([_value(lambertian, light) for light in lights])
    np.testing.assert_allclose(values / values[0], np.cos(angles), rtol=0.01)


def test_light_below_the_surface_is_an_attached_shadow(lambertian):
    p = _centre(lambertian, PIXEL)
    assert _value(lambertian, p + [0.1, 0.0, -0.01]) == 0.0


def _mirror_target(p, n, v, z):
    """Where the view direction ``v`` mirrored about ``n`` at ``p`` reaches height ``z``."""
    refl = 2 * np.dot(n, v) * n - v
    return p[0] + (z - p[2]) * refl[0] / refl[2]


@pytest.mark.parametrize(
    ("slope", "camera"),
    [(0.0, None), (0.0, PinholeCamera(0.15, 0.0, 0.5, 800.0)), (0.12, None)],
    ids=["flat-orthographic", "flat-pinhole", "tilted-orthographic"],
)
def test_specular_peak_sits_at_the_mirror_position(slope, camera):
    x = (np.arange(16) + 0.5 - 8) * PITCH
    height = np.tile(slope * x, (16, 1))  # a tilted plane h = slope * X
    mirror = uniform_scene(height, albedo=0.0, spec=1.0, roughness=0.05, metallic=1.0)
    p = _centre(mirror, PIXEL)
    n = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)
    v = np.array([0.0, 0.0, 1.0]) if camera is None else \
        (np.array([camera.p, camera.q, camera.distance]) - p)
    v = v / np.linalg.norm(v)
    z, step = 0.3, 1e-3
    rs = np.arange(-0.3, 0.3, step)
    values = [_value(mirror, [r, p[1], z], camera=camera) for r in rs]
    assert abs(rs[int(np.argmax(values))] - _mirror_target(p, n, v, z)) <= step


def test_gold_highlight_is_coloured():
    gold = make_scene("icon", size=32)
    yx = (1, 1)  # on the gilded border
    assert gold.metallic[yx] == 1.0
    light = _centre(gold, yx) + [0, 0, 0.3]
    rgb = render_frame(gold, light)[yx]
    assert rgb[0] > rgb[1] > rgb[2] > 0


def test_cast_shadow_matches_reference_ray_test(block_scene):
    pixels = [(24, 20), (24, 38), (5, 30), (41, 26)]  # left, right, above and below the block
    rs = np.linspace(-0.2, 0.2, 13)
    lights = np.array([[r, s, 0.1] for r in rs for s in rs])
    frames = render_frames(block_scene, lights)
    occluded_any = 0
    for yx in pixels:
        occluded = np.array([is_occluded(block_scene, yx, light) for light in lights])
        values = frames[:, yx[0], yx[1], 1]
        np.testing.assert_array_equal(values == 0, occluded)
        assert np.all(values[~occluded] > 0)
        occluded_any += occluded.sum()
    assert 0.05 * len(lights) * len(pixels) < occluded_any < 0.5 * len(lights) * len(pixels)


def test_shadow_geometry_of_a_wall(block_scene):
    yx = (24, 20)  # X = -3.5 mm; the block's bilinear face rises over X in [-0.5, 0.5] mm
    p = _centre(block_scene, yx)

    def ray_height(r, x_face):  # height of the ray to (r, Y, 0.1) above X = x_face
        return 0.1 * (x_face - p[0]) / (r - p[0])

    assert ray_height(0.1, 0.5e-3) < 6e-3 and ray_height(0.03, -0.5e-3) > 6e-3
    for r, expect in ((0.1, True), (0.2, True), (0.03, False), (p[0], False), (-0.2, False)):
        assert is_occluded(block_scene, yx, [r, p[1], 0.1]) is expect
        assert bool(render_frame(block_scene, [r, p[1], 0.1])[yx][1] == 0) is expect


@pytest.mark.parametrize("camera", [None, PinholeCamera(0.05, -0.02, 0.6, 500.0)])
def test_ltm_columns_are_frames_at_cell_centres(camera):
    scene = make_scene("relief", size=24, seed=1)
    plane = Plane((-0.2, 0.2), (-0.1, 0.2), 0.25)
    lattice = Lattice.from_plane(plane, (4, 3))
    ltm = render_ltm(scene, lattice, plane.height, camera=camera)
    assert ltm.shape == (24, 24, 4, 3, 3) and ltm.dtype == np.float32
    r, s = lattice.centres(0), lattice.centres(1)
    for i, j in np.ndindex(4, 3):
        frame = render_frame(scene, (r[i], s[j], plane.height), camera=camera)
        np.testing.assert_array_equal(ltm[:, :, i, j], frame)


def test_render_frames_stacks_frames():
    scene = make_scene("canvas", size=16)
    lights = np.array([[0.0, 0.0, 0.3], [0.1, -0.1, 0.2]])
    frames = render_frames(scene, lights, intensity=2.0)
    assert frames.shape == (2, 16, 16, 3)
    np.testing.assert_allclose(frames[1], 2.0 * render_frame(scene, lights[1]), rtol=1e-6)


@pytest.mark.parametrize("name", SCENES)
def test_scenes_are_seeded_and_plausible(name):
    a, b = make_scene(name, size=48, seed=0), make_scene(name, size=48, seed=0)
    np.testing.assert_array_equal(a.height, b.height)
    assert not np.array_equal(a.height, make_scene(name, size=48, seed=1).height)
    assert a.pixel_size == pytest.approx(0.2 / 48)
    assert a.albedo.shape == (48, 48, 3) and 0 <= a.albedo.min() and a.albedo.max() <= 1
    assert np.all(np.isfinite(a.normals())) and a.height.min() >= 0


def test_scene_features():
    canvas, icon, relief = (make_scene(n, size=64) for n in SCENES)
    assert 0.2e-3 < canvas.height.max() <= 1e-3 and not canvas.metallic.any()
    gold = icon.metallic > 0
    assert 0.05 < gold.mean() < 0.6
    assert np.all(icon.roughness[gold] <= 0.1) and np.all(icon.spec_color[gold][:, 2] < 0.5)
    assert 5e-3 <= relief.height.max() <= 8e-3


def test_errors():
    with pytest.raises(LtmError, match="unknown scene 'oil'; expected one of canvas, icon"):
        make_scene("oil")
    with pytest.raises(LtmError, match=r"light \[0.0, 0.3\] must be three finite numbers"):
        render_frame(make_scene("canvas", size=8), [0.0, 0.3])
    with pytest.raises(LtmError, match="camera distance -1.0 must be a positive number"):
        PinholeCamera(0.0, 0.0, -1.0, 100.0)
    with pytest.raises(LtmError, match="scene size 4 must be an integer of at least 8"):
        make_scene("canvas", size=4)


@pytest.mark.parametrize("lobe", LOBES)
@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.6])
def test_every_lobe_is_a_normalised_distribution(lobe, alpha):
    """The microfacet distributions of :class:`Shading` integrate to one: int D cos dw = 1."""
    theta = np.linspace(0, np.pi / 2, 200001)
    d = _distribution(lobe, np.cos(theta), alpha**2)
    integral = np.trapezoid(d * np.cos(theta) * np.sin(theta) * 2 * np.pi, theta)
    assert integral == pytest.approx(1.0, abs=2e-3)


def test_led_profile_dims_off_axis_pixels_by_cos_power(lambertian):
    p = _centre(lambertian, PIXEL)
    led = Shading(led_exponent=3.0)
    above, aside = p + [0, 0, 0.2], p + [0.2, 0, 0.2]  # 0 and 45 degrees off the LED's axis
    for light, cos in ((above, 1.0), (aside, np.sqrt(0.5))):
        plain = render_frame(lambertian, light)[PIXEL]
        np.testing.assert_allclose(render_frame(lambertian, light, shading=led)[PIXEL],
                                   plain * cos**3, rtol=1e-5)


def test_ambient_floor_lights_a_cast_shadow(block_scene):
    yx, light = (24, 20), np.array([0.2, 0.0, 0.05])  # low light beyond the block: shadowed
    assert is_occluded(block_scene, yx, light)
    ambient = render_frame(block_scene, light, shading=Shading(ambient=0.05))[yx]
    expected = 0.05 * np.asarray(block_scene.albedo)[yx] / 0.05**2
    np.testing.assert_allclose(ambient, expected * (1 - block_scene.metallic[yx]), rtol=1e-5)


def test_mismatched_shading_changes_the_highlight_not_the_diffuse(lambertian):
    p = _centre(lambertian, PIXEL)
    gloss = make_scene("canvas", size=32)
    yx = (16, 16)
    q = _centre(gloss, yx) + [0, 0, 0.3]
    plain, other = render_frame(gloss, q)[yx], render_frame(gloss, q, shading=MISMATCHED)[yx]
    assert abs(other[1] / plain[1] - 1) > 0.05  # the lobe differs where it peaks
    flat = render_frame(lambertian, p + [0, 0, 0.3], shading=Shading(lobe="phong"))[PIXEL]
    np.testing.assert_allclose(flat, render_frame(lambertian, p + [0, 0, 0.3])[PIXEL])


@pytest.mark.parametrize("kwargs", [{"lobe": "cook"}, {"led_exponent": -1.0},
                                    {"ambient": float("nan")}, {"clearcoat_roughness": 0.0}])
def test_bad_shading_is_refused(kwargs):
    with pytest.raises(LtmError, match=next(iter(kwargs))):
        Shading(**kwargs)
