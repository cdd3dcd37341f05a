"""The widget's kernel side without a browser: what a front end may send (hostile until
validated), what Python may pass (one typed error), and what the views get back, over
real renderer processes and the web server's sessions."""

import asyncio
import threading
import time

import numpy as np
import pytest

pytest.importorskip("anywidget", reason="the notebook extra")

from lodsprite.distributed.protocol import ProtocolError  # noqa: E402
from lodsprite.distributed.web.wire import pack_message, unpack  # noqa: E402
from lodsprite.errors import InputError, LodspriteError  # noqa: E402
from lodsprite.notebook.bundle import import_order, widget_esm  # noqa: E402
from lodsprite.notebook.messages import MAX_PNG_BYTES, decode_front  # noqa: E402

VIEW = "0123456789abcdef"
TERRAIN = dict(grid=64, lod=8, size=(96, 96))
DEADLINE_S = 30.0


def load_message(terrain="fractal:64:4", seq=1):
    return pack_message({"kind": "control", "seq": seq, "op": "load",
                         "args": {"terrain": terrain, "size": [96, 96], "lod": 8,
                                  "grid": 64, "epsilon": 1.0, "visibility": "coarse"}})


@pytest.mark.parametrize("content, buffers, why", [
    ({"kind": "nope", "view": VIEW}, [], "unknown kind"),
    ({"view": VIEW}, [], "no kind"),
    ("wire", [], "not a map"),
    ({"kind": "wire", "view": "../../etc"}, [b"x"], "a view id not 16 hex digits"),
    ({"kind": "wire", "view": VIEW}, [], "a wire message without its buffer"),
    ({"kind": "wire", "view": VIEW}, [b"a", b"b"], "two buffers"),
    ({"kind": "closed", "view": VIEW}, [b"a"], "a buffer where none is expected"),
    ({"kind": "status", "view": VIEW, "stats": {"frames": "many"}}, [], "a string figure"),
    ({"kind": "status", "view": VIEW, "stats": {}, "camera": [0.0] * 11}, [], "11 numbers"),
    ({"kind": "status", "view": VIEW, "stats": {}, "extra": 1}, [], "an unknown field"),
    ({"kind": "shot", "view": VIEW, "id": -1}, [b"png"], "a negative id"),
    ({"kind": "failed", "view": VIEW, "error": "x" * 5000}, [], "an error over 4000"),
])
def test_hostile_front_end_messages_are_refused(content, buffers, why):
    with pytest.raises(ProtocolError):
        decode_front(content, buffers)


def test_a_buffer_over_its_cap_is_refused_before_it_is_copied():
    big = memoryview(bytearray(MAX_PNG_BYTES + 1))
    with pytest.raises(ProtocolError, match="at most"):
        decode_front({"kind": "shot", "view": VIEW, "id": 1}, [big])
    msg, data = decode_front({"kind": "shot", "view": VIEW, "id": 1}, [b"\x89PNG"])
    assert msg.id == 1 and data == b"\x89PNG"


def test_the_front_end_runs_the_page_modules_in_import_order():
    esm = widget_esm()
    assert "startApp" in esm and "/*__MODULES__*/null" not in esm
    sources = {"a.js": "import { b } from './b.js';", "b.js": "import { c } from './c.js';",
               "c.js": "export const c = 1;"}
    assert import_order(sources) == ["c.js", "b.js", "a.js"]
    with pytest.raises(LodspriteError, match="cycle"):
        import_order({**sources, "c.js": "import { a } from './a.js';"})
    with pytest.raises(LodspriteError, match="not shipped"):
        import_order({"a.js": "import { x } from './x.js';"})


@pytest.mark.parametrize("kwargs, match", [
    (dict(source="no/such/dem.tif"), "not found"),
    (dict(source="fractal:63"), "power of two"),
    (dict(source="fractal:64:4", size=(5, 5)), "widget"),
    (dict(source="fractal:64:4", epsilon=-1.0), "widget"),
    (dict(source="fractal:64:4", visibility="sometimes"), "widget"),
    (dict(source="fractal:64:4", path="nowhere"), "path 'nowhere'"),
])
def test_bad_python_arguments_are_one_input_error(kwargs, match):
    import lodsprite

    with pytest.raises(InputError, match=match) as err:
        lodsprite.widget(kwargs.pop("source"), **kwargs)
    assert "\n" not in str(err.value)


def test_errors_show_as_one_line_in_ipython(capsys):
    from IPython.core.interactiveshell import InteractiveShell

    from lodsprite.notebook import one_line_errors

    shell = InteractiveShell.instance()
    try:
        one_line_errors()  # the handler goes on the running shell
        shell.run_cell("import lodsprite\nlodsprite.widget('fractal:64', size=(5, 5))")
        out = capsys.readouterr()
        text = (out.out + out.err).strip()
        assert text.startswith("InputError: widget:") and "\n" not in text, text
        assert "Traceback" not in text
    finally:
        shell.set_custom_exc((), None)
        InteractiveShell.clear_instance()


def widget_with_outbox():
    """A sprite widget whose messages to the front end are kept in a list."""
    import lodsprite

    w = lodsprite.widget("fractal:64:4", **TERRAIN)
    sent = []
    w._core.send = lambda content, buffers: sent.append((content, buffers))
    return w, sent


async def wait_for(pred, deadline_s=DEADLINE_S):
    end = time.monotonic() + deadline_s
    while not pred():
        assert time.monotonic() < end, "no answer within the deadline"
        await asyncio.sleep(0.02)


def replies(sent, view=VIEW):
    """The web messages sent to ``view``, as (header dict, buffers)."""
    import msgspec

    out = []
    for content, buffers in sent:
        if content.get("kind") == "wire" and content.get("view") == view:
            parts = unpack(buffers[0], max_bytes=1 << 30)
            out.append((msgspec.msgpack.decode(parts[0]), parts[1:]))
    return out


def test_a_view_survives_hostile_messages_and_loads_only_its_own_terrain():
    async def main():
        w, sent = widget_with_outbox()
        try:
            core = w._core
            for content, buffers in [({"kind": "wire"}, [b"x"]), ([], None),
                                     ({"kind": "wire", "view": VIEW}, [b"\x00" * 7])]:
                w._on_front(w, content, buffers)  # never raises
            assert core.counts["rejected"] == 2
            w._on_front(w, {"kind": "wire", "view": VIEW}, [load_message("jacksboro", 5)])
            w._on_front(w, {"kind": "wire", "view": VIEW}, [load_message("fractal:64:4", 6)])
            await wait_for(lambda: any(h.get("seq") == 6 and h.get("kind") == "reply"
                                       for h, _ in replies(sent)))
            got = {h["seq"]: h for h, _ in replies(sent) if h["kind"] == "reply"}
            assert got[0]["ok"] is False  # the malformed web message, answered
            assert got[5]["ok"] is False and "this widget shows" in got[5]["error"]
            assert got[6]["ok"] is True
            scene = [(h, b) for h, b in replies(sent) if h["kind"] == "scene"]
            assert len(scene) == 1 and scene[0][0]["coarse"] == 8
        finally:
            w.close()

    asyncio.run(main())


def test_a_request_gets_a_keyframe_and_close_ends_the_renderers():
    async def main():
        w, sent = widget_with_outbox()
        procs = w._core.pool.local_processes()
        try:
            w._on_front(w, {"kind": "wire", "view": VIEW}, [load_message()])
            await wait_for(lambda: any(h["kind"] == "scene" for h, _ in replies(sent)))
            vp = {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.0, 1.0], "z": [0.0, -1.0, 0.0],
                  "o": [960.0, -400.0, 600.0]}
            w._on_front(w, {"kind": "wire", "view": VIEW},
                        [pack_message({"kind": "request", "seq": 2, "t": 1.5,
                                       "viewpoint": vp})])
            await wait_for(lambda: any(h["kind"] == "keyframe" for h, _ in replies(sent)))
            key = next(h for h, _ in replies(sent) if h["kind"] == "keyframe")
            assert key["seq"] == 2 and key["t0"] == 1.5
            assert np.allclose(key["viewpoint"]["o"], vp["o"])
            w._on_front(w, {"kind": "status", "view": VIEW, "stats": {"frames": 3.0},
                            "camera": [*vp["x"], *vp["y"], *vp["z"], *vp["o"]],
                            "state": "flying"}, [])
            assert w.stats["frames"] == 3 and w.stats["state"] == "flying"
            w.reset_stats()
            assert sent[-1][0] == {"kind": "reset"} and w.stats["frames"] == 0
            w._on_front(w, {"kind": "status", "view": VIEW, "stats": {"frames": 0.0},
                            "camera": [*vp["x"], *vp["y"], *vp["z"], *vp["o"]]}, [])
            assert np.allclose(w.camera.o, vp["o"])
            w._on_front(w, {"kind": "closed", "view": VIEW}, [])
            assert not w._core.views
        finally:
            w.close()
        assert all(not p.is_alive() for p in procs)
        with pytest.raises(LodspriteError, match="closed"):
            w.stop()

    asyncio.run(main())


def test_camera_and_screenshot_refuse_what_cannot_be_done():
    async def main():
        w, sent = widget_with_outbox()
        try:
            with pytest.raises(InputError, match="12"):
                w.camera = [1.0, 2.0, 3.0]
            with pytest.raises(InputError, match="camera"):
                w.camera = [1.0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0]  # x == y
            with pytest.raises(LodspriteError, match="no view"):
                await w.screenshot(timeout=1)
            with pytest.raises(LodspriteError, match="play"):
                await w.played(timeout=1)
            w.camera = [1.0, 0, 0, 0, 0, 1.0, 0, -1.0, 0, 5.0, 6.0, 7.0]
            assert sent[-1][0] == {"kind": "camera",
                                   "viewpoint": [1.0, 0, 0, 0, 0, 1.0, 0, -1.0, 0, 5.0, 6.0,
                                                 7.0]}
        finally:
            w.close()

    asyncio.run(main())


def test_messages_from_a_subshell_thread_are_handled_on_the_widgets_own_loop():
    """JupyterLab sends widget messages to a kernel subshell (ipykernel 7): its thread
    hands each to the widget's loop, where the cell awaiting ``played()`` runs."""
    async def main():
        w, sent = widget_with_outbox()
        try:
            w.play("chen1999", frames=4)
            handled = []
            core_handle = w._core.handle
            w._core.handle = lambda c, b: (handled.append(threading.get_ident()),
                                           core_handle(c, b))
            subshell = threading.Thread(target=w._on_front, args=(
                w, {"kind": "played", "view": VIEW, "frames": 4}, []))
            subshell.start()
            subshell.join()
            assert await w.played(timeout=DEADLINE_S) == 4
            assert handled == [threading.get_ident()]
        finally:
            w.close()

    asyncio.run(main())


def test_a_scene_file_widget_draws_spriteframes_unless_asked_to_stream(tmp_path):
    """A scene file is a sprite widget (its walkers in the scene message, keyframes of
    what stands); with ``stream=True`` a stream widget (the comparison)."""
    import lodsprite
    from lodsprite.notebook.sprite import SpriteWidget

    scene = tmp_path / "few.toml"
    scene.write_text('[terrain]\nsource = "fractal:64:4"\n[[objects]]\nmesh = "ogre"\n'
                     'height_m = 40.0\ncount = 12\nwalk_mps = 3.0\n')

    async def main():
        w = lodsprite.widget(scene, lod=8, size=(96, 96))
        assert isinstance(w, SpriteWidget)
        sent = []
        w._core.send = lambda content, buffers: sent.append((content, buffers))
        try:
            w._on_front(w, {"kind": "wire", "view": VIEW}, [pack_message(
                {"kind": "control", "seq": 1, "op": "load",
                 "args": {"terrain": "few.toml", "size": [96, 96], "lod": 8,
                          "visibility": "fragment"}})])
            await wait_for(lambda: any(h["kind"] == "scene" for h, _ in replies(sent)))
            header = next(h for h, _ in replies(sent) if h["kind"] == "scene")
            assert header["walkers"]["count"] == 12
            vp = {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.6, 0.8], "z": [0.0, -0.8, 0.6],
                  "o": [0.0, -1500.0, 2600.0]}
            w._on_front(w, {"kind": "wire", "view": VIEW}, [pack_message(
                {"kind": "request", "seq": 2, "t": 0.5, "viewpoint": vp})])
            await wait_for(lambda: any(h["kind"] == "keyframe" for h, _ in replies(sent)))
            key = next(h for h, _ in replies(sent) if h["kind"] == "keyframe")
            assert key["zbuffer"] == "full"
        finally:
            w.close()

    asyncio.run(main())
    streamed = lodsprite.widget(scene, stream=True)
    try:
        assert type(streamed).__name__ == "StreamWidget"
    finally:
        streamed.close()


def test_a_crowd_widget_draws_spriteframes_and_a_light_field_streams(tmp_path):
    """``crowd:N`` is a sprite widget (the crowd's world on its ground, in keyframes);
    a light field's folder, which the page does not draw, a stream widget."""
    import lodsprite
    from lodsprite.notebook import _scene_kind
    from lodsprite.notebook.sprite import SpriteWidget

    async def main():
        w = lodsprite.widget("crowd:40:4", lod=8, size=(64, 64))
        try:
            assert isinstance(w, SpriteWidget)
            assert w.options["terrain"] == "crowd:40:4"
        finally:
            w.close()

    asyncio.run(main())
    lf = tmp_path / "lf"
    lf.mkdir()
    (lf / "lumigraph.json").write_text("{}")
    assert _scene_kind(str(lf)) and not _scene_kind("crowd:40") and not _scene_kind(
        "fractal:64")
