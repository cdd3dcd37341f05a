"""The adaptive renderer's node grid (``grid``, quads a node side): smaller nodes let a
coarse tolerance draw fewer triangles (the scenes' terrain layer uses 32)."""

from __future__ import annotations

import time

import pytest

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.camera import look_at
from lodsprite.errors import InputError
from lodsprite.scene import load_scene


def settled_triangles(r, grid: int, vp, deadline_s: float = 20.0) -> int:
    """Triangles the adaptive renderer draws at 16 px from ``vp`` once its tiles have
    streamed in (the count stops changing; deadline ``deadline_s``)."""
    t = techniques.create("adaptive", r, sse=16.0, grid=grid)
    try:
        last, same, end = -1, 0, time.monotonic() + deadline_s
        while time.monotonic() < end and same < 5:
            n = t.frame(vp).triangles
            same = same + 1 if n == last else 0
            last = n
            time.sleep(0.02)
        assert same >= 5, "the selection did not settle before the deadline"
        return last
    finally:
        t.release()


def test_a_smaller_node_grid_draws_fewer_triangles_at_a_coarse_tolerance(gl):
    scene = load_scene("fractal:512", "terrain", None, 1.0)
    vp = look_at((0.0, -6000.0, 3000.0), (0.0, 0.0, 0.0))
    with Renderer(scene, (128, 128), 60.0, ctx=gl.mgl) as r:
        t64, t32 = settled_triangles(r, 64, vp), settled_triangles(r, 32, vp)
    assert t32 < t64 and t32 % (32 * 32 * 2) == 0 and t64 % (64 * 64 * 2) == 0


@pytest.mark.parametrize("grid", [0, 24, 512, 32.5])
def test_a_node_grid_outside_the_offered_ones_is_refused(gl, grid):
    scene = load_scene("fractal:64", "terrain", None, 1.0)
    with Renderer(scene, (32, 32), 60.0, ctx=gl.mgl) as r:
        with pytest.raises(InputError, match="option --node-grid: got"):
            techniques.create("adaptive", r, grid=grid)
