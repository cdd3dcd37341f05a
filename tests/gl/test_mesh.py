"""Flat-shaded instanced meshes: analytic shading, per-instance placement and albedo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lodsprite.camera import look_at, perspective
from lodsprite.gl.mesh import MeshDrawer, MeshSet
from lodsprite.profiles.scenes import placement

# A unit square in the xy-plane facing +z (counter-clockwise seen from +z).
QUAD = (np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32),
        np.array([[0, 1, 2], [0, 2, 3]], np.int32))


@pytest.fixture
def scene(gl):
    renderer = MeshDrawer(gl, 64, 64, samples=4)
    meshes = MeshSet(gl, [QUAD, QUAD])
    yield gl, renderer, meshes
    renderer.forget(meshes)
    meshes.release()
    renderer.release()


def view_proj() -> np.ndarray:
    vp = look_at(np.array([0.0, 0.0, 5.0]), np.zeros(3), up=(0.0, 1.0, 0.0))
    return perspective(30.0, 1.0, 1.0, 10.0) @ vp.view_matrix()


@pytest.mark.parametrize("angle_deg", [0.0, 60.0, 100.0])
def test_lambert_shading_of_a_face(scene, angle_deg):
    _, renderer, meshes = scene
    a = math.radians(angle_deg)
    light = (math.sin(a), 0.0, math.cos(a))
    models = placement(np.zeros((1, 3)), 2.0)
    n = renderer.render(meshes, np.array([0]), models, view_proj(), light, ambient=0.2)
    assert n == 2
    lum = renderer.read_luminance()
    expected = 0.2 + 0.8 * max(math.cos(a), 0.0)
    assert lum[32, 32] == pytest.approx(expected, abs=1e-5)
    assert lum[0, 0] == 0.0                                    # background


def test_instances_placed_and_coloured(scene):
    _, renderer, meshes = scene
    # Two quads left and right of centre, different levels and albedos.
    models = placement(np.array([[-0.8, 0, 0], [0.8, 0, 0]]), 0.5)
    albedo = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    n = renderer.render(meshes, np.array([1, 0]), models, view_proj(), (0, 0, 1),
                        albedo=albedo, ambient=0.0)
    assert n == 4
    rgb = renderer.read_rgb8()
    # Projected centres: x = +-0.8 at distance 5 with a 30 degree field of view.
    px = 0.8 / (5 * math.tan(math.radians(15))) * 32
    left, right = rgb[32, round(32 - px)], rgb[32, round(32 + px)]
    assert list(left) == [255, 0, 0] and list(right) == [0, 0, 255]
    assert list(rgb[32, 32]) == [0, 0, 0]


def test_multisampled_edges_are_partial(scene):
    _, renderer, meshes = scene
    models = placement(np.zeros((1, 3)), 1.3) @ _rot_z(0.3)
    renderer.render(meshes, np.array([0]), models, view_proj(), (0, 0, 1), ambient=1.0)
    lum = renderer.read_luminance()
    assert np.any((lum > 0.1) & (lum < 0.9))                  # antialiased coverage
    assert renderer.samples >= 1


def _rot_z(a: float) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return m
