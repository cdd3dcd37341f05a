"""Profile LOD against linear LOD at equal triangles, and the engine's desired-factor hook."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lodsprite.camera import look_at
from lodsprite.gl.target import RenderTarget
from lodsprite.manager import profile_compare as pc
from lodsprite.manager.engine import CrowdEngine
from lodsprite.manager.models import ProgressiveMesh
from lodsprite.manager.scene import build_crowd
from lodsprite.profiles.object_lod import TypeProfile
from lodsprite.profiles.table import ProfileTable


def ball(name: str, radius: float) -> ProgressiveMesh:
    m = trimesh.creation.icosphere(2, radius=radius)
    return ProgressiveMesh(name, m.vertices + [0, 0, radius], m.faces)


@pytest.fixture(scope="module")
def crowd():
    """Two types: 60 small balls on a grid and 8 big ones among them."""
    return build_crowd([ball("a", 0.6)], objects=60, trees=8, tree_model=ball("b", 1.5),
                       spacing=3.0, seed=2)


def table_profile(z0: float) -> TypeProfile:
    """Three LODs, one view; error falls with distance (z0, 2 z0, 4 z0)."""
    e = np.zeros((3, 1, 1, 3))
    e[0, 0, 0] = [0.4, 0.2, 0.05]
    e[1, 0, 0] = [0.1, 0.04, 0.01]
    meta = {"fov_deg": 10.0, "image_size": 100, "z0": z0, "centre": [0.0, 0.0, 1.0]}
    t = ProfileTable(e, e, [0.0], [0.0], [z0, 2 * z0, 4 * z0], [10, 20, 40], [np.nan] * 3,
                     meta)
    return TypeProfile(t, np.array([0.0, 0.5, 1.0]))


PROFILES = {0: table_profile(20.0), 1: table_profile(40.0)}


def viewpoints(crowd):
    e = crowd.extent
    return [look_at((-e, -e, 2.0), (0.0, 0.0, 0.0)), look_at((0.0, -e * 1.2, 4.0),
                                                             (0.0, 0.0, 0.0))]


@pytest.mark.parametrize(("share", "near"), [(1.0, 5.0), (0.75, 5.0), (0.3, 5.0), (0.3, 40.0)])
def test_the_linear_rule_is_tuned_to_the_target_triangles(crowd, share, near):
    views = pc._Views(crowd, viewpoints(crowd), (96, 64), 60.0)
    full = pc._triangles(crowd, views, [np.ones(len(crowd))] * 2)
    least = pc._triangles(crowd, views, [np.zeros(len(crowd))] * 2)
    target = int(least + share * (full - least))
    p, s = pc.match_linear(crowd, views, target, near, 150.0)
    got = pc._triangles(crowd, views, pc.linear_factors(views, near, 150.0, p, s))
    assert abs(got - target) <= 0.02 * target
    # Every object nearer than 40 m is at full detail whatever the exponent: the ranges
    # must shrink; otherwise the exponent alone reaches the target.
    assert (s < 1.0) == (near == 40.0)


def test_profile_and_linear_are_compared_at_equal_triangles(gl, crowd):
    r = pc.profile_vs_linear(gl, crowd, PROFILES, viewpoints(crowd), size=(64, 48),
                             fov_y_deg=60.0, threshold=0.1)
    assert abs(r.triangles_linear - r.triangles_profile) <= 0.02 * r.triangles_profile
    assert r.triangles_profile < r.triangles_full
    assert r.rmse_profile > 0 and r.rmse_linear > 0 and 0 < r.flip_profile < 1
    exact = pc.profile_vs_linear(gl, crowd, PROFILES, viewpoints(crowd)[:1], size=(64, 48),
                                 threshold=0.0)      # threshold 0: every object at full
    assert exact.triangles_profile == exact.triangles_full and exact.rmse_profile == 0.0
    with pytest.raises(ValueError, match="every type"):
        pc.profile_vs_linear(gl, crowd, {0: PROFILES[0]}, viewpoints(crowd))


def test_the_engine_takes_desired_factors_from_its_hook(gl, crowd):
    seen = []

    def hook(viewpoint, transforms, desired, exponent):
        seen.append((transforms.shape, desired.shape, exponent))
        return np.full(len(desired), 0.5)

    t = RenderTarget(gl, 64, 48)
    e = CrowdEngine(gl, crowd, t, "manager", slots=8, active=len(crowd))
    try:
        e.desired_hook = hook
        e.frame(viewpoints(crowd)[0])
        assert seen == [((len(crowd), 4), (len(crowd),), 1.0)]
        assert np.all(e.manager.lod == 0.5)           # every object took the hook's factor
    finally:
        e.release()
        t.release()
