"""``lodsprite view LF``: the lumigraph's methods driven through the viewer's technique
interface, headless (a :class:`ViewerCore` on the session's context, offscreen)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lodsprite import techniques
from lodsprite.gl.target import RenderTarget
from lodsprite.lumigraph.run import capture_lumigraph
from lodsprite.lumigraph.technique import VIEW_METHODS, to_lumigraph
from lodsprite.scene import open_scene
from lodsprite.viewer.controls import CameraController
from lodsprite.viewer.core import ViewerCore

SIZE = (96, 96)


@pytest.fixture(scope="module")
def lf_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("view") / "lf"
    capture_lumigraph("still-life", folder, n_st=8, n_uv=48, codec="png")
    return folder


def test_the_home_view_looks_at_the_object_from_in_front(lf_dir):
    from lodsprite.lumigraph.store import Lumigraph

    centre = Lumigraph(lf_dir).slabs[0].frame[:3, 3]
    home = CameraController.from_home(open_scene(str(lf_dir)).camera_home())
    vp = to_lumigraph(home.viewpoint)
    # in the lumigraph's world the eye is in front of the object (+z), looking at it
    to = centre - vp.o
    assert -to[2] > Lumigraph(lf_dir).slabs[0].st_distance
    np.testing.assert_allclose(vp.forward, to / np.linalg.norm(to), atol=1e-6)


STATUS = re.compile(r"(\d+) node images, (\d+) uploaded; texture (\d+)/(\d+) "
                    r"\(([\d.]+) MB\); decoded (\d+)")


def assert_status_is_the_last_frames(tech, name: str) -> None:
    """The status line states the last frame's node images and uploads, the texture's
    residency and size and the nodes decoded, and they are consistent."""
    m = STATUS.fullmatch(tech.status())
    assert m, (name, tech.status())
    images, uploads, resident, capacity, mb, decoded = m.groups()
    f, rec = tech._last, tech.method.rec
    assert (int(images), int(uploads)) == (f.extra["images"], f.extra["uploads"]), name
    assert (int(resident), int(capacity)) == (len(rec.slot_of), rec.capacity), name
    assert float(mb) == pytest.approx(rec.capacity * rec.node_bytes / 2 ** 20, abs=0.05)
    assert int(decoded) <= tech.method.loader.decoded, name   # the loader decodes on
    # a frame that drew the object drew node images (or reused the projective method's
    # last image: none); those it drew are resident, and were decoded
    assert (int(images) == 0) == (f.kind == "reuse"), name
    assert 1 <= int(resident) <= int(capacity), name
    assert int(decoded) >= int(resident) and int(uploads) <= int(capacity), name


def test_every_method_draws_the_object_in_the_viewer_and_keys_switch(gl, lf_dir):
    scene = open_scene(str(lf_dir))  # the registry's modes for its light field
    assert scene.layers == ("lightfield",) and scene.mode == "critical"
    modes = techniques.factories(scene.layers)
    assert tuple(modes) == VIEW_METHODS
    core = ViewerCore(gl.mgl, scene, SIZE, modes, "critical",
                      CameraController.from_home(scene.camera_home()))
    target = RenderTarget(gl, *SIZE)
    try:
        for k, name in enumerate(VIEW_METHODS):
            core.key(str(k + 1))
            assert core.mode == name
            for _ in range(2):
                core.frame(1 / 30, target.fbo)
                core.log_frame()
            img = core.technique.read_image().astype(float)
            # the object (the red sphere at its centre) fills the middle of the view
            mid = img[40:56, 40:56]
            assert mid.mean() > 40 and (mid[..., 0] > mid[..., 2]).mean() > 0.5, name
            assert_status_is_the_last_frames(core.technique, name)
            # the HUD shows the technique's last frame and, once refreshed, its status
            f = core.technique._last
            assert core.hud.frame_type == f.kind
            assert core.hud.triangles == core.technique.method.rec.vertex_count // 3
            core._panel_at = -np.inf
            core.frame(1 / 30, target.fbo)
            core.log_frame()
            # (what is decoded moves on beside the frames: compared up to there)
            shown, now = core.hud.status, core.technique.status()
            assert STATUS.fullmatch(shown) and core.hud.mode == name
            assert shown.split("; decoded")[0] == now.split("; decoded")[0]
        core.key("1")
        before = core.technique.params()["fps"].value
        core.key("]")
        assert core.technique.params()["fps"].value == pytest.approx(before * 1.25)
        assert core.summary()["frames"] == 3 * len(VIEW_METHODS)
    finally:
        core.release()
        target.release()
