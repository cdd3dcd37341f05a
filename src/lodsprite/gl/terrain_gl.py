"""One scene's terrain GL state (:class:`TerrainGL`): context, geometry and terrain
drawer, made once and released once; what the terrain techniques draw with."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import moderngl

from lodsprite.gl.context import GLContext
from lodsprite.gl.target import RenderTarget
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry

if TYPE_CHECKING:  # a scene is passed in: gl/ imports no scene code
    from lodsprite.scene import Scene


class TerrainGL:
    """GL state for one scene: context, geometry and drawer (:attr:`drawer`, a
    :class:`~lodsprite.gl.terrain.TerrainDrawer`), created once, released once."""

    def __init__(self, scene: Scene, size: tuple[int, int], fov_y_deg: float = 45.0,
                 ctx: GLContext | None = None,
                 framebuffer: moderngl.Framebuffer | None = None) -> None:
        self.scene = scene
        self.own_ctx = ctx is None
        self.ctx = ctx or GLContext()
        self.geometry = None
        try:
            self.geometry = TerrainGeometry(self.ctx, scene.hf, scene.texture)
            target = (RenderTarget.wrap(self.ctx, framebuffer) if framebuffer is not None
                      else None)
            self.drawer = TerrainDrawer(self.ctx, self.geometry, size[0], size[1],
                                            fov_y_deg, target)
        except BaseException:  # release what was made: a leaked context outlives us
            if self.geometry is not None:
                self.geometry.release()
            if self.own_ctx:
                self.ctx.release()
            raise

    def timed(self, viewpoint, level: int | None) -> tuple[float, int]:
        """Render one frame; (milliseconds including ``ctx.finish()``, triangles)."""
        t0 = time.perf_counter()
        stats = self.drawer.render(viewpoint, level)
        self.ctx.finish()
        return (time.perf_counter() - t0) * 1e3, stats.triangles

    def release(self) -> None:
        self.drawer.release()
        self.geometry.release()
        if self.own_ctx:
            self.ctx.release()

    def __enter__(self) -> TerrainGL:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
