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
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lodsprite import Renderer, write_image
from lodsprite.errors import LodspriteError
from lodsprite.files import write_csv, write_json
from lodsprite.gl.overlay import HudLayer, LineOverlay, frustum_segments
from lodsprite.paths import CameraPath
from lodsprite.scene import Scene
from lodsprite.techniques import Technique, TechniqueFactory
from lodsprite.viewer.controls import CameraController, FlightRecorder
from lodsprite.viewer.hud import PANEL_HZ, HudState, glyph_atlas, layout_text

if TYPE_CHECKING:  # hints only: moderngl is imported under gl/
    import moderngl

log = logging.getLogger(__name__)

FRAME_COLUMNS = ["frame", "kind", "ms", "triangles", "error_px", "render_ms", "interval_ms",
                 "keyframes"]
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
        self.hud = HudState(renderer=self.renderer.info.renderer)
        self._atlas = glyph_atlas(26 if max(size) >= 2000 else 13)  # HiDPI: twice the size
        self._hud_layer = HudLayer(self.renderer.gl, self._atlas.alpha)
        self._lines = LineOverlay(self.renderer.gl)
        self.mode = mode
        self.technique: Technique = self.factories[mode](self.renderer)
        self.rows: list[dict] = []
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
        self._last_start: float | None = None
        self._last = None

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
        """Render and draw one frame into ``framebuffer`` (its whole viewport)."""
        self._start = time.perf_counter()
        vp = self.viewpoint(dt_s)
        self._last = self.technique.frame(vp)
        self._shot, self._shot_ms = None, 0.0
        if self._shot_due():  # read before overlays and HUD; its time is not the frame's
            t = time.perf_counter()
            self._shot = self.technique.read_image()
            self._shot_ms = (time.perf_counter() - t) * 1e3
        framebuffer.use()
        self.technique.draw_to(framebuffer)
        self._overlays(vp)
        if self.record is not None:
            self.record.append(vp)
        if self.toggles["hud"]:
            self._draw_hud(framebuffer)

    def _shot_due(self) -> bool:
        plan = self.play
        return self._want_shot or (plan is not None and plan.screenshots is not None
                                   and self.index % plan.every == 0)

    def warm_up(self, framebuffer: moderngl.Framebuffer, frames: int = 3) -> None:
        """Untimed, unlogged frames at the first viewpoint, as ``lodsprite render`` does
        before its timed frames: shaders compiled (llvmpipe compiles a shader variant at
        its first draw), the first keyframe taken, overlays and HUD drawn once."""
        record, self.record = self.record, None
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

    def log_frame(self) -> None:
        """Log the frame just shown (call after the buffer swap): its time from the start
        of :meth:`frame` to now, the technique's own time and the interval since the
        previous frame's start; take the played path's screenshot; finish a played path."""
        if self._last is None:  # no frame drawn yet
            return
        now = time.perf_counter()
        ms = (now - self._start) * 1e3 - self._shot_ms
        interval = (self._start - self._last_start) * 1e3 if self._last_start else 0.0
        self._last_start = self._start
        f = self._last
        self.hud.record(ms, interval)
        self.hud.frame_type, self.hud.error_px = f.kind, f.error_px
        self.hud.keyframes, self.hud.triangles = f.keyframes, f.triangles
        self.rows.append({"frame": self.index, "kind": f.kind, "ms": ms,
                          "triangles": f.triangles, "error_px": f.error_px, "render_ms": f.ms,
                          "interval_ms": interval, "keyframes": f.keyframes})
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
            self._lines.wireframe(self.renderer.paths.geometry, level, view_proj,
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
            self._hud_layer.set_text(*layout_text(h.lines(), self._atlas))
        w, h = framebuffer.width, framebuffer.height
        ph = int(self._hud_layer.panel_height)
        ms = np.asarray(self.hud.frame_ms)
        top = max(33.4, float(np.percentile(ms, 99)) * 1.2) if len(ms) else 33.4
        self._hud_layer.draw((w, h), ms, (8, ph + 8, min(240, w - 16), 60), top)

    def _say(self, message: str) -> None:
        """Show ``message`` in the HUD's status line for ``MESSAGE_S`` seconds."""
        self._message, self._message_until = message, time.perf_counter() + MESSAGE_S
        self.hud.status = message
        self._panel_at = -math.inf

    def screenshot(self, image: np.ndarray | None = None) -> Path | None:
        """Write ``image`` (default: the frame shown, read now) as ``frame_NNNNN.png`` in
        the screenshot folder, NNNNN the number of that frame (the last one logged).  The
        viewer reads a frame before drawing its overlays and HUD, so none are in it."""
        shown = self.rows[-1]["frame"] if self.rows else 0
        path = self.screenshot_dir / f"frame_{shown:05d}.png"
        try:
            write_image(path, self.technique.read_image() if image is None else image)
        except LodspriteError as exc:  # a flight goes on without its screenshot
            self._say(f"cannot save a screenshot: {exc}")
            log.warning("cannot save a screenshot: %s", exc)
            return None
        self.screenshots.append(path)
        return path

    def summary(self) -> dict:
        """The core timing keys of the frame times shown (:func:`lodsprite.harness.
        timing_summary`), the technique's own time, and the run's facts."""
        from lodsprite.harness import timing_summary
        from lodsprite.workers import peak_rss_mb

        ms = np.array([r["ms"] for r in self.rows], dtype=np.float64)
        render = np.array([r["render_ms"] for r in self.rows], dtype=np.float64)
        return {**timing_summary(ms), "mode": self.mode, "terrain": self.scene.name,
                "path": self.play.path.name if self.play else "flight",
                "size": list(self.renderer.size),
                "render_median_ms": float(np.median(render)),
                "render_p99_ms": float(np.percentile(render, 99)),
                "keyframes": int(self.rows[-1]["keyframes"]) if self.rows else 0,
                "status": self.technique.status(), "gl_renderer": self.renderer.info.renderer,
                "peak_rss_mb": peak_rss_mb() + self.technique.outside_mb(),
                "machine": platform.machine(), "python": platform.python_version()}

    def write_outputs(self, out_dir: Path) -> dict:
        """``frames.csv`` and ``summary.json`` of the frames shown so far."""
        summary = self.summary()
        try:
            write_csv(Path(out_dir) / "frames.csv", self.rows, FRAME_COLUMNS)
            write_json(Path(out_dir) / "summary.json", summary)
        except OSError as exc:
            raise LodspriteError(f"cannot write the run's results to {out_dir}: "
                                 f"{exc.strerror or exc}") from exc
        return summary

    def release(self) -> None:
        self.technique.release()
        self._hud_layer.release()
        self._lines.release()
        self.renderer.release()
