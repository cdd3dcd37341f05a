"""Embed lodsprite in a moderngl-window application.

The application owns the window and its OpenGL context; lodsprite renders LOD-sprite
frames with that context (``lodsprite.Renderer(scene, size, ctx=self.ctx)``) and draws
each one into the application's framebuffer (``sprite.draw_to(self.ctx.screen)``),
between the application's own drawing.  Here the application clears the window to its
own colour, draws the terrain frame into the window with a margin where that colour
shows, and orbits the camera around the terrain with ``lodsprite.look_at``.

Run it on a desktop::

    python examples/embed_moderngl_window.py

or on a machine without a display, under a virtual X server::

    xvfb-run -a -s "-screen 0 1280x1024x24" python examples/embed_moderngl_window.py --frames 30

``--frames N`` quits after N frames and prints a summary line; ``--inline`` renders
keyframes in the frame that needs them (the 1999 algorithm) instead of in a worker process;
``--epsilon PX`` sets the error threshold.  moderngl-window's own options (``--size``,
``--vsync``, ...) work too.
"""

from __future__ import annotations

import math
import statistics

import moderngl_window

import lodsprite

MARGIN_PX = 24
APP_COLOUR = (0.10, 0.12, 0.16)


class TerrainWindow(moderngl_window.WindowConfig):
    gl_version = (3, 3)
    title = "lodsprite in a moderngl-window app"
    window_size = (800, 600)
    aspect_ratio = None      # the whole window is ours: no letterboxing viewport
    resizable = False        # a resizable app would remake Renderer and sprite in on_resize
    vsync = False
    clear_color = None       # we clear ourselves in on_render

    @classmethod
    def add_arguments(cls, parser) -> None:
        parser.add_argument("--frames", type=int, default=0,
                            help="quit after N frames and print a summary (0: run until closed)")
        parser.add_argument("--epsilon", type=float, default=1.0,
                            help="LOD-sprite error threshold in pixels")
        parser.add_argument("--inline", action="store_true",
                            help="render keyframes inline instead of in a worker process")

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.scene = lodsprite.load_scene("jacksboro")
        w, h = self.wnd.buffer_size
        size = (w - 2 * MARGIN_PX, h - 2 * MARGIN_PX)
        # lodsprite draws with the window's context; it never releases it.
        self.renderer = lodsprite.Renderer(self.scene, size, ctx=self.ctx)
        self.sprite = self.renderer.sprite(epsilon_px=self.argv.epsilon,
                                           threaded=not self.argv.inline)
        self.viewport = (MARGIN_PX, MARGIN_PX, *size)
        lo, hi = self.scene.hf.bounds()
        self.centre = (lo + hi) / 2
        self.radius = 0.9 * self.scene.hf.extent
        self.height = hi[2] + 0.35 * self.scene.hf.extent
        self.count = 0
        self.frames: list[lodsprite.SpriteFrame] = []

    def viewpoint(self, t: float) -> lodsprite.Viewpoint:
        angle = 0.15 * t     # radians per second of animation time
        eye = self.centre + (self.radius * math.cos(angle), self.radius * math.sin(angle), 0.0)
        eye[2] = self.height
        return lodsprite.look_at(eye, self.centre)

    def on_render(self, time: float, frame_time: float) -> None:
        # With --frames, step a fixed 1/30 s per frame so runs are repeatable.
        t = self.count / 30.0 if self.argv.frames else time
        self.ctx.screen.use()
        self.ctx.clear(*APP_COLOUR)                  # the application's own drawing
        frame = self.sprite.frame(self.viewpoint(t))  # lodsprite renders offscreen ...
        self.ctx.screen.viewport = self.viewport
        self.sprite.draw_to(self.ctx.screen)         # ... and draws into our framebuffer
        self.ctx.screen.viewport = (0, 0, *self.wnd.buffer_size)
        self.frames.append(frame)
        self.count += 1
        if self.argv.frames and self.count >= self.argv.frames:
            self.report()
            self.wnd.close()

    def report(self) -> None:
        w, h = self.wnd.buffer_size
        corner = self.ctx.screen.read(viewport=(0, 0, 1, 1))   # the margin: our colour
        centre = self.ctx.screen.read(viewport=(w // 2, h // 2, 1, 1))  # the terrain
        ms = statistics.median(f.ms for f in self.frames)
        print(f"{self.count} frames in a {w}x{h} window, {len(self.sprite.keyframes)} "
              f"keyframes, median {ms:.1f} ms per lodsprite frame; "
              f"margin pixel {tuple(corner)}, centre pixel {tuple(centre)}; "
              f"GL {self.renderer.info.renderer}")

    def on_close(self) -> None:
        self.sprite.release()     # ends the keyframe worker process
        self.renderer.release()   # lodsprite's GPU objects (not the window's context)


if __name__ == "__main__":
    moderngl_window.run_window_config(TerrainWindow)
