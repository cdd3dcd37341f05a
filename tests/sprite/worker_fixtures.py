"""Fixtures of the keyframe worker's tests (imported by them): a small ridged terrain
and a sprite drawer on the session's context (tests/conftest.py's ``gl``)."""

from __future__ import annotations

import pytest

from conftest import make_field
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
from lodsprite.scene import Scene
from lodsprite.terrain import make_texture

SIZE = (96, 96)


@pytest.fixture
def scene() -> Scene:
    hf = make_field(64, kind="ridges")
    return Scene(hf, make_texture("terrain", hf), "ridges", "terrain")


@pytest.fixture
def sprite(gl, scene):
    """A :class:`SpriteDrawer` of :data:`SIZE` pixels, coarse level 8, guard band 4."""
    geo = TerrainGeometry(gl, scene.hf, scene.texture)
    tr = TerrainDrawer(gl, geo, *SIZE)
    sp = SpriteDrawer(tr, 8, guard_px=4)
    yield sp
    sp.release()
    tr.release()
    geo.release()
