"""One scene model (issue 31, must-have 3): a scene file's layers all end up in the
:class:`~lodsprite.scene.Scene`, no object set holds its scene, every kind opens through
:func:`~lodsprite.scene.open_scene`, and :class:`~lodsprite.api.Renderer` draws a scene
without terrain (a crowd) as the crowd technique draws it."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from lodsprite.api import Renderer
from lodsprite.errors import InputError
from lodsprite.scene import LightField, Scene, SceneKind, open_scene, scene_kinds
from lodsprite.scene.world import World


def write_scene_file(folder: Path) -> Path:
    """A flat 512 m terrain, two ogres and one light field folder (its header only: the
    file's checks read no more)."""
    np.save(folder / "flat.npy", np.zeros((17, 17), np.float32))
    (folder / "statue.lf").mkdir()
    (folder / "statue.lf" / "lumigraph.json").write_text("{}")
    p = folder / "scene.toml"
    p.write_text('[terrain]\nsource = "flat.npy"\ngrid = 16\n'
                 '[[objects]]\nmesh = "ogre"\ncount = 2\n'
                 '[[lightfields]]\nsource = "statue.lf"\nposition = [10.0, -20.0]\n'
                 'height_m = 30.0\n'
                 '[view]\npath = "flyover"\nfov = 40.0\n')
    return p


def test_a_scene_file_gives_a_scene_with_all_three_layers(tmp_path):
    """Before, the file's light fields lived only in its world and Scene.lightfield was
    None: a renderer given the scene saw no light field."""
    scene = open_scene(str(write_scene_file(tmp_path)))
    assert scene.layers == ("terrain", "objects", "lightfield")
    assert scene.lightfields == (LightField(tmp_path / "statue.lf", (10.0, -20.0), 30.0),)
    assert scene.lightfield == str(tmp_path / "statue.lf")
    assert isinstance(scene.objects, World) and scene.objects.count == 2
    assert scene.view is not None and scene.view.fov == 40.0
    assert scene.default_path == "flyover" and scene.mode == "scene"


def test_no_object_set_holds_its_scene(tmp_path):
    """The world is the object sets' state: no field of it is (or holds) a Scene, so the
    old loop (world.scene.objects is world) is gone; a crowd holds none either."""
    scene = open_scene(str(write_scene_file(tmp_path)))
    world = scene.objects
    assert not any(isinstance(getattr(world, f.name), Scene) for f in fields(world))
    assert world.ground_field is scene.hf  # it stands on the scene's terrain, no more
    crowd = open_scene("crowd:5").objects
    assert not any(isinstance(getattr(crowd, f.name), Scene) for f in fields(crowd))


def test_every_kind_opens_through_one_opener(tmp_path):
    names = [k.name for k in scene_kinds()]
    assert names[0] == "scene-file" and {"crowd", "lumigraph"} <= set(names)
    assert all(isinstance(k, SceneKind) for k in scene_kinds())
    assert open_scene("crowd:12").layers == ("objects",)
    assert open_scene("fractal:64", grid=32).layers == ("terrain",)
    with pytest.raises(InputError):
        open_scene("crowd:x")


def test_a_crowd_alone_draws_through_the_renderer_as_the_crowd_technique_does(gl):
    """A scene without terrain: Renderer.draw composites its one layer (the crowd on its
    own ground, through its own projection) and read_color reads it.  The reference is
    the crowd technique's own frame at full meshes (LOD exponent 0): every pixel within 2
    levels, and 99.5 % of them equal (rasterisation of the same triangles)."""
    from lodsprite.manager.technique import CrowdTechnique

    scene = open_scene("crowd:30")
    vp = scene.path("walk", 8).viewpoints[3]
    with Renderer(scene, (96, 72), 60.0, ctx=gl.mgl) as r:
        frame = r.draw(vp)
        drawn = r.read_color().astype(int)
        assert frame.triangles > 0 and drawn.shape == (72, 96, 3)
        t = CrowdTechnique(r, scene.objects, "manager", None)
        try:
            t.engine.feedback.exponent = 0.0  # full meshes, as the renderer draws
            t.frame(vp)
            own = t.read_image().astype(int)
        finally:
            t.release()
    diff = np.abs(drawn - own)
    assert len(np.unique(own.reshape(-1, 3), axis=0)) > 3  # crowd and ground in view
    assert diff.max() <= 2 and (diff.max(axis=2) == 0).mean() >= 0.995


def test_a_renderer_of_a_light_field_alone_refuses_to_composite(gl, tmp_path):
    """A light field on its own (a lumigraph folder) has no world to stand in: draw()
    says so in one line rather than drawing an empty frame."""
    scene = Scene(lightfields=(LightField(tmp_path),))
    with Renderer(scene, (32, 32), ctx=gl.mgl) as r, pytest.raises(InputError):
        r.draw(scene.camera_home().home if scene.home else _any_viewpoint())


def _any_viewpoint():
    from lodsprite.camera import look_at

    return look_at((0.0, -10.0, 2.0), (0.0, 0.0, 0.0))


def test_the_wire_description_round_trips_and_hostile_ones_are_refused():
    """A scene's description (what ``load`` carries) decodes to itself, opens the same
    terrain, and is the head of LoadArgs (the same bytes decode as either); the scene
    files' caps refuse what they refuse, before anything is loaded."""
    import msgspec

    from lodsprite.distributed.messages import LoadArgs
    from lodsprite.scene.file import MAX_GRID
    from lodsprite.scene.spec import SceneSpec, describe, open_spec

    scene = open_scene("fractal:64", grid=32)
    spec = describe(scene)  # grid: the working field's 32 quads
    raw = msgspec.msgpack.encode(spec)
    assert msgspec.msgpack.decode(raw, type=SceneSpec) == spec
    np.testing.assert_array_equal(open_spec(spec).hf.heights, scene.hf.heights)
    load = msgspec.msgpack.decode(raw, type=LoadArgs)
    assert (load.terrain, load.texture, load.grid) == ("fractal:64", "terrain", 32)
    for hostile in ({"terrain": "fractal:64", "grid": 2 * MAX_GRID},
                    {"terrain": "fractal:64", "grid": 48},
                    {"terrain": "fractal:64", "exaggeration": 0.0},
                    {"terrain": "x" * 257}, {"terrain": ""},
                    {"terrain": "fractal:64", "objects": "crowd:9"}):
        with pytest.raises(msgspec.ValidationError):
            msgspec.msgpack.decode(msgspec.msgpack.encode(hostile), type=SceneSpec)
    with pytest.raises(InputError):
        describe(open_scene("crowd:3"))


def test_the_web_scene_message_is_made_from_the_scene():
    """A web page's scene message is made from a Scene's terrain layer: its heights are
    the working field's coarse level (row 0 south); a scene without terrain has none."""
    from lodsprite.distributed.messages import LoadArgs
    from lodsprite.distributed.web.scene import decode_scene, scene_parts

    scene = open_scene("fractal:64", grid=32)
    data = decode_scene(scene_parts(scene, LoadArgs(terrain="fractal:64", grid=32, lod=8)))
    np.testing.assert_array_equal(data.heights, scene.hf.heights[::4, ::4][::-1])
    assert data.header.coarse == 8
    with pytest.raises(InputError):
        scene_parts(open_scene("crowd:3"), LoadArgs())
