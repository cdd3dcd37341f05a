"""A streaming widget: every frame rendered in the kernel and sent to the browser
(jupyter_rfb on anywidget, the convention of PyVista, pygfx and vispy in Jupyter: JPEG
at quality 80 while moving, a lossless PNG when still, at most two frames in flight).

It shows any scene the library opens (a terrain, a scene file with objects, a light
field, a crowd), drawn at full detail by :meth:`lodsprite.Renderer.draw`; it is what
:func:`lodsprite.widget` returns for the scenes the browser's spriteframes do not draw,
and the baseline the sprite widget is measured against (``benchmarks/
notebook_vs_rfb.py``).  Every frame waits for the kernel and the network: a frame shows
the camera as the kernel last heard of it.  Same Python API as
:class:`~lodsprite.notebook.sprite.SpriteWidget`.
"""

from __future__ import annotations

import asyncio
import io
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from jupyter_rfb import RemoteFrameBuffer

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError, LodspriteError
from lodsprite.gl.context import keep_current
from lodsprite.notebook.events import MAX_KEYS, MAX_TIME, check_event, key, number
from lodsprite.notebook.flight import MOVE_KEYS, FlyCamera, look_along
from lodsprite.notebook.home import at_home, home_loop
from lodsprite.notebook.source import check_path, path_played

__all__ = ["StreamWidget"]

KEEP = 2000
MAX_INPUTS = 2000
FIRST_STEP_S = 1 / 60
"""The camera's step (seconds of flight) on the first frame of a key held: the frames
after it step by the time between frames."""
MAX_SPEC = 1024


def _percentile(values: Any, p: float) -> float | None:
    a = np.asarray(values, dtype=np.float64)
    return float(np.percentile(a, p)) if a.size else None


def start_view(scene: Any) -> Viewpoint:
    """A first viewpoint: the scene's default path's first (a scene file's ``[view]``
    path, a light field's ``arc``, a crowd's ``walk``), else over the terrain looking at
    its centre (as the page's), else 30 m back from the origin."""
    if scene.default_path is not None:
        try:
            return scene.path(scene.default_path, 2).viewpoints[0]
        except Exception:  # noqa: BLE001 - no default path: a view of its own
            pass
    if scene.hf is not None:
        lo, hi = scene.hf.bounds()
        centre = 0.5 * (lo + hi)
        extent = float(hi[0] - lo[0])
        eye = np.array([centre[0], centre[1] - 1.2 * extent, centre[2] + 0.6 * extent])
        return look_along(eye, centre - eye)
    return look_along(np.array([0.0, -30.0, 5.0]), np.array([0.0, 1.0, -0.15]))


def _check_scene_path(scene: Any, spec: Any, frames: int | None) -> None:
    """``spec`` and ``frames`` checked before a path is made: a terrain's paths are the
    built-ins (:func:`check_path`); a scene with paths of its own (a light field, a crowd)
    names them or a JSON file, which :meth:`Scene.path` checks.  Raises
    :class:`InputError`."""
    if scene.paths is None:
        check_path(spec, frames)
        return
    if not isinstance(spec, str) or not 0 < len(spec) <= MAX_SPEC:
        raise InputError(f"path: a path name or a JSON file (1..{MAX_SPEC} characters), "
                         f"got {spec!r:.40}")
    check_path("chen1999", frames)  # the frame count's bounds


class StreamWidget(RemoteFrameBuffer):
    """Frames of ``source`` rendered in the kernel, ``size`` (w, h) pixels; see the
    module."""

    rejected: int = 0
    """Messages and input events from the page dropped as malformed."""

    def __init__(self, source: str | Path = "jacksboro", *, path: str | None = None,
                 frames: int | None = None, size: tuple[int, int] = (640, 480),
                 fov_y_deg: float | None = None, quality: int = 80, **scene_options: Any
                 ) -> None:
        from lodsprite import Renderer, open_scene

        w, h = (int(v) for v in size)
        scene = open_scene(str(source), **scene_options)
        if path is not None:
            _check_scene_path(scene, path, frames)
        fov = fov_y_deg or (scene.view.fov_y_deg if scene.view is not None
                            and getattr(scene.view, "fov_y_deg", None) else 45.0)
        super().__init__(css_width=f"{w}px", css_height=f"{h}px", resizable=False,
                         quality=quality)
        self._home = home_loop()  # every draw and event runs here (lodsprite.notebook.home)
        self.scene = scene
        self.renderer = Renderer(scene, size=(w, h), fov_y_deg=fov)
        first = start_view(scene)
        speed = (0.25 * float(np.ptp(scene.hf.bounds(), axis=0)[0]) if scene.hf is not None
                 else scene.home.speed_mps if scene.home is not None else 15.0)
        self.flight = FlyCamera(first, speed)
        self._path: list[Viewpoint] = []
        self._path_index = 0
        self._played: asyncio.Future | None = None
        self._last = None  # the frame time (perf_counter) of the last frame
        self._started = time.perf_counter()
        self._intervals: deque[float] = deque(maxlen=KEEP)
        self._render_ms: deque[float] = deque(maxlen=KEEP)
        self._drag: tuple[float, float] | None = None
        self.inputs: deque[tuple[float, int]] = deque(maxlen=MAX_INPUTS)
        """(browser event timestamp, index of the first frame rendered after it) for each
        key press, for input-to-frame measurements (the frame index is jupyter_rfb's)."""
        self._pending_inputs: deque[float] = deque(maxlen=MAX_INPUTS)
        self.drawn: deque[int] = deque(maxlen=KEEP)
        """jupyter_rfb's index of each frame :meth:`get_frame` rendered (not its lossless
        re-sends of the last one), to tell the frames in ``shown`` apart."""
        self.shown: deque[tuple[int, float]] = deque(maxlen=KEEP)
        """(jupyter_rfb frame index, browser wall-clock time in s) of each frame the page
        put on screen, from jupyter_rfb's frame feedback: frame times as the page shows
        them, and the end of an input-to-frame measurement."""
        self.observe(self._on_feedback, names=["_frame_feedback"])
        self.frames = 0
        if path is not None:
            self.play(path, frames)
        else:
            self.request_draw()

    # ------------------------------------------------------------------ rendering

    def get_frame(self) -> np.ndarray | None:
        """Render the next frame (the path's next viewpoint, or the flown camera); None
        once closed."""
        if self.renderer is None:
            return None
        now = time.perf_counter()
        if self._last is not None:  # the frame before asked for this one: in one run
            dt = now - self._last
            self._intervals.append(dt * 1e3)
        else:  # the first frame after a pause (a path, a key pressed, a draw asked for)
            dt = FIRST_STEP_S
        more = False
        if self._path_index < len(self._path):
            vp = self._path[self._path_index]
            self._path_index += 1
            more = self._path_index < len(self._path)
            self.flight.viewpoint = vp
            if not more:
                self._settle(result=self.frames + 1)
        else:
            self.flight.step(dt)
            more = bool(self.flight.keys & MOVE_KEYS)
            vp = self.flight.viewpoint
        self._last = now if more else None
        t0 = time.perf_counter()
        with self.renderer.gl.mgl:  # its own context current (another widget's may be)
            self.renderer.draw(vp, t=now - self._started)
            image = self.renderer.read_color()
        self._render_ms.append((time.perf_counter() - t0) * 1e3)
        self.frames += 1
        index = self._rfb_frame_index + 1  # the index jupyter_rfb gives this frame
        self.drawn.append(index)
        self.inputs.extend((t, index) for t in self._pending_inputs)
        self._pending_inputs.clear()
        if more:
            self.request_draw()
        return image

    def _settle(self, result: int | None = None, why: str | None = None) -> None:
        """End a path's ``played()`` future: its frames, or an error saying ``why``."""
        future = self._played  # kept: played() answers with it after the end too
        if future is None or future.done():
            return
        if why is None:
            future.set_result(result)
        else:
            future.set_exception(LodspriteError(why))

    # jupyter_rfb's front-end messages and draws, on the widget's home loop: messages may
    # arrive on a kernel subshell's thread (lodsprite.notebook.home)

    def _rfb_handle_msg(self, widget: Any, content: Any, buffers: list) -> None:
        if not check_event(content):  # the page is untrusted (lodsprite.notebook.events)
            self.rejected += 1
            return
        at_home(getattr(self, "_home", None), super()._rfb_handle_msg, widget, content,
                buffers)

    def _rfb_schedule_maybe_draw(self, *args: Any) -> None:
        home = getattr(self, "_home", None)
        if home is None:
            super()._rfb_schedule_maybe_draw(*args)
            return
        try:
            home.call_soon_threadsafe(self._rfb_maybe_draw)
        except RuntimeError:  # the kernel's loop has closed
            pass

    def _on_feedback(self, change: dict) -> None:
        fb = change.get("new") or {}
        try:
            self.shown.append((int(fb["index"]), float(fb["localtime"])))
        except (KeyError, TypeError, ValueError):  # the page's message: ignore what is not
            pass

    def handle_event(self, event: dict) -> None:
        """One input event from the page (jupyter_rfb's): keys fly, a drag looks, the
        wheel moves.  The page is untrusted: an event whose fields are not what they
        should be (a coordinate not a finite number within :data:`MAX_COORD`, a key name
        over 16 characters, more than :data:`MAX_KEYS` keys held) is dropped and
        counted in ``rejected``."""
        try:
            self._handle(event)
        except (TypeError, ValueError, AttributeError):
            self.rejected += 1

    def _handle(self, event: dict) -> None:
        kind = event.get("type") or event.get("event_type")
        if kind == "key_down":
            name, t = key(event), number(event, "timestamp", 0.0, MAX_TIME)
            if name not in self.flight.keys and len(self.flight.keys) >= MAX_KEYS:
                raise ValueError("too many keys held")
            self.flight.keys.add(name)
            self._pending_inputs.append(t)
        elif kind == "key_up":
            self.flight.keys.discard(key(event))
        elif kind == "pointer_down":
            self._drag = (number(event, "x"), number(event, "y"))
        elif kind == "pointer_up":
            self._drag = None
        elif kind == "pointer_move" and self._drag is not None:
            x, y = number(event, "x"), number(event, "y")
            self.flight.drag(x - self._drag[0], y - self._drag[1])
            self._drag = (x, y)
        elif kind == "wheel":
            self.flight.wheel(number(event, "dy"))
        else:
            return
        if self._path:  # input takes the camera from a path
            self._path = []
            self._last = None
            self._settle(why="the path was stopped by input in the view")
        self.request_draw()

    # ----------------------------------------------------------------------- API

    def play(self, path: str | None = None, frames: int | None = None) -> None:
        """Play the camera ``path`` over ``frames`` viewpoints (None: the path's own
        count), one a frame: a built-in terrain path (chen1999, swan2002, flyover[:...],
        patrol[:...], bank[:...]) or the scene's own (a light field's ``arc``, a crowd's
        ``walk``, a JSON path file); None: the scene's default path, else chen1999.
        Raises :class:`InputError` for an unknown path."""
        from lodsprite.errors import PathError

        spec = path if path is not None else self.scene.default_path or "chen1999"
        _check_scene_path(self.scene, spec, frames)
        try:
            self._path = list(self.scene.path(spec, frames).viewpoints)
        except PathError as exc:
            raise InputError(str(exc)) from None
        self._path_index = 0
        self._last = None
        self._settle(why="another path was played")
        loop = self._home or home_loop()  # resolved where get_frame runs
        self._played = None if loop is None else loop.create_future()
        self.request_draw()

    async def played(self, timeout: float = 120.0) -> int:
        """Wait until the path has been rendered to its end; the frames rendered.

        A stream's frames flow while the kernel is idle: jupyter_rfb sends a frame once
        the page has confirmed the one before last, and JupyterLab and Notebook 7 hold
        those confirmations (widget state updates) while a cell runs.  So await it in a
        cell of its own after the path has played, or in a task
        (``asyncio.ensure_future(w.played())``); a cell awaiting it while the path plays
        raises :class:`LodspriteError` after ``timeout`` s, saying so."""
        try:
            return await path_played(self._played, timeout)
        except LodspriteError as exc:
            confirmed = self._frame_feedback.get("index", 0)
            if self._rfb_frame_index - confirmed >= self.max_buffered_frames:
                raise LodspriteError(
                    f"{exc}: the page confirmed no frame since frame {confirmed} (the "
                    "notebook holds a stream's confirmations while a cell runs: let the "
                    "cell end, or await played() in a task)") from None
            raise

    def stop(self) -> None:
        """Stop a playing path where it is (its ``played()`` raises, saying so)."""
        if self._path:
            self._path = []
            self._last = None
            self._settle(why="the path was stopped")

    @property
    def camera(self) -> Viewpoint:
        """The viewpoint of the last frame; set it to move the view there."""
        return self.flight.viewpoint

    @camera.setter
    def camera(self, value: Viewpoint | Any) -> None:
        from lodsprite.notebook.sprite import _row

        r = _row(value)
        self._path = []
        self.flight.viewpoint = Viewpoint(np.array(r[0:3]), np.array(r[3:6]),
                                          np.array(r[6:9]), np.array(r[9:12]))
        self.request_draw()

    @property
    def stats(self) -> dict[str, Any]:
        """Frames rendered (each is a keyframe), their intervals' median and p99 (ms),
        the kernel's render time (median, ms) and jupyter_rfb's own figures (``rfb``:
        frames sent and confirmed, round trip and delivery times)."""
        return {"frames": self.frames, "keyframes": self.frames,
                "median_ms": _percentile(self._intervals, 50),
                "p99_ms": _percentile(self._intervals, 99),
                "render_ms": _percentile(self._render_ms, 50),
                "error_px": 0.0 if self.frames else None,
                "error_px_mean": 0.0 if self.frames else None,
                "rfb": dict(self.get_stats())}

    def reset_stats(self) -> None:
        """Start the figures again (jupyter_rfb's too; its constructor calls this)."""
        super().reset_stats()
        if hasattr(self, "_intervals"):
            self.frames = 0
            self._intervals.clear()
            self._render_ms.clear()
            self.inputs.clear()
            self.shown.clear()
            self.drawn.clear()
            self._last = None

    async def screenshot(self, timeout: float = 10.0) -> bytes:
        """A PNG of the last frame sent to the browser (what it shows once delivered)."""
        from PIL import Image

        frame = self._rfb_last_frame
        if frame is None:
            raise LodspriteError("no frame was rendered yet: display the widget first")
        out = io.BytesIO()
        Image.fromarray(np.asarray(frame)[..., :3]).save(out, format="PNG")
        return out.getvalue()

    def close(self) -> None:
        """Release the renderer (its GL context) and close the widget; idempotent.  A
        path playing stops (its ``played()`` raises) and nothing more is drawn."""
        self._path = []
        self._settle(why="the widget was closed")
        self._rfb_draw_requested = False
        self._rfb_cancel_lossless_draw()
        renderer, self.renderer = getattr(self, "renderer", None), None
        if renderer is not None:
            with keep_current():  # its objects released on its own context
                renderer.gl.mgl.__enter__()
                renderer.release()
        super().close()
        self._output_context.close()  # jupyter_rfb's Output widget
