"""The streaming widget (jupyter_rfb): every frame rendered in the kernel, flown by the
browser's input events or a path, with the sprite widget's Python API."""

import asyncio
import threading
import time
from io import BytesIO

import numpy as np
import pytest

pytest.importorskip("jupyter_rfb", reason="the notebook extra")

from lodsprite.errors import InputError, LodspriteError  # noqa: E402
from lodsprite.notebook.stream import FIRST_STEP_S  # noqa: E402


def stream(**kw):
    import lodsprite

    w = lodsprite.widget("fractal:64:4", stream=True, size=(64, 48), grid=64, **kw)
    w._has_visible_views = True  # as a displayed view reports
    return w


def with_stream(body, **kw) -> None:
    """Run ``await body(w)`` on a fresh stream ``w`` in an event loop; close it after."""
    async def main():
        w = stream(**kw)
        try:
            await body(w)
        finally:
            w.close()

    asyncio.run(main())


def test_a_path_plays_one_viewpoint_a_frame_and_resolves_played():
    async def main():
        w = stream(path="chen1999", frames=4)
        try:
            path = w.scene.path("chen1999", 4).viewpoints
            shown = []
            for _ in range(4):
                image = w.get_frame()
                shown.append(w.camera.o.copy())
            assert image.shape == (48, 64, 3) and image.dtype == np.uint8
            assert np.allclose(shown, [vp.o for vp in path])
            assert await w.played(timeout=1) == 4
            png = await w.screenshot()
            from PIL import Image

            assert np.array_equal(np.asarray(Image.open(BytesIO(png))), image)
            assert w.stats["frames"] >= 4 and w.stats["median_ms"] is not None  # + held redraws
            w.reset_stats()
            assert w.stats["frames"] == 0 and w.stats["median_ms"] is None
        finally:
            w.close()

    asyncio.run(main())


def test_keys_fly_the_camera_and_are_logged_for_input_to_frame():
    async def body(w):
        w.get_frame()
        before = w.camera
        time.sleep(0.3)  # a pause before the key: no flight, no frame interval
        w.handle_event({"type": "key_down", "key": "W", "timestamp": 1234.5})
        w.get_frame()
        first = w.camera.o - before.o
        assert np.linalg.norm(first) == pytest.approx(w.flight.speed * FIRST_STEP_S)
        assert np.dot(first, -before.z) > 0 and np.allclose(
            np.cross(first, before.z), 0, atol=1e-6 * np.linalg.norm(first))
        assert list(w.inputs) == [(1234.5, w._rfb_frame_index + 1)]
        assert not w._intervals
        at = w.camera.o
        w._last = time.perf_counter() - 0.5  # the next frame half a second on, key held
        w.get_frame()
        assert np.linalg.norm(w.camera.o - at) == pytest.approx(w.flight.speed * 0.5,
                                                                 rel=0.05)
        assert len(w._intervals) == 1
        w.handle_event({"type": "key_up", "key": "w"})
        assert not w.flight.keys
        w.get_frame()
        assert w._last is None  # nothing held: the run ends
        with pytest.raises(InputError):
            w.camera = [0.0] * 12
        with pytest.raises(InputError):
            w.play("nowhere")

    with_stream(body)


def test_screenshot_before_a_frame_says_why():
    async def main():
        w = stream()
        try:
            with pytest.raises(LodspriteError, match="no frame"):
                await w.screenshot()
        finally:
            w.close()

    asyncio.run(main())


def test_the_pages_frame_feedback_is_logged_and_hostile_feedback_ignored():
    async def main():
        w = stream()
        try:
            w._frame_feedback = {"index": 3, "timestamp": 1.0, "localtime": 1700000000.25}
            w._frame_feedback = {"index": "x", "localtime": None}  # from a hostile page
            w._frame_feedback = {"localtime": 2.0}
            assert list(w.shown) == [(3, 1700000000.25)]
            w.handle_event({"type": "key_down", "key": "w", "timestamp": 1.0})
            w.get_frame()
            w.reset_stats()
            assert not w.shown and not w.inputs
        finally:
            w.close()

    asyncio.run(main())


def test_a_light_field_streams_from_its_own_view_and_plays_its_own_path(tmp_path):
    import lodsprite
    from lodsprite.lumigraph.run import capture_lumigraph

    folder = tmp_path / "still.lf"
    capture_lumigraph("still-life", folder, n_st=4, n_uv=32, codec="png")

    async def main():
        w = lodsprite.widget(folder, size=(64, 48))
        try:
            w._has_visible_views = True
            image = w.get_frame()
            assert image.shape == (48, 64, 3)
            lit = image.max(axis=-1) > 0  # the still life on the lumigraph's black
            assert 0.02 < lit.mean() < 0.98, "the light field is not in view"
            w.play(frames=3)  # the scene's own default path: the arc
            arc = w.scene.path("arc", 3).viewpoints
            for vp in arc:
                w.get_frame()
                assert np.allclose(w.camera.o, vp.o)
            assert await w.played(timeout=1) == 4
            with pytest.raises(InputError, match="not found"):
                w.play("nowhere.json")
            with pytest.raises(InputError):
                w.play("arc", frames=1)
        finally:
            w.close()

    asyncio.run(main())


def test_events_from_a_subshell_thread_draw_on_the_widgets_own_loop():
    """An event handled on a kernel subshell's thread (JupyterLab, ipykernel 7) draws on
    the widget's loop, where its GL context was made, not on that thread."""
    async def main():
        w = stream()
        drew = []
        get_frame = w.get_frame
        w.get_frame = lambda: (drew.append(threading.get_ident()), get_frame())[1]

        async def drawn():
            end = time.monotonic() + 10.0
            while not drew:
                assert time.monotonic() < end, "no frame drawn"
                await asyncio.sleep(0.02)

        try:
            await drawn()  # the first frame, asked for when the widget was made
            w._frame_feedback = {"index": w._rfb_frame_index, "timestamp": 1.0,
                                 "localtime": 1.0}  # the page has shown it
            await asyncio.sleep(0.05)
            drew.clear()
            subshell = threading.Thread(target=w._rfb_handle_msg, args=(
                w, {"type": "key_down", "key": "w", "timestamp": 2.0}, []))
            subshell.start()
            subshell.join()
            await drawn()
            assert set(drew) == {threading.get_ident()} and "w" in w.flight.keys
        finally:
            w.close()

    asyncio.run(main())


def test_two_streams_in_one_kernel_each_draw_on_their_own_context(tmp_path):
    """Each stream has its own GL context; making a second one (as a second widget in a
    notebook does) leaves it current, and the first must still draw on its own."""
    import lodsprite
    from lodsprite.lumigraph.run import capture_lumigraph

    folder = tmp_path / "still.lf"
    capture_lumigraph("still-life", folder, n_st=4, n_uv=32, codec="png")

    async def main():
        first = stream()
        second = None
        try:
            alone = first.get_frame().copy()
            second = lodsprite.widget(folder, size=(64, 48))
            second._has_visible_views = True
            assert np.array_equal(first.get_frame(), alone)  # the held view, once more
            light = second.get_frame().copy()
            assert (light.max(axis=-1) > 0).mean() > 0.02
            assert np.array_equal(first.get_frame(), alone)
            assert np.array_equal(second.get_frame(), light)
        finally:
            first.close()
            if second is not None:
                second.close()
        assert first.renderer is None and second.renderer is None

    asyncio.run(main())


def test_hostile_input_events_are_dropped_and_the_camera_stays_finite():
    async def body(w):
        w.get_frame()
        before = w.camera
        hostile = [{"type": "pointer_down", "x": "abc", "y": 1},
                   {"type": "pointer_down", "x": float("nan"), "y": 0.0},
                   {"type": "wheel", "dy": 1e300}, {"type": "wheel", "dy": True},
                   {"type": "key_down", "key": "x" * 1000},
                   {"type": "key_down", "key": ["w"]},
                   {"type": "key_down", "key": "w", "timestamp": "soon"}]
        for event in hostile:
            w.handle_event(event)  # never raises
        assert w.rejected == len(hostile)
        for k in "abcdefghijkl":  # more keys than anyone holds
            w.handle_event({"type": "key_down", "key": k, "timestamp": 1.0})
        assert len(w.flight.keys) == 8 and w.rejected == len(hostile) + 4
        w.get_frame()
        assert np.all(np.isfinite(w.camera.o)) and np.all(np.isfinite(before.o))

    with_stream(body)


def test_stop_close_and_input_end_a_path_and_its_played():
    async def body(w):
        w.play("chen1999", frames=5)
        w.get_frame()
        w.stop()
        with pytest.raises(LodspriteError, match="stopped"):
            await w.played(timeout=1)
        w.play("chen1999", frames=5)
        w.get_frame()
        w.handle_event({"type": "wheel", "dy": 1.0})
        with pytest.raises(LodspriteError, match="input"):
            await w.played(timeout=1)
        w.play("chen1999", frames=5)
        played = asyncio.ensure_future(w.played(timeout=5))
        await asyncio.sleep(0)
        w.close()
        with pytest.raises(LodspriteError, match="closed"):
            await played
        assert w.get_frame() is None  # a draw asked for before the close draws nothing

    with_stream(body)


def test_page_messages_jupyter_rfb_would_choke_on_are_dropped():
    async def body(w):
        w._rfb_last_resize_event = None
        for content in ([1, 2], {"type": 5}, {"type": "resize", "height": 10},
                        {"type": "resize", "width": "1px' onerror='x", "height": 10},
                        {"type": "pointer_down", "x": 1, "y": 1, "buttons": 5},
                        {"type": "pointer_down", "x": 1, "y": 1, "modifiers": [None]},
                        {"type": "key_down", "key": "w", "timestamp": float("inf")}):
            w._rfb_handle_msg(w, content, [])  # never raises
        assert w.rejected == 7
        assert w._rfb_last_resize_event is None and not w.flight.keys
        w._rfb_handle_msg(w, {"type": "resize", "width": 64, "height": 48, "ratio": 1.0}, [])
        assert w._rfb_last_resize_event["width"] == 64 and w.rejected == 7

    with_stream(body)
