"""The viewer's window: moderngl-window (pyglet backend) around :class:`ViewerCore`.

moderngl-window makes the window and its OpenGL 3.3 core context and turns the
toolkit's events into callbacks; lodsprite draws with that context through its public
API (:class:`lodsprite.Renderer` with ``ctx=``).  The frame loop is ours: draw, swap,
log, then sleep to the frame period (``fps``; 0 = as fast as possible, no vsync), so that
the keyframe worker process gets the CPU time between frames, as at a display's rate.
Sizes are the framebuffer's, not the window's, so HiDPI screens get full resolution.
"""

from __future__ import annotations

import gc
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from lodsprite.errors import InputError
from lodsprite.scene import Scene
from lodsprite.techniques import TechniqueFactory
from lodsprite.viewer.controls import CameraController, FlightRecorder
from lodsprite.viewer.core import PlayPlan, ViewerCore

DEFAULT_FPS = 60.0
WARM_UP_FRAMES = 5


class NoDisplayError(InputError):
    """No display to open a window on."""


@dataclass(frozen=True)
class WindowOptions:
    """Window size ``(w, h)`` (screen units), title, frame rate cap (0: none), vsync."""

    size: tuple[int, int] = (1024, 768)
    title: str = "lodsprite"
    fps: float = DEFAULT_FPS
    vsync: bool = False
    resizable: bool = True


def check_display() -> None:
    """Raise :class:`NoDisplayError` (one line) when no window can be opened here."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise NoDisplayError("no display: lodsprite view needs a screen (set DISPLAY, or run "
                             "it under xvfb-run for a virtual one)")


def open_window(options: WindowOptions):
    """A moderngl-window window (pyglet) with an OpenGL 3.3 core context."""
    check_display()
    import moderngl_window
    from moderngl_window import settings

    settings.WINDOW["class"] = "moderngl_window.context.pyglet.Window"
    settings.WINDOW["gl_version"] = (3, 3)
    settings.WINDOW["size"] = tuple(options.size)
    settings.WINDOW["title"] = options.title
    settings.WINDOW["vsync"] = options.vsync
    settings.WINDOW["resizable"] = options.resizable
    settings.WINDOW["aspect_ratio"] = None
    try:
        return moderngl_window.create_window_from_settings()
    except Exception as exc:  # pyglet raises several kinds when no window can be made
        raise NoDisplayError(f"cannot open a window: {' '.join(str(exc).split())}") from exc


def _key_name(window, key) -> str:
    keys = window.keys
    named = {keys.ESCAPE: "escape", keys.TAB: "tab", keys.LEFT_SHIFT: "shift",
             keys.RIGHT_SHIFT: "shift"}
    if key in named:
        return named[key]
    try:
        return chr(key).lower()
    except (TypeError, ValueError, OverflowError):
        return ""


def run_viewer(scene: Scene, factories: dict[str, TechniqueFactory], mode: str,
               options: WindowOptions, play: PlayPlan | None = None,
               record: Path | None = None, fov_y_deg: float = 45.0,
               screenshot_dir: Path = Path("screenshots"),
               controller: CameraController | None = None) -> dict:
    """Open the window and run until it closes (or a played path ends with ``exit``);
    returns the summary of the frames shown.  ``controller``: the camera (default: the
    scene's home)."""
    window = open_window(options)
    recorder = FlightRecorder() if record is not None else None
    controller = controller or CameraController.from_home(scene.camera_home())
    try:
        core = ViewerCore(window.ctx, scene, window.buffer_size, factories, mode, controller,
                          fov_y_deg, play, recorder, screenshot_dir, window.ctx.screen)
    except BaseException:
        window.destroy()
        raise
    ratio = window.pixel_ratio

    def on_key(key, action, modifiers):
        name = _key_name(window, key)
        if name:
            core.key(name, action == window.keys.ACTION_PRESS)

    window.key_event_func = on_key
    window.mouse_drag_event_func = lambda x, y, dx, dy: core.drag(dx * ratio, dy * ratio)
    window.mouse_scroll_event_func = lambda dx, dy: core.scroll(dy)
    window.mouse_position_event_func = lambda x, y, dx, dy: core.pointer(x * ratio, y * ratio)
    # A resize remakes the renderer (and a keyframe worker): dragging a window corner
    # sends dozens of events, so only the last size is applied, before the next frame.
    window.resize_func = lambda w, h: setattr(core, "pending_size", window.buffer_size)
    try:
        _loop(window, core, options.fps)
        if record is not None:
            recorder.save(record, fov_y_deg)
        return core.summary() if core.rows else {}
    finally:
        core.release()
        window.destroy()


def _loop(window, core: ViewerCore, fps: float) -> None:
    period = 1.0 / fps if fps > 0 else 0.0
    try:
        _frames(window, core, period)
    finally:
        gc.unfreeze()


def _frames(window, core: ViewerCore, period: float) -> None:
    if core.play is not None:  # warm-up, untimed: shaders, first keyframe, first swaps
        for _ in range(WARM_UP_FRAMES):
            core.warm_up(core.framebuffer, frames=1)
            window.swap_buffers()
    # Everything made so far (modules, the scene, GL wrappers) moves out of the collector's
    # reach: a full collection of it costs about 35 ms, a stall if it came mid-flight.
    gc.collect()
    gc.freeze()
    last = time.perf_counter()
    while not window.is_closing and not core.quit:
        start = time.perf_counter()
        if core.pending_size is not None:
            size, core.pending_size = core.pending_size, None
            core.resize(size)
        core.frame(min(start - last, 0.25), core.framebuffer)
        last = start
        window.swap_buffers()
        core.log_frame()
        if period:
            rest = period - (time.perf_counter() - start)
            if rest > 0:
                time.sleep(rest)

