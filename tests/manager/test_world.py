"""A crowd as a world on its ground (what a page and a widget are served): every member
and tree an instance of its type where the crowd has it, on flat ground covering the
crowd's own ground square, textured as its ground shader colours it."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.manager.run import CrowdConfig, make_crowd
from lodsprite.manager.world import (
    FIELD_RGB,
    GROUND_SCALE,
    LINE_RGB,
    crowd_ground,
    crowd_world,
    ground_texture,
    world_scene,
)
from lodsprite.scene.kinds import open_scene


@pytest.fixture(scope="module")
def crowd():
    return make_crowd(CrowdConfig(objects=60, trees=7))


def test_every_member_and_tree_stands_where_the_crowd_has_it(crowd) -> None:
    ground = crowd_ground(crowd)
    world = crowd_world(crowd, ground)
    assert world.count == len(crowd) and not world.moving().any()
    poses = world.poses(3.0)  # nothing walks: the same at any time
    order = np.concatenate([np.flatnonzero(crowd.types == t) for t in range(2)])
    np.testing.assert_allclose(poses[:, :2], crowd.positions[order, :2], atol=1e-4)
    np.testing.assert_allclose(poses[:, 2], 0.0)
    turn = np.angle(np.exp(1j * (poses[:, 3] - crowd.yaw[order])))  # headings mod 2 pi
    np.testing.assert_allclose(turn, 0.0, atol=1e-6)
    assert [t.model for t in world.types] == crowd.models  # the same LOD meshes
    for t, m in zip(world.types, crowd.models, strict=True):
        assert len(t.faces) == m.triangles(1.0) and 0 < t.lod_floor < 1
    lo, hi = world.extent
    np.testing.assert_allclose(hi, GROUND_SCALE * crowd.extent)
    np.testing.assert_allclose(lo, -GROUND_SCALE * crowd.extent)


def test_the_ground_texture_has_the_shaders_lines_every_8_m() -> None:
    tex = ground_texture(40.0)  # 80 m at 0.25 m a texel
    assert tex.shape == (320, 320, 3)
    line = np.round(np.array(LINE_RGB) * 255)
    field = np.round(np.array(FIELD_RGB) * 255)
    # texel centres at -39.875 + 0.25 k: x = -40 + 8 j is a line, 4 m from it is not
    col = lambda x: int((x + 40.0) / 0.25)  # noqa: E731
    np.testing.assert_array_equal(tex[10, col(-32.0)], line)
    np.testing.assert_array_equal(tex[10, col(0.0)], line)
    assert (tex[:, col(-28.1)] == line).all(axis=1).sum() == 20  # only its row lines
    np.testing.assert_array_equal(tex[col(4.1), col(4.1)], field)
    assert ground_texture(10_000.0).shape[0] == 2048  # capped


def test_a_crowd_scene_becomes_a_scene_of_objects_on_the_ground() -> None:
    scene = world_scene(open_scene("crowd:30:3", light=True))
    assert scene.layers == ("terrain", "objects") and scene.texture is not None
    assert not scene.hf.heights.any()
    walk = scene.path("walk", 8)
    assert len(walk.viewpoints) == 8 and walk.viewpoints[0].o[2] == pytest.approx(1.7)
    assert scene.path("flyover", 5).viewpoints  # the built-in paths over its ground
    terrain = open_scene("fractal:64:1", light=True)
    assert world_scene(terrain) is terrain  # no crowd: as it is
