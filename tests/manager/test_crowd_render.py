"""The crowd's drawing and engine on the real GL driver."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.camera import look_at, perspective
from lodsprite.gl.crowd import CrowdDrawer
from lodsprite.gl.target import RenderTarget
from lodsprite.manager.builtins import ogre
from lodsprite.manager.engine import CrowdEngine, discrete_levels
from lodsprite.manager.scene import build_crowd, walkthrough

SIZE = (128, 96)


@pytest.fixture(scope="module")
def member():
    return ogre()


def test_instanced_drawing_of_a_shared_lod_equals_drawing_one_by_one(gl, member):
    crowd = build_crowd([member], objects=25, spacing=3.0)
    r = CrowdDrawer(gl, crowd.models, crowd.extent)
    t = RenderTarget(gl, *SIZE)
    try:
        r.set_indices(0, 0, member.extract(0.5))
        r.upload_instances(np.concatenate([crowd.positions, crowd.yaw[:, None]], 1))
        vp = perspective(60.0, SIZE[0] / SIZE[1], 0.3, 200.0) @ look_at(
            (0.0, -14.0, 6.0), (0.0, 0.0, 1.0)).view_matrix()
        r.draw(vp, t.fbo, [(0, 0, len(crowd))])
        together, calls = t.read_color(), r.draw_calls
        r.draw(vp, t.fbo, [(0, i, 1) for i in range(len(crowd))])
        apart = t.read_color()
        assert calls == 2 and r.draw_calls == len(crowd) + 1   # the ground is one more
        assert np.array_equal(together, apart)
        assert (together != together[0, 0]).any(axis=2).mean() > 0.1  # the crowd is there
    finally:
        r.release()
        t.release()


def test_the_manager_shares_what_independent_objects_extract_themselves(gl, member):
    crowd = build_crowd([member], objects=400, spacing=3.0)
    path = walkthrough(crowd, 12)
    out = {}
    for mode in ("manager", "independent"):
        t = RenderTarget(gl, *SIZE)
        e = CrowdEngine(gl, crowd, t, mode, slots=8, active=100, range_far=60.0)
        try:
            frames = [e.frame(vp) for vp in path.viewpoints]
            out[mode] = (sum(f.extra["extractions"] for f in frames),
                         frames[-1].extra["draw_calls"],
                         t.read_color())
        finally:
            e.release()
            t.release()
    (ext_m, calls_m, img_m), (ext_i, calls_i, img_i) = out["manager"], out["independent"]
    assert ext_m <= 8 and ext_i > 5 * ext_m
    assert calls_m <= 9 + 1 < calls_i
    # same buckets, so nearly the same picture
    assert np.abs(img_m.astype(float) - img_i.astype(float)).mean() < 4.0


def test_discrete_levels_switch_with_hysteresis():
    th = (0.25, 0.1, 0.04)
    cur = np.array([3, 3, 0, 1])
    h = np.array([0.26, 0.30, 0.24, 0.08])
    # from level 3, 0.26 passes 0.04 and 0.1 by 15 % but not 0.25: level 1; 0.30 passes
    # 0.25 by 15 %: level 0; 0.24 is under 0.25 by less than 15 %: stays at 0; 0.08 is
    # under 0.1 by 20 %: level 2
    assert discrete_levels(h, cur, th, 0.15).tolist() == [1, 0, 0, 2]
