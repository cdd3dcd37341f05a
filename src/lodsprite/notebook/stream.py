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
from lodsprite.notebook.flight import FlyCamera, look_along
from lodsprite.notebook.home import at_home, home_loop
from lodsprite.notebook.source import check_path, path_played

__all__ = ["StreamWidget"]

KEEP = 2000
MAX_INPUTS = 2000
MAX_KEYS = 8
"""Keys held at once; a key down beyond them is dropped."""
MAX_COORD = 1e6
"""Largest magnitude of an event's coordinate (pixels) or wheel step accepted."""


def _number(event: dict, name: str, default: float = 0.0, limit: float = MAX_COORD) -> float:
    """``event[name]`` as a finite float within +-``limit``; ValueError otherwise."""
    value = event.get(name, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} is not a number")
    value = float(value)
    if not np.isfinite(value) or abs(value) > limit:
        raise ValueError(f"{name} out of range")
    return value


def _key(event: dict) -> str:
    key = event.get("key", "")
    if not isinstance(key, str) or len(key) > 16:
        raise ValueError("not a key name")
    return key.lower()
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
        self._pending_inputs: list[float] = []
        self.rejected = 0
        """Input events from the page dropped as malformed (see :meth:`handle_event`)."""
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

    def get_frame(self) -> np.ndarray:
        """Render the next frame (the path's next viewpoint, or the flown camera)."""
        now = time.perf_counter()
        dt = 0.0 if self._last is None else now - self._last
        if self._last is not None:
            self._intervals.append(dt * 1e3)
        self._last = now
        more = False
        if self._path_index < len(self._path):
            vp = self._path[self._path_index]
            self._path_index += 1
            more = self._path_index < len(self._path)
            self.flight.viewpoint = vp
            if not more and self._played is not None and not self._played.done():
                self._played.set_result(self.frames + 1)
        else:
            more = self.flight.step(dt)
            vp = self.flight.viewpoint
        t0 = time.perf_counter()
        with self.renderer.gl.mgl:  # its own context current (another widget's may be)
            self.renderer.draw(vp, t=now - self._started)
            image = self.renderer.read_color()
        self._render_ms.append((time.perf_counter() - t0) * 1e3)
        self.frames += 1
        index = self._rfb_frame_index + 1  # the index jupyter_rfb gives this frame
        self.inputs.extend((t, index) for t in self._pending_inputs)
        self._pending_inputs = []
        if more:
            self.request_draw()
        return image

    # jupyter_rfb's front-end messages and draws, on the widget's home loop: messages may
    # arrive on a kernel subshell's thread (lodsprite.notebook.home)

    def _rfb_handle_msg(self, widget: Any, content: Any, buffers: list) -> None:
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
            key, t = _key(event), _number(event, "timestamp", 0.0, 1e12)
            if key not in self.flight.keys and len(self.flight.keys) >= MAX_KEYS:
                raise ValueError("too many keys held")
            self.flight.keys.add(key)
            self._pending_inputs.append(t)
        elif kind == "key_up":
            self.flight.keys.discard(_key(event))
        elif kind == "pointer_down":
            self._drag = (_number(event, "x"), _number(event, "y"))
        elif kind == "pointer_up":
            self._drag = None
        elif kind == "pointer_move" and self._drag is not None:
            x, y = _number(event, "x"), _number(event, "y")
            self.flight.drag(x - self._drag[0], y - self._drag[1])
            self._drag = (x, y)
        elif kind == "wheel":
            self.flight.wheel(_number(event, "dy"))
        else:
            return
        self._path = []  # input takes the camera from a path
        self._last = None if not self.flight.keys else self._last
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
        try:
            self._played = asyncio.get_running_loop().create_future()
        except RuntimeError:
            self._played = None
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
        """Stop a playing path where it is."""
        self._path = []

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
        """Release the renderer (its GL context) and close the widget; idempotent."""
        renderer, self.renderer = getattr(self, "renderer", None), None
        if renderer is not None:
            with keep_current():  # its objects released on its own context
                renderer.gl.mgl.__enter__()
                renderer.release()
        super().close()
