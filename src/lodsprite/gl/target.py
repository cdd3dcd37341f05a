"""Offscreen render targets: a framebuffer with colour and depth textures."""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext

SRGB8_ALPHA8 = 0x8C43  # GL internal format


class RenderTarget:
    """``width x height`` RGBA8 colour texture (unless ``color=False``) plus depth texture,
    bound as one framebuffer.

    The colour texture can be sampled by later draws (a keyframe's sprite), so
    rendering into a target never needs a copy.
    """

    def __init__(self, ctx: GLContext, width: int, height: int, color: bool = True,
                 srgb: bool = False) -> None:
        mgl = ctx.mgl
        self.ctx = ctx
        self.external = False
        self._copy: tuple | None = None
        self.size = (int(width), int(height))
        # srgb: stored as written (GL_FRAMEBUFFER_SRGB stays off), decoded to linear light
        # when sampled, so that filtering it averages light
        self.color = (mgl.texture(self.size, 4, internal_format=SRGB8_ALPHA8 if srgb else None)
                      if color else None)
        if self.color is not None:
            self.color.repeat_x = self.color.repeat_y = False
        self.depth = mgl.depth_texture(self.size)
        self.depth.repeat_x = self.depth.repeat_y = False
        self.fbo = mgl.framebuffer(color_attachments=[self.color] if color else [],
                                   depth_attachment=self.depth)

    @classmethod
    def wrap(cls, ctx: GLContext, fbo: moderngl.Framebuffer) -> RenderTarget:
        """An application's framebuffer (a window's, with a depth buffer) as a target:
        frames are drawn straight into it (no copy to present them).  It has no textures
        of lodsprite's; :meth:`read_color` copies it to one first.  Never released here."""
        self = cls.__new__(cls)
        self.ctx, self.external, self._copy = ctx, True, None
        self.size = (int(fbo.viewport[2]), int(fbo.viewport[3]))
        self.color = self.depth = None
        self.fbo = fbo
        return self

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    def use(self, clear_rgb: tuple[float, float, float]) -> None:
        self.fbo.use()
        self.fbo.clear(*clear_rgb, 1.0, depth=1.0)

    def read_color(self, copy: bool = True) -> np.ndarray:
        """Colour ``(height, width, 3) uint8``, row 0 at the top of the image.

        ``copy=False`` returns a read-only view flipped from GL's bottom-up rows, whose
        ``[::-1]`` is contiguous again: what a sender of raw GL rows wants.
        """
        fbo = self.fbo
        if self.external:  # copied to a framebuffer of ours (reading a window's may fail)
            if self._copy is None:
                tex = self.ctx.mgl.texture(self.size, 4)
                self._copy = (self.ctx.mgl.framebuffer(color_attachments=[tex]), tex)
            self.ctx.mgl.copy_framebuffer(self._copy[0], self.fbo)
            fbo = self._copy[0]
        data = fbo.read(components=3, alignment=1)
        img = np.frombuffer(data, np.uint8).reshape(self.height, self.width, 3)[::-1]
        return img.copy() if copy else img

    def read_depth(self, copy: bool = True) -> np.ndarray:
        """Window depth ``(height, width) float32`` in [0, 1] (1 = far plane / background),
        row 0 at the top; ``copy=False`` as in :meth:`read_color`."""
        if self.depth is None:
            raise InputError("an application's framebuffer has no depth texture to read")
        data = self.depth.read(alignment=1)
        img = np.frombuffer(data, np.float32).reshape(self.height, self.width)[::-1]
        return img.copy() if copy else img

    def release(self) -> None:
        if self.external:
            for obj in self._copy or ():
                obj.release()
            self._copy = None
            return
        if self.ctx.mgl.fbo is self.fbo:
            # moderngl re-binds the current framebuffer after creating others: never a dead one.
            self.ctx.default_fbo.use()
        for obj in (self.fbo, self.color, self.depth):
            if obj is not None:
                obj.release()
