"""The viewer's core: techniques, camera, overlays, HUD, screenshots, played and recorded
flights, on any moderngl context and framebuffer (a window's, or an offscreen one in tests).

The window (:mod:`lodsprite.viewer.window`) turns its events into :meth:`ViewerCore.key`,
:meth:`~ViewerCore.drag`, :meth:`~ViewerCore.scroll` and calls :meth:`~ViewerCore.frame`
then :meth:`~ViewerCore.log_frame` once per displayed frame.  The core knows techniques
only through :class:`~lodsprite.techniques.Technique` and a dict of factories by mode name.

Keys: ``1``-``9`` switch mode (in the order of the factories), ``[`` / ``]`` step the
technique's parameter (ε in sprite mode, N in lod mode), ``x`` coarse wireframe, ``t``
fallback tint, ``k`` keyframe frustum, ``h`` HUD, ``p`` screenshot (of the next frame, without
overlays and HUD), ``escape`` quits; the
rest go to the :class:`~lodsprite.viewer.controls.CameraController` (WASD/QE fly, shift
faster, tab fly/orbit, r reset).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lodsprite import Renderer, write_image
from lodsprite.errors import LodspriteError
from lodsprite.gl.overlay import HudLayer, LineOverlay, frustum_segments
from lodsprite.paths import CameraPath
from lodsprite.scene import Scene
from lodsprite.scene.model import scene_attribution
from lodsprite.techniques import Frame, Technique, TechniqueFactory
from lodsprite.viewer.controls import CameraController, FlightRecorder
from lodsprite.viewer.cursor import cursor_line
from lodsprite.viewer.hud import PANEL_HZ, HudState, glyph_atlas, layout_text

if TYPE_CHECKING:  # hints only: moderngl is imported under gl/
    import moderngl

log = logging.getLogger(__name__)

#: The window's own columns of ``frames.csv``, after the harness's core columns and the
#: technique's own (milliseconds): ``present_ms`` (the frame drawn into the window, with
#: its overlays), ``hud_ms`` (the HUD), ``swap_ms`` (from there to after the buffer swap),
#: ``window_ms`` (the whole window frame: from its start to after the swap, a screenshot's
#: read excluded; ``ms`` is its technique share, as in the harness) and ``interval_ms``
#: (since the previous frame's start).
WINDOW_COLUMNS = ("present_ms", "hud_ms", "swap_ms", "window_ms", "interval_ms")
TOGGLE_KEYS = {"x": "wireframe", "t": "tint", "k": "frustum", "h": "hud"}
WIREFRAME_RGBA = (0.1, 0.1, 0.1, 0.55)
FRUSTUM_RGBA = (1.0, 0.9, 0.1, 0.9)
MESSAGE_S = 5.0  # how long a message ("cannot switch ...") holds the HUD's status line


@dataclass(frozen=True)
class PlayPlan:
    """A path to play frame by frame: screenshots every ``every`` frames into
    ``screenshots`` (if set), timings to ``out_dir`` (if set), quit at the end if ``exit``."""

    path: CameraPath
    out_dir: Path | None = None
    screenshots: Path | None = None
    every: int = 1
    exit: bool = True


class ViewerCore:
    """Everything the viewer does between window events (see the module docstring)."""

    def __init__(self, ctx: moderngl.Context, scene: Scene, size: tuple[int, int],
                 factories: dict[str, TechniqueFactory], mode: str,
                 controller: CameraController, fov_y_deg: float = 45.0,
                 play: PlayPlan | None = None, record: FlightRecorder | None = None,
                 screenshot_dir: Path = Path("screenshots"),
                 framebuffer: moderngl.Framebuffer | None = None) -> None:
        if mode not in factories:
            raise LodspriteError(f"unknown mode {mode!r}: use one of {', '.join(factories)}")
        self.ctx = ctx
        self.scene = scene
        self.factories = dict(factories)
        self.controller = controller
        self.fov_y_deg = fov_y_deg
        self.play = play
        self.record = record
        self.screenshot_dir = Path(play.screenshots) if play and play.screenshots else Path(
            screenshot_dir)
        self.toggles = {"wireframe": False, "tint": False, "frustum": False, "hud": True}
        # With ``framebuffer`` (the window's), frames are drawn straight into it.
        self.framebuffer = framebuffer
        self.renderer = Renderer(scene, size, fov_y_deg, ctx=ctx, framebuffer=framebuffer)
        self.hud = HudState(renderer=self.renderer.info.renderer,
                            attribution=scene_attribution(scene))
        self.pointer_px: tuple[float, float] | None = None  # the cursor, window pixels
        self._shown_vp = None  # the last frame's viewpoint (the cursor's ray starts there)
        self._atlas = glyph_atlas(26 if max(size) >= 2000 else 13)  # HiDPI: twice the size
        self._hud_layer = HudLayer(self.renderer.gl, self._atlas.alpha)
        self._lines = LineOverlay(self.renderer.gl)
        self.mode = mode
        self.technique: Technique = self.factories[mode](self.renderer)
        self.frames: list[Frame] = []  # the frames logged, window times in their extra
        self.first_frame_ms = float("nan")  # the warm-up's time (ms), as the harness's
        self.index = 0
        self.quit = False
        self.pending_size: tuple[int, int] | None = None  # set by the window's resize event
        self.screenshots: list[Path] = []
        self._panel_at = -math.inf
        self._want_shot = False
        self._message, self._message_until = "", 0.0
        self._shot: np.ndarray | None = None
        self._shot_ms = 0.0
        self._start = time.perf_counter()
        self._marks = (0.0, 0.0, 0.0)  # technique done, presented, HUD done (perf_counter)
        self._last_start: float | None = None
        self._last: Frame | None = None

    # ------------------------------------------------------------------ input

    def key(self, name: str, pressed: bool = True) -> None:
        """A key went down (``pressed``) or up; names are lower-case key names."""
        name = name.lower()
        if pressed and name.isdigit() and name != "0":
            modes = list(self.factories)
            if int(name) <= len(modes):
                self.switch_mode(modes[int(name) - 1])
        elif pressed and name in ("[", "]"):
            self.step_param(name == "]")
        elif pressed and name in TOGGLE_KEYS:
            self.toggle(TOGGLE_KEYS[name])
        elif pressed and name == "p":
            self._want_shot = True  # of the next frame, before the HUD is drawn
        elif pressed and name == "escape":
            self.quit = True
        else:
            self.controller.key(name, pressed)

    def pointer(self, x: float | None, y: float | None = None) -> None:
        """The cursor moved to window pixel ``(x, y)`` (None: it left the window)."""
        self.pointer_px = None if x is None else (float(x), float(y))

    def drag(self, dx: float, dy: float) -> None:
        """Mouse moved ``dx, dy`` framebuffer pixels with a button held."""
        self.controller.drag(dx, dy)

    def scroll(self, steps: float) -> None:
        self.controller.scroll(steps)

    def toggle(self, what: str) -> None:
        self.toggles[what] = not self.toggles[what]
        if what == "tint":
            self.technique.set_fallback_tint(self.toggles["tint"])

    def step_param(self, up: bool) -> None:
        """Step the technique's first parameter up or down (its own factor)."""
        params = self.technique.params()
        if params:
            p = next(iter(params.values())).stepped(up)
            self.technique.set_param(p.name, p.value)

    def switch_mode(self, mode: str) -> None:
        """Switch technique; on failure keep the current one and say why in the HUD."""
        if mode == self.mode:
            return
        try:
            new = self.factories[mode](self.renderer)
        except LodspriteError as exc:
            self._say(f"cannot switch to {mode}: {exc}")
            log.warning("cannot switch to %s: %s", mode, exc)
            return
        self.technique.release()
        self.technique, self.mode = new, mode
        self.technique.set_fallback_tint(self.toggles["tint"])
        self._message_until, self.hud.status = 0.0, ""

    def resize(self, size: tuple[int, int]) -> None:
        """The framebuffer is now ``size = (w, h)`` pixels: remake renderer and technique."""
        if tuple(size) == self.renderer.size or min(size) < 16:
            return
        renderer = None
        if self.framebuffer is not None:  # the window's, at its new size
            self.framebuffer = self.ctx.detect_framebuffer(0)
        try:  # the new pair first: on failure the old one goes on drawing
            renderer = Renderer(self.scene, size, self.fov_y_deg, ctx=self.ctx,
                                framebuffer=self.framebuffer)
            technique = self.factories[self.mode](renderer)
        except LodspriteError as exc:
            if renderer is not None:
                renderer.release()
            self._say(f"cannot resize: {exc}")
            log.warning("cannot resize to %s: %s", size, exc)
            return
        self.technique.release()
        self._lines.forget_meshes()
        self.renderer.release()
        self.renderer, self.technique = renderer, technique
        self.technique.set_fallback_tint(self.toggles["tint"])

    # ------------------------------------------------------------------ frames

    def viewpoint(self, dt_s: float):
        """The next frame's viewpoint: the played path's, or the controller's after
        ``dt_s`` seconds of held keys."""
        if self.play is not None:
            return self.play.path.viewpoints[min(self.index, len(self.play.path) - 1)]
        return self.controller.update(dt_s)

    def frame(self, dt_s: float, framebuffer: moderngl.Framebuffer) -> None:
        """Render and draw one frame into ``framebuffer`` (its whole viewport).  The
        technique's :meth:`~lodsprite.techniques.Technique.frame` and ``ctx.finish()`` are
        the frame's ``ms``, as in the harness; presenting, overlays and HUD are timed
        apart (:data:`WINDOW_COLUMNS`)."""
        self._start = time.perf_counter()
        vp = self.viewpoint(dt_s)  # the camera's move: the window's time, not the frame's
        t0 = time.perf_counter()
        f = self.technique.frame(vp)
        self.ctx.finish()
        done = time.perf_counter()
        self._last = replace(f, ms=(done - t0) * 1e3)
        self._shot, self._shot_ms = None, 0.0
        if self._shot_due():  # read before overlays and HUD; its time is not the frame's
            self._shot = self.technique.read_image()
            self._shot_ms = (time.perf_counter() - done) * 1e3
        shown = time.perf_counter()
        framebuffer.use()
        self.technique.draw_to(framebuffer)
        self._overlays(vp)
        self._shown_vp = vp
        if self.record is not None:
            self.record.append(vp)
        presented = time.perf_counter()
        if self.toggles["hud"]:
            self._draw_hud(framebuffer)
        self._marks = (shown, presented, time.perf_counter())

    def _shot_due(self) -> bool:
        plan = self.play
        return self._want_shot or (plan is not None and plan.screenshots is not None
                                   and self.index % plan.every == 0)

    def warm_up(self, framebuffer: moderngl.Framebuffer, frames: int = 3) -> None:
        """Untimed, unlogged frames at the first viewpoint, as ``lodsprite render`` does
        before its timed frames: shaders compiled (llvmpipe compiles a shader variant at
        its first draw), the first keyframe taken, overlays and HUD drawn once."""
        record, self.record = self.record, None
        t0 = time.perf_counter()
        try:
            for _ in range(frames):
                for _ in range(2):  # so that the frame-time graph is drawn too
                    self.hud.record(0.0, 0.0)
                self.frame(0.0, framebuffer)
                self._panel_at = -math.inf
        finally:
            self.record = record
            self.hud.frame_ms.clear()
            self.hud.interval_ms.clear()
        self._last = None
        self.ctx.finish()
        self.first_frame_ms = (time.perf_counter() - t0) * 1e3

    def log_frame(self) -> None:
        """Log the frame just shown (call after the buffer swap): the technique's frame
        (``ms`` its :meth:`~lodsprite.techniques.Technique.frame` and ``ctx.finish()``) with
        the window's times (:data:`WINDOW_COLUMNS`); take the played path's screenshot;
        finish a played path."""
        if self._last is None:  # no frame drawn yet
            return
        now = time.perf_counter()
        window = (now - self._start) * 1e3 - self._shot_ms
        interval = (self._start - self._last_start) * 1e3 if self._last_start else 0.0
        self._last_start = self._start
        shown, presented, hud = self._marks
        f = replace(self._last, extra={
            **self._last.extra, "keyframes": self._last.keyframes,
            "present_ms": (presented - shown) * 1e3, "hud_ms": (hud - presented) * 1e3,
            "swap_ms": (now - hud) * 1e3, "window_ms": window, "interval_ms": interval})
        self.hud.record(window, interval)
        self.hud.frame_type, self.hud.error_px = f.kind, f.error_px
        self.hud.keyframes, self.hud.triangles = f.keyframes, f.triangles
        self.frames.append(f)
        if self._shot is not None:
            self.screenshot(self._shot)
            self._shot, self._want_shot = None, False
        self.index += 1
        plan = self.play
        if plan is not None and self.index >= len(plan.path):
            if plan.out_dir is not None:
                self.write_outputs(plan.out_dir)
            self.quit = self.quit or plan.exit
            self.play = None if not plan.exit else plan

    def _overlays(self, vp) -> None:
        view_proj = self.renderer.projection(vp).matrix() @ vp.view_matrix()
        level = self.technique.coarse_level()
        if self.toggles["wireframe"] and level is not None:
            self._lines.wireframe(self.renderer.terrain_gl.geometry, level, view_proj,
                                  WIREFRAME_RGBA)
        key = self.technique.key_view()
        if self.toggles["frustum"] and key is not None:
            self._lines.segments(frustum_segments(*key), view_proj, FRUSTUM_RGBA)

    def _draw_hud(self, framebuffer: moderngl.Framebuffer) -> None:
        now = time.perf_counter()
        if now - self._panel_at >= 1.0 / PANEL_HZ:
            self._panel_at = now
            h = self.hud
            h.mode = self.mode
            h.params = "  ".join(f"{p.name} {p.value:g}{p.unit}"
                                 for p in self.technique.params().values())
            h.toggles = "  ".join(k for k, on in self.toggles.items() if on and k != "hud")
            h.status = (self._message if now < self._message_until
                        else self.technique.status())
            h.cursor = self._cursor_line()
            self._hud_layer.set_text(*layout_text(h.lines(), self._atlas))
        w, h = framebuffer.width, framebuffer.height
        ph = int(self._hud_layer.panel_height)
        ms = np.asarray(self.hud.frame_ms)
        top = max(33.4, float(np.percentile(ms, 99)) * 1.2) if len(ms) else 33.4
        self._hud_layer.draw((w, h), ms, (8, ph + 8, min(240, w - 16), 60), top)

    def _cursor_line(self) -> str:
        """The HUD's cursor line (:func:`~lodsprite.viewer.cursor.cursor_line`); the
        exaggeration alone while the cursor is off the window or off the terrain."""
        hf, vp = self.scene.hf, self._shown_vp
        if hf is None or vp is None:
            return ""
        if self.pointer_px is None:
            return f"exaggeration {float(hf.meta.get('exaggeration', 1.0)):.2f}x"
        return cursor_line(hf, vp, *self.pointer_px, self.renderer.size, self.fov_y_deg)

    def _say(self, message: str) -> None:
        """Show ``message`` in the HUD's status line for ``MESSAGE_S`` seconds."""
        self._message, self._message_until = message, time.perf_counter() + MESSAGE_S
        self.hud.status = message
        self._panel_at = -math.inf

    def screenshot(self, image: np.ndarray | None = None) -> Path | None:
        """Write ``image`` (default: the frame shown, read now) as ``frame_NNNNN.png`` in
        the screenshot folder, NNNNN the number of that frame (the last one logged).  The
        viewer reads a frame before drawing its overlays and HUD, so none are in it."""
        shown = len(self.frames) - 1 if self.frames else 0
        path = self.screenshot_dir / f"frame_{shown:05d}.png"
        try:
            write_image(path, self.technique.read_image() if image is None else image)
        except LodspriteError as exc:  # a flight goes on without its screenshot
            self._say(f"cannot save a screenshot: {exc}")
            log.warning("cannot save a screenshot: %s", exc)
            return None
        self.screenshots.append(path)
        return path

    @property
    def rows(self) -> list[dict]:
        """The rows of ``frames.csv`` so far (:func:`lodsprite.record.frame_rows`)."""
        from lodsprite.harness import frame_rows

        return frame_rows(self.frames)[0]

    def summary(self) -> dict:
        """The harness's summary of the frames shown (:func:`lodsprite.record.
        frames_summary`: ``ms`` the technique's frame and ``ctx.finish()``), the window's
        frame time beside it, and the run's facts."""
        from lodsprite.harness import frames_summary
        from lodsprite.workers import peak_rss_mb

        window = np.array([f.extra["window_ms"] for f in self.frames], dtype=np.float64)
        return {**frames_summary(self.frames, self.technique.name,
                                 self.renderer.info.renderer, self.first_frame_ms),
                "mode": self.mode, "terrain": self.scene.name,
                "path": self.play.path.name if self.play else "flight",
                "size": list(self.renderer.size),
                "window_median_ms": float(np.median(window)),
                "window_p99_ms": float(np.percentile(window, 99)),
                "keyframes": self.frames[-1].keyframes if self.frames else 0,
                "status": self.technique.status(),
                "peak_rss_mb": peak_rss_mb() + self.technique.outside_mb()}

    def write_outputs(self, out_dir: Path) -> dict:
        """``frames.csv`` and ``summary.json`` of the frames shown so far, through the
        harness's record (:func:`lodsprite.harness.write_run`)."""
        from lodsprite.harness import RunResult, frame_rows, write_run

        summary = self.summary()
        rows, columns = frame_rows(self.frames)
        try:
            write_run(Path(out_dir), RunResult(self.frames, [], rows, columns, summary))
        except OSError as exc:
            raise LodspriteError(f"cannot write the run's results to {out_dir}: "
                                 f"{exc.strerror or exc}") from exc
        return summary

    def release(self) -> None:
        self.technique.release()
        self._hud_layer.release()
        self._lines.release()
        self.renderer.release()
