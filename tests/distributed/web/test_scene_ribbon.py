"""The scene message's border ribbon: the coarse level's ribbons as lodsprite's own
spriteframes draw them (and the server's coarse z-buffer is drawn with them), none when
the load asks for none, and hostile ribbons refused."""

import msgspec
import numpy as np
import pytest

from lodsprite.distributed.protocol import (
    PROTOCOL_VERSION,
    LoadArgs,
    ProtocolError,
    SceneMessage,
)
from lodsprite.distributed.web.scene import build_scene_field, decode_ribbon, decode_scene
from lodsprite.terrain.proxy import border_ribbon

ARGS = {"terrain": "fractal:64:4", "grid": 64, "lod": 8, "size": (64, 64)}


def test_the_scene_carries_the_coarse_levels_border_ribbon():
    parts, hf = build_scene_field(LoadArgs(**ARGS))
    scene = decode_scene(parts)
    want = border_ribbon(hf, 8)
    assert len(want.tris) > 0  # a fractal's border stands off its coarse line
    np.testing.assert_array_equal(scene.ribbon, want.positions)
    np.testing.assert_array_equal(scene.ribbon_tris, want.tris)
    # its vertices lie on the terrain's border, inside the coarse level's extent
    h = scene.header
    lo = np.array(h.origin)
    hi = lo + [h.coarse * h.spacing, h.coarse * h.spacing_y]
    xy = scene.ribbon[:, :2].astype(np.float64)
    assert np.all(xy >= lo - 1e-3) and np.all(xy <= hi + 1e-3)
    on_edge = (np.isclose(xy, lo, atol=1e-2) | np.isclose(xy, hi, atol=1e-2)).any(1)
    assert on_edge.all()


def test_a_load_without_border_gets_a_scene_without_ribbon():
    from lodsprite.distributed.web.scene import scene_key

    args = LoadArgs(**ARGS, border=False)
    scene = decode_scene(build_scene_field(args)[0])
    assert scene.ribbon.shape == (0, 3) and scene.ribbon_tris.shape == (0, 3)
    assert scene_key(args) != scene_key(LoadArgs(**ARGS))  # cached apart


def _message(ribbon: bytes, tris: bytes) -> SceneMessage:
    image = {"shape": [2, 2], "dtype": "float32", "codec": "raw"}
    return msgspec.convert({"v": PROTOCOL_VERSION, "kind": "scene", "seq": 0, "coarse": 1,
                            "origin": [0, 0], "spacing": 1, "spacing_y": 1, "size": [8, 8],
                            "fov": 45, "near": 1, "far": 2, "epsilon": 1, "visibility": "coarse",
                            "heights": image, "texture": image, "ribbon": ribbon,
                            "ribbon_tris": tris}, SceneMessage)


@pytest.mark.parametrize("ribbon, tris, why", [
    (np.zeros(7, "<f4").tobytes(), b"", "not whole"),
    (np.zeros((3, 3), "<f4").tobytes(), np.array([[0, 1, 3]], "<u4").tobytes(), "vertex 3"),
    (np.full((3, 3), np.nan, "<f4").tobytes(), np.array([[0, 1, 2]], "<u4").tobytes(),
     "not finite"),
], ids=["partial", "index", "nan"])
def test_a_hostile_ribbon_is_refused(ribbon, tris, why):
    with pytest.raises(ProtocolError, match=why):
        decode_ribbon(_message(ribbon, tris))
    verts, t = decode_ribbon(_message(np.zeros((3, 3), "<f4").tobytes(),
                                      np.array([[0, 1, 2]], "<u4").tobytes()))
    assert verts.shape == (3, 3) and t.tolist() == [[0, 1, 2]]


def test_a_ribbon_over_the_cap_is_refused_by_the_schema():
    from lodsprite.distributed.messages import MAX_RIBBON_TRIANGLES

    with pytest.raises(msgspec.ValidationError):
        _message(b"", bytes(12 * MAX_RIBBON_TRIANGLES + 12))


def test_a_stores_scene_is_textured_in_its_keyframes_heights_shading(store512):
    """A store's keyframes are shaded from its heights, so the scene message's texture (what
    the page shows where no keyframe saw the surface) is that shading of the working grid,
    not the terrain texture; an in-memory terrain keeps its texture."""
    from lodsprite.distributed.protocol import LoadArgs
    from lodsprite.scene import load_scene
    from lodsprite.terrain.store import TerrainStore
    from lodsprite.terrain.textures import height_shading

    parts, hf = build_scene_field(LoadArgs(terrain=store512, size=(64, 64), lod=8))
    got = decode_scene(parts).texture[::-1]  # the message's rows run south to north
    mm = TerrainStore(store512).minmax(0)
    want = height_shading(hf.heights, hf.dx, hf.dy, float(mm[..., 0].min()),
                          float(mm[..., 1].max()))
    np.testing.assert_array_equal(got, want)
    memory = decode_scene(build_scene_field(LoadArgs(terrain="fractal:64:4", size=(64, 64),
                                                     lod=8))[0]).texture[::-1]
    own = load_scene("fractal:64:4", light=True).texture
    assert memory.shape == own.shape and (memory == own).all()
