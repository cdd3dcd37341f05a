"""The window's cursor in the dataset's CRS: the ray through a pixel meets a flat UTM DEM
where the closed form says, taken back to easting, northing and height above the datum."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lodsprite import load_scene, terrain_techniques
from lodsprite.camera import look_at
from lodsprite.viewer.controls import CameraController
from lodsprite.viewer.core import ViewerCore
from lodsprite.viewer.cursor import cursor_line, pixel_ray, ray_ground
from terrain.test_imagery import CELL, N0, SIDE, W0, dem


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    return load_scene(str(dem(tmp_path_factory.mktemp("flat"), relief=0.0)), "terrain",
                      None, 2.0)


def test_the_cursor_lands_where_the_closed_form_ray_meets_flat_ground(flat):
    hf = flat.hf
    vp = look_at((300.0, -900.0, 2400.0), (-200.0, 150.0, 600.0))
    size, fov, px, py = (160, 120), 50.0, 37.0, 81.0
    d = pixel_ray(vp, px, py, size, fov)
    o = np.asarray(vp.o)
    t = (600.0 - o[2]) / d[2]  # the ground: 300 m, exaggerated twice
    want = o + t * d
    got = ray_ground(hf, o, d)
    assert np.allclose(got, want, atol=0.05)
    line = cursor_line(hf, vp, px, py, size, fov)
    e = W0 + CELL / 2 + (SIDE - 1) * CELL / 2 + want[0]  # the samples are the cells' centres
    n = N0 - CELL / 2 - (SIDE - 1) * CELL / 2 + want[1]
    assert f"E {e:.1f} N {n:.1f} (EPSG:32614)" in line
    assert "height 300.0 m" in line and "exaggeration 2.00x" in line
    sky = cursor_line(hf, look_at((0, 0, 2000.0), (0, 5000.0, 2500.0)), 80, 10, size, fov)
    assert sky == "exaggeration 2.00x"  # a ray into the sky meets nothing
    assert math.isfinite(float(line.split("height ")[1].split()[0]))


def test_the_window_hud_shows_the_cursor_and_the_exaggeration(gl, flat):
    from lodsprite.gl.target import RenderTarget

    factories = terrain_techniques(16, 1.0, threaded=False)
    core = ViewerCore(gl.mgl, flat, (96, 96), factories, "full",
                      CameraController.for_terrain(flat.hf))
    target = RenderTarget(gl, 96, 96)
    try:
        core.frame(0.0, target.fbo)
        assert core.hud.cursor == "exaggeration 2.00x"
        core.pointer(48.0, 60.0)
        core._panel_at = -math.inf  # the panel is laid out again at its next frame
        core.frame(0.0, target.fbo)
        assert core.hud.cursor.startswith("cursor E ") and "(EPSG:32614)" in core.hud.cursor
        assert core.hud.cursor in core.hud.lines()
    finally:
        core.release()
        target.release()
