"""The keyframe worker process over a terrain store (Swan et al. 2002's LOD server, with
the adaptive renderer drawing keyframes: ``sprite-adaptive --keyframes worker``).

The process (:func:`store_keyframe_handler`, :mod:`lodsprite.workers`' factory, named by
:data:`lodsprite.techniques.adaptive.WORKER_FACTORY`) makes its own headless context and
the drawing side's terrain from the arrays handed over through shared memory (a store's
light grid), opens the store at the path the user gave (validated there as on the
drawing side: :class:`~lodsprite.terrain.store.TerrainStore`; an in-memory terrain is
drawn from its arrays as a pyramid) and builds what ``sprite-adaptive`` builds for its
keyframes: its own adaptive renderer (tile reader and caches), the coarse level with its
ribbons from the store's coarse level, the level-0 reader, and the error metric whose
``C`` is the surface each keyframe draws (:class:`~lodsprite.techniques.drawn_surface.
DrawnSurface`).  Per request it streams (collects the tiles arrived: never waits, except
for the first keyframe, whose view it fills as the inline technique's warm-up does),
takes the keyframe's ``C'``, draws the keyframe adaptively at ``key_sse`` and answers it
with:

* ``deficit_px`` — what it lacks (:meth:`~lodsprite.techniques.adaptive_terrain.
  AdaptiveTerrain.deficit_px`): its ``C'`` carries it into the keyframe's error on the
  drawing side every frame, so a keyframe drawn while tiles stream is asked for again
  until they have arrived;
* ``selection`` — the nodes drawn and those morphed, which the drawing side's untimed
  replay draws again (:class:`~lodsprite.techniques.adaptive_keys.WorkerAdaptiveKeys`);
* ``points`` — the keyframe's own ``C`` (pickling a ``C'`` drops them).

With tiles (:attr:`~lodsprite.sprite.worker_settings.WorkerSettings.tiles`) a request
names the tiles to draw: each is drawn adaptively, culled by its sub-frustum (the
update's stream request is its tiles' selections gathered, as the inline
``TiledAdaptiveKeys`` does), and answered with its own selection and what it lacks
(:mod:`lodsprite.sprite.worker_tiles`).

It imports no technique and no :mod:`lodsprite.api` (the process is named by the
technique, so importing it back would be a cycle): it builds the GL objects itself.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import replace
from typing import TYPE_CHECKING

from lodsprite.sprite.keyframe_process import (
    keyframe_answer,
    render_tiles_at,
    serve,
    tile_c_prime,
    tiled_drawer,
    tiles_answer,
)
from lodsprite.sprite.metric import ErrorMetric

if TYPE_CHECKING:
    import numpy as np

    from lodsprite.camera import Viewpoint
    from lodsprite.sprite.worker_settings import WorkerSettings
    from lodsprite.terrain import HeightField


def store_keyframe_handler(shm_name: str, layout: dict, field: tuple,
                           settings: WorkerSettings):
    """The worker process's request handler over a store (the requests and answers of
    :func:`~lodsprite.sprite.keyframe_process.keyframe_handler`, module docstring)."""
    return serve(StoreKeyframes, shm_name, layout, field, settings)


class StoreKeyframes:
    """The worker's GL state: its own context, the terrain ``hf`` (the drawing side's
    working grid; ``texture (H, W, 3) uint8`` or None), the adaptive renderer over the
    store ``settings.store.path`` at ``key_sse`` and the sprite renderer whose keyframes
    it draws."""

    def __init__(self, hf: HeightField, texture: np.ndarray | None,
                 s: WorkerSettings, ctx=None) -> None:
        from lodsprite.gl.context import GLContext
        from lodsprite.gl.sprite import SpriteDrawer
        from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry
        from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
        from lodsprite.techniques.drawn_surface import DrawnSurface
        from lodsprite.terrain.pyramid import MemoryPyramid
        from lodsprite.terrain.remote import location
        from lodsprite.terrain.store import TerrainStore, is_store
        from lodsprite.terrain.storefield import store_field

        keys = s.store
        self.ctx = GLContext() if ctx is None else ctx  # given: shared, not released here
        made: list = [self.ctx] if ctx is None else []
        self.heights = None
        try:
            geometry = TerrainGeometry(self.ctx, hf, texture)
            made.append(geometry)
            self.terrain = TerrainDrawer(self.ctx, geometry, s.size[0], s.size[1],
                                         s.fov_y_deg)
            made.append(self.terrain)
            pyramid = (TerrainStore(location(keys.path),
                                    float(hf.meta.get("exaggeration", 1.0)))
                       if is_store(keys.path) else MemoryPyramid.from_heightfield(hf))
            if keys.clip and isinstance(pyramid, TerrainStore):  # finer imagery, streamed
                from lodsprite.techniques.terrain import use_clipmap

                use_clipmap(geometry, pyramid)
            self.adaptive = AdaptiveTerrain(
                self.ctx, pyramid, self.terrain.target, s.fov_y_deg, keys.key_sse,
                gpu_mb=keys.gpu_mb, host_mb=keys.host_mb,
                color=None if keys.heights else geometry.color_tex,
                clip=None if keys.heights else geometry.clip)
            made.append(self.adaptive)
            field = store_field(pyramid) if isinstance(pyramid, TerrainStore) else None
            if field is not None:
                geometry.set_full(field)
            # the coarse level, its ribbons and the metric's squares from the store's
            # coarse level held whole (no level-0 chunk read), as sprite-adaptive's setup
            with nullcontext() if field is None else field.heights.from_coarse():
                self.sprite = SpriteDrawer(self.terrain, s.lod, s.visibility,
                                           border=s.border, guard_px=s.guard_px,
                                           key_scale=s.key_scale)
                made.append(self.sprite)
                self.metric = ErrorMetric.for_level(geometry.full, s.lod, s.resampling)
                if field is not None:
                    geometry.proxy(s.lod, s.border)
                    field.heights.start_reader()
                    self.heights = field.heights
            self.tiled = None if s.tiles <= 1 else tiled_drawer(self.sprite, s.tiles)
        except BaseException:  # released in the order made, backwards
            for obj in reversed(made):
                obj.release()
            raise
        self._made = made
        if self.heights is not None:  # C: the surface each keyframe draws
            self.metric = replace(self.metric, surface=DrawnSurface(self.adaptive).heights)
        self.sprite.keyframe_drawer = self.adaptive.render_into
        self.zbuffer = s.zbuffer
        self.estimate_stride = s.estimate_stride
        self.key_size = s.sprite_px  # the metric's keyframe size, display pixels
        self.filled = False
        self._drawn: list[tuple] = []  # the update's tiles: (selection, deficit) each

    def keyframe(self, vp: Viewpoint):
        """The keyframe at ``vp`` drawn adaptively and finished, without its ``C'`` (a
        server's renderer that never paces); the :class:`~lodsprite.gl.sprite.GLKeyframe`
        shown, read it back as :func:`keyframe_answer` does."""
        frame_projection = self.terrain.projection(vp)
        self._ready(vp, self.sprite.key_projection(frame_projection))
        self._draw(vp, time.perf_counter(), frame_projection, 1.0)
        return self.sprite.keyframe

    def _draw(self, vp: Viewpoint, t0: float, frame_projection, spread: float) -> None:
        self.sprite.render_keyframe(vp, t0, frame_projection, spread=spread)
        self.ctx.finish()

    def release(self) -> None:
        """The level-0 reader stopped, the GL objects released, the context too when it
        is this object's own (a worker process ends with it; a renderer that keeps
        several scenes on one context releases them one by one).  Idempotent."""
        if self.heights is not None:
            self.heights.close()
            self.heights = None
        made, self._made = self._made, []
        for obj in reversed(made):
            obj.release()

    def _ready(self, vp: Viewpoint, key_projection) -> None:
        """Before a keyframe or tile update: the first one's view resident (waited for,
        as the inline technique's warm-up), the level-0 chunks and tiles arrived taken
        (neither waits)."""
        if not self.filled:
            self.adaptive.fill(vp, key_projection.matrix())
            self.filled = True
        if self.heights is not None:
            self.heights.pump()
        self.adaptive.prefetch()

    def _draw_tile(self, vp: Viewpoint, projection, target, cull):
        """A tile by the adaptive renderer, culled by its sub-frustum (an update's
        stream request is its tiles' selections gathered); its selection and what it
        lacks kept."""
        stats = self.adaptive.render_into(vp, projection, target, cull)
        self._drawn.append(((tuple(self.adaptive.last_draw), self.adaptive.last_morphed),
                            self.adaptive.deficit_px()))
        return stats

    def render_tiles(self, vp: Viewpoint, predicted: bool, asked: float,
                     tiles: tuple[int, ...]) -> tuple[bytes, bytes]:
        """The keyframe's ``tiles`` at ``vp`` drawn adaptively, as an answer
        (:func:`~lodsprite.sprite.keyframe_process.tiles_answer`, with per tile its
        selection and what it lacks)."""
        t0 = time.perf_counter()
        frame_projection = self.terrain.projection(vp)
        key = self.sprite.key_projection(frame_projection)
        self._ready(vp, key)
        key_vp = key.matrix() @ vp.view_matrix()
        c_prime = tile_c_prime(self.metric, self.tiled, tiles, vp, key_vp)  # C' first
        self._drawn.clear()
        self.adaptive.gathering = ([], set())
        try:
            render_tiles_at(self.tiled, tiles, vp, key, self._draw_tile)
        finally:
            self.adaptive.gathering = None
        self.ctx.finish()
        return tiles_answer(self.tiled, tiles, t0, {
            "viewpoint": vp, "frame_projection": frame_projection, "requested_at": asked,
            "predicted": predicted, "projection": key, "c_prime": c_prime,
            "points": getattr(c_prime, "points", None),
            "selections": tuple(d[0] for d in self._drawn),
            "deficits": tuple(d[1] for d in self._drawn)})

    def render(self, vp: Viewpoint, predicted: bool, asked: float,
               spread: float = 1.0) -> tuple[bytes, bytes]:
        """The keyframe at ``vp`` drawn adaptively (its guard band ``spread``), as an
        answer (module docstring)."""
        t0 = time.perf_counter()
        s, adaptive = self.sprite, self.adaptive
        frame_projection = self.terrain.projection(vp)
        key_projection = s.key_projection(frame_projection, spread)
        self._ready(vp, key_projection)
        c_prime = self.metric.reproject(vp.o, key_projection.matrix() @ vp.view_matrix(),
                                        self.key_size)
        self._draw(vp, t0, frame_projection, spread)
        return keyframe_answer(s, self.zbuffer, {
            "viewpoint": vp, "frame_projection": frame_projection, "c_prime": c_prime,
            "requested_at": asked, "predicted": predicted,
            "points": getattr(c_prime, "points", None), "deficit_px": adaptive.deficit_px(),
            "selection": (tuple(adaptive.last_draw), adaptive.last_morphed)}, t0,
            self.estimate_stride)
