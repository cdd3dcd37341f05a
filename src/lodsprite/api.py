"""The Python API: scenes, renderers (standalone or embedded), LOD-sprite frame by frame,
camera paths and images.  ``import lodsprite`` exports everything here.

A minimal session::

    import lodsprite as ls

    scene = ls.load_scene("jacksboro")
    path = ls.get_path("chen1999", scene.hf, frames=60)
    with ls.Renderer(scene, size=(512, 512)) as renderer:
        sprite = renderer.sprite(epsilon_px=1.0)
        for vp in path.viewpoints:
            frame = sprite.frame(vp)          # keyframe or spriteframe, timed
        ls.write_image("last.png", sprite.read_image())

Any scene: :meth:`Renderer.draw` draws every layer the scene has (terrain, objects, light
fields) composited by depth at full detail, through the scene technique's layers
(:class:`~lodsprite.layered.technique.LayeredTechnique`); a scene without terrain (a
crowd) too::

    scene = ls.open_scene("crowd:200")
    with ls.Renderer(scene, size=(512, 512), fov_y_deg=60.0) as renderer:
        renderer.draw(scene.path("walk", 2).viewpoints[0])
        image = renderer.read_color()

Embedding: ``Renderer(scene, size, ctx=app_ctx)`` draws with an application's moderngl
context (for example a moderngl-window window's ``ctx``) and :meth:`Renderer.draw_to` /
:meth:`LodSprite.draw_to` put the last frame into the application's framebuffer.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.files import write_png
from lodsprite.gl.context import GLContext, GLInfo
from lodsprite.gl.overlay import Presenter
from lodsprite.gl.sprite import DEFAULT_GUARD_PX, DEFAULT_VISIBILITY, SpriteDrawer
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.record import Frame
from lodsprite.scene import Scene
from lodsprite.sprite.cache import DEFAULT_POLICY
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX, LodSpriteEngine
from lodsprite.sprite.worker_engine import WorkerLodSpriteEngine
from lodsprite.terrain.lod import DEFAULT_COARSE

if TYPE_CHECKING:  # hints only: moderngl is imported under gl/
    import moderngl

    from lodsprite.gl.target import RenderTarget
    from lodsprite.techniques.base import Frame

MAX_IMAGE_PIXELS = 1 << 28


class Renderer:
    """One scene on one GL context: frames of ``size = (w, h)`` pixels with a vertical
    field of view ``fov_y_deg`` (degrees): every layer composited (:meth:`draw`), or the
    terrain at full resolution or a uniform level (:meth:`render`).

    ``ctx=None`` makes a headless EGL context that the renderer owns; a
    :class:`moderngl.Context` (current on this thread) is used as it is and never
    released.  ``framebuffer``: one of that context's framebuffers (a window's screen,
    with a depth buffer) to draw frames straight into, at its size, instead of an
    offscreen image of the renderer's own: nothing to copy to show them.  GPU objects
    live until :meth:`release` (or the ``with`` block's end).
    """

    def __init__(self, scene: Scene, size: tuple[int, int] = (512, 512),
                 fov_y_deg: float = 45.0, ctx: moderngl.Context | None = None,
                 framebuffer: moderngl.Framebuffer | None = None) -> None:
        if framebuffer is not None:
            if ctx is None:
                raise InputError("framebuffer= needs the ctx= it belongs to")
            if tuple(framebuffer.viewport[:2]) != (0, 0):
                raise InputError("framebuffer= must have its viewport at (0, 0); draw into "
                                 "an offset viewport with draw_to() instead")
            size = tuple(framebuffer.viewport[2:])
        w, h = (int(v) for v in size)
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be between 16 and 8192 pixels, got {w}x{h}")
        self.scene = scene
        self.size = (w, h)
        self.fov_y_deg = float(fov_y_deg)
        self.gl = GLContext() if ctx is None else GLContext.wrap(ctx)
        self._terrain_gl = None  # the terrain layer's GL state (none without one)
        if scene.hf is not None:
            try:
                self._terrain_gl = TerrainGL(scene, self.size, self.fov_y_deg, self.gl,
                                           framebuffer)
            except BaseException:
                self.gl.release()  # a context of our own only; a wrapped one is forgotten
                raise
        self._presenter: Presenter | None = None
        self._sprites: list[LodSprite] = []  # released with the renderer
        self._own_terrain_gl = True
        self._own_target: RenderTarget | None = None  # a scene without terrain's image
        self._layers: Any = None  # the layered reference drawing every layer (draw())

    @classmethod
    def wrap(cls, terrain_gl: TerrainGL) -> Renderer:
        """A renderer over existing GL state ``terrain_gl`` (its scene, size and field of
        view), which it never releases: what a caller holding a
        :class:`~lodsprite.gl.terrain_gl.TerrainGL` passes to a technique."""
        self = cls.__new__(cls)
        r = terrain_gl.drawer
        self.scene, self.size = terrain_gl.scene, (r.target.width, r.target.height)
        self.fov_y_deg = float(r.fov_y_deg)
        self.gl, self._terrain_gl = terrain_gl.ctx, terrain_gl
        self._presenter, self._sprites, self._own_terrain_gl = None, [], False
        self._own_target, self._layers = None, None
        return self

    @property
    def info(self) -> GLInfo:
        """The GL driver's renderer and version strings."""
        return self.gl.info

    @property
    def terrain_gl(self) -> TerrainGL:
        """The terrain layer's GL state (context, geometry, terrain drawer)."""
        return self._terrain()

    def _terrain(self) -> TerrainGL:
        if self._terrain_gl is None:
            raise InputError("this scene has no terrain layer to draw")
        return self._terrain_gl

    @property
    def target(self) -> RenderTarget:
        """The image every layer draws into: the terrain's, or (a scene without terrain)
        one of the renderer's own, with a depth buffer, made on first use."""
        if self._terrain_gl is not None:
            return self._terrain_gl.drawer.target
        if self._own_target is None:
            from lodsprite.gl.target import RenderTarget

            self._own_target = RenderTarget(self.gl, *self.size)
        return self._own_target

    def draw(self, viewpoint: Viewpoint, t: float = 0.0) -> Frame:
        """Draw every layer of the scene at ``viewpoint`` and time ``t`` seconds (walkers
        moved), composited by depth at full detail: full-resolution terrain, full meshes,
        every light field node (the ``scene`` technique's reference, :func:`~lodsprite.
        layered.technique.reference`, made through the registry); returns once the GL
        work is done.  A light field alone (a lumigraph folder) is drawn from every node
        of it (the ``lumigraph-full`` technique) into :attr:`target`."""
        from lodsprite import techniques

        alone = self.scene.hf is None and self.scene.objects is None
        if self._layers is None:
            self._layers = (techniques.create("lumigraph-full", self) if alone else
                            techniques.create("scene", self, ground_truth=True))
            self._layers.warm_up(viewpoint)
        if not alone:
            self._layers.index = max(0, round(float(t) / self._layers.frame_s))
        frame = self._layers.frame(viewpoint)
        if alone:
            self._layers.draw_to(self.target.fbo)
        self.gl.finish()
        return frame

    def projection(self, viewpoint: Viewpoint) -> Projection:
        """The frame projection at ``viewpoint`` (near/far fitted to the terrain; without
        one, 0.1 m to 100 km)."""
        if self._terrain_gl is None:
            return Projection(self.fov_y_deg, self.size[0] / self.size[1], 0.1, 1e5)
        return self._terrain_gl.drawer.projection(viewpoint)

    def render(self, viewpoint: Viewpoint, lod: int | None = None) -> Frame:
        """Draw the terrain at full resolution (``lod=None``) or at uniform level ``lod``
        (quads per side) into the renderer's image; returns once the GL work is done."""
        stats = self._terrain().drawer.render(viewpoint, lod)
        self.gl.finish()
        return stats

    def read_color(self) -> np.ndarray:
        """The last image, ``(h, w, 3) uint8``, row 0 at the top (any scene's)."""
        return self.target.read_color()

    def read_depth(self) -> np.ndarray:
        """The last z-buffer, ``(h, w) float32`` window depth in [0, 1], row 0 at the top."""
        return self.target.read_depth()

    def sprite(self, epsilon_px: float = DEFAULT_EPSILON_PX, lod: int = DEFAULT_COARSE,
               threaded: bool = False, visibility: str = DEFAULT_VISIBILITY,
               guard_px: int = DEFAULT_GUARD_PX, border: bool = True, cache_mb: float = 0.0,
               cache_policy: str = DEFAULT_POLICY, metric: str = "warp",
               store=None, depth_stride: int | None = None,
               key_scale: float = 1.0, pair: bool = False) -> LodSprite:
        """A LOD-sprite engine on this renderer: error threshold ``epsilon_px`` pixels,
        coarse level ``lod`` quads per side.  ``threaded=True`` renders keyframes in a
        worker process with its own context (:mod:`lodsprite.sprite.worker_engine`); otherwise a
        keyframe is rendered inline in the frame that needs it (the 1999 algorithm).
        ``cache_mb > 0`` keeps keyframes in a GPU cache of that many MB replaced by
        ``cache_policy`` (``lru`` | ``benefit``; :mod:`lodsprite.sprite.cache`; inline
        keyframes only).  ``metric``: ``"warp"`` (Eq. 1-2), ``"resample"`` (adds the
        keyframe image's resampling error, :mod:`lodsprite.sprite.resampling`) or
        ``"depth"`` (the estimate on each keyframe's own depth, with ``depth_stride``:
        :mod:`lodsprite.sprite.depth_metric`).  ``store``:
        the worker's keyframes over a terrain store, drawn adaptively
        (:class:`~lodsprite.sprite.worker_settings.StoreKeys`; threaded only).
        ``depth_stride``: spriteframes draw a mesh from the keyframe's own depth, a vertex
        every that many keyframe texels (None: the coarse level); ``key_scale``: keyframe
        texels a display pixel side; ``pair``: the keyframe before the current one drawn
        too, composited by depth (:class:`~lodsprite.gl.sprite.SpriteDrawer`)."""
        if not epsilon_px > 0:
            raise InputError(f"epsilon must be > 0 pixels, got {epsilon_px}")
        if not cache_mb >= 0:
            raise InputError(f"cache_mb must be >= 0 MB, got {cache_mb}")
        if cache_mb > 0 and threaded:
            raise InputError("the keyframe cache needs inline keyframes "
                             "(--inline-keyframes)")
        sprite = LodSprite(self, epsilon_px, lod, threaded, visibility, guard_px, border,
                           cache_mb, cache_policy, metric, store, depth_stride, key_scale,
                           pair)
        self._sprites.append(sprite)
        return sprite

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
        """Draw the last image over ``framebuffer``'s viewport (default: the context's
        screen, the window of an embedding application).  Rendering binds lodsprite's own
        targets, so an application passes the framebuffer it draws into next."""
        target = self.target
        if target.external:  # already drawn there, or copied from there
            dst = framebuffer if framebuffer is not None else self.gl.default_fbo
            if dst is not target.fbo and dst.glo != target.fbo.glo:
                self.gl.mgl.copy_framebuffer(dst, target.fbo)
            return
        self.present(target.color, (0.0, 0.0, 1.0, 1.0), framebuffer, target.fbo)

    def present(self, texture: moderngl.Texture, uv: tuple[float, float, float, float],
                 framebuffer: moderngl.Framebuffer | None,
                 source: moderngl.Framebuffer | None = None) -> None:
        """Draw ``texture``'s region ``uv`` over ``framebuffer`` (default: the context's
        screen).  A whole image of the framebuffer's size (``source``, its framebuffer) is
        copied with a blit, which costs a third of a textured quad on llvmpipe."""
        dst = framebuffer if framebuffer is not None else self.gl.default_fbo
        if (source is not None and uv == (0.0, 0.0, 1.0, 1.0)
                and tuple(dst.viewport) == (0, 0, *source.size)):
            self.gl.mgl.copy_framebuffer(dst, source)
            return
        if self._presenter is None:
            self._presenter = Presenter(self.gl)
        dst.use()
        self._presenter.draw(texture, uv)

    def release(self) -> None:
        """Release every GPU object, the sprites made here included (and the context, if
        the renderer made it)."""
        for sprite in self._sprites:
            sprite.release()
        self._sprites.clear()
        if self._layers is not None:
            self._layers.release()
            self._layers = None
        if self._own_target is not None:
            self._own_target.release()
            self._own_target = None
        if self._presenter is not None:
            self._presenter.release()
            self._presenter = None
        if self._terrain_gl is not None:
            if self._own_terrain_gl:
                self._terrain_gl.release()
            self._terrain_gl = None
        if self.gl is not None and self.gl.owned and self._own_terrain_gl:
            self.gl.release()
        self.gl = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class LodSprite:
    """LOD-sprite frame by frame on a :class:`RenderActor` (made by :meth:`Renderer.sprite`).

    :meth:`frame` decides, renders and times one frame; :attr:`keyframes` lists every
    keyframe taken (:class:`~lodsprite.sprite.policy.KeyChoice`); :meth:`read_image` and
    :meth:`draw_to` give the frame shown.
    """

    def __init__(self, renderer: Renderer, epsilon_px: float, lod: int, threaded: bool,
                 visibility: str, guard_px: int, border: bool, cache_mb: float = 0.0,
                 cache_policy: str = DEFAULT_POLICY, metric: str = "warp",
                 store=None, depth_stride: int | None = None,
                 key_scale: float = 1.0, pair: bool = False) -> None:
        self.renderer = renderer
        self.threaded = threaded
        self.sprite = SpriteDrawer(renderer.terrain_gl.drawer, lod, visibility, border=border,
                                   guard_px=guard_px, depth_stride=depth_stride,
                                   key_scale=key_scale, pair=pair)
        try:
            self.engine: LodSpriteEngine | WorkerLodSpriteEngine = (
                WorkerLodSpriteEngine(self.sprite, renderer.scene, renderer.fov_y_deg,
                                        epsilon_px, metric=metric, store=store) if threaded
                else LodSpriteEngine(self.sprite, epsilon_px, cache_mb=cache_mb,
                                     cache_policy=cache_policy, metric=metric))
        except BaseException:
            self.sprite.release()
            raise
        self.last: Frame | None = None

    @property
    def epsilon_px(self) -> float:
        return self.engine.epsilon_px

    @epsilon_px.setter
    def epsilon_px(self, value: float) -> None:
        if not value > 0:
            raise InputError(f"epsilon must be > 0 pixels, got {value}")
        if isinstance(self.engine, LodSpriteEngine):
            self.engine.policy.epsilon_px = float(value)
        else:
            self.engine.epsilon_px = float(value)

    @property
    def keyframes(self) -> list:
        return self.engine.keyframes

    @property
    def lod(self) -> int:
        return self.sprite.coarse_quads

    def frame(self, viewpoint: Viewpoint) -> Frame:
        """Render the frame for ``viewpoint`` (returns after ``ctx.finish()``)."""
        self.last = self.engine.frame(viewpoint)
        return self.last

    def read_image(self) -> np.ndarray:
        """The frame shown, ``(h, w, 3) uint8``, row 0 at the top."""
        return self.engine.read_image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        """The shown keyframe's viewpoint and (guard-band widened) projection."""
        key = self.sprite.keyframe
        return None if key is None else (key.viewpoint, key.projection)

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
        """Draw the frame shown over ``framebuffer``'s viewport (default: the context's
        screen): the keyframe's centre (without its guard band) or the spriteframe."""
        key = self.sprite.keyframe
        if isinstance(self.engine, LodSpriteEngine) and self.engine.shows_keyframe and key:
            w, h = key.color.size
            g = self.sprite.guard_px
            self.renderer.present(key.color, (g / w, g / h, 1 - g / w, 1 - g / h),
                                   framebuffer)
        else:
            self.renderer.draw_to(framebuffer)

    def release(self) -> None:
        """Stop the keyframe worker (if any) and release the sprite's GPU objects (once;
        :meth:`Renderer.release` calls it for every sprite not released yet)."""
        if self.sprite is None:
            return
        if isinstance(self.engine, WorkerLodSpriteEngine):
            self.engine.close()
        self.sprite.release()
        self.sprite = None
        if self in self.renderer._sprites:
            self.renderer._sprites.remove(self)

    def __enter__(self) -> LodSprite:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def read_image(path: str | os.PathLike) -> np.ndarray:
    """An image file as ``(h, w, 3) uint8`` RGB (raises :class:`InputError`)."""
    try:
        with Image.open(Path(path)) as im:
            if im.width * im.height > MAX_IMAGE_PIXELS:
                raise InputError(f"{path}: image of {im.width}x{im.height} is too large")
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise InputError(f"cannot read image {path}: {exc}") from exc


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an ``(h, w, 3) uint8`` image as PNG (atomically: no half-written file)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"image must be an (h, w, 3) uint8 array, got {image.shape} "
                         f"{image.dtype}")
    try:
        write_png(Path(path), image)
    except OSError as exc:
        raise InputError(f"cannot write image {path}: {exc.strerror or exc}") from exc
