"""The keyframe worker's process side (:mod:`lodsprite.sprite.keyframe_worker` is the
drawing side's end): its priority lowered, its own headless OpenGL context and the
scene's in-memory terrain made from the arrays handed over through shared memory, the
full-resolution keyframe rendered for each viewpoint sent, its colour, z-buffer and
``C'`` answered.  Over a store the process runs
:func:`lodsprite.techniques.adaptive_worker.store_keyframe_handler` instead.
"""

from __future__ import annotations

import pickle
import time
from multiprocessing import shared_memory
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.procs import lower_priority
from lodsprite.sprite.guard import MAX_SPREAD
from lodsprite.sprite.metric import ErrorMetric

if TYPE_CHECKING:
    from lodsprite.sprite.worker_settings import WorkerSettings
    from lodsprite.terrain import HeightField



def copy_shared(shm_name: str, layout: dict[str, tuple]) -> dict[str, np.ndarray]:
    """The arrays :func:`~lodsprite.sprite.keyframe_worker.share_arrays` put in the
    segment ``shm_name``, copied out."""
    shm = shared_memory.SharedMemory(shm_name)
    try:
        return {name: np.ndarray(shape, dtype, buffer=shm.buf, offset=off).copy()
                for name, (off, shape, dtype) in layout.items()}
    finally:
        shm.close()


def keyframe_handler(shm_name: str, layout: dict, field: tuple, settings: WorkerSettings):
    """The worker process's request handler (:mod:`lodsprite.workers`' factory): its
    priority lowered, its context and scene made from the shared arrays.  A request's
    meta is ``(viewpoint, predicted, requested_at)`` pickled; the answer's meta the
    keyframe's fields pickled, its data the depth then the colour bytes; with tiles the
    request adds the tiles to render (:func:`checked_tiles`)."""
    return serve(_WorkerGL, shm_name, layout, field, settings)


def serve(make, shm_name: str, layout: dict, field: tuple, settings: WorkerSettings):
    """A request handler: this thread's priority lowered, the terrain made from the
    shared arrays (``field``: its ``dx, dy, name, meta``) and handed with its texture to
    ``make(hf, texture, settings)``, whose ``render`` (whole keyframes) or
    ``render_tiles`` (``settings.tiles > 1``, over its ``tiled`` drawer) answers each
    request."""
    from lodsprite.terrain import HeightField

    lower_priority(settings.nice)
    arrays = copy_shared(shm_name, layout)
    dx, dy, name, meta = field
    gl = make(HeightField(arrays["heights"], dx, dy, name, meta), arrays.get("texture"),
              settings)

    def answer(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        vp, predicted, asked, spread, *tiles = pickle.loads(meta)
        if settings.tiles > 1:
            return gl.render_tiles(vp, predicted, asked, checked_tiles(tiles, gl.tiled.count))
        return gl.render(vp, predicted, asked, checked_spread(spread))

    return answer


def checked_spread(spread) -> float:
    """A request's guard band spread (:class:`~lodsprite.sprite.guard.GuardBand`): a
    number from 1 to :data:`~lodsprite.sprite.guard.MAX_SPREAD`; raises ValueError
    otherwise (the request is answered with the error, the process goes on)."""
    if not isinstance(spread, float) or not 1.0 <= spread <= MAX_SPREAD:
        raise ValueError(f"a guard band spread is a number from 1 to {MAX_SPREAD:g}")
    return spread


def checked_tiles(rest: list, count: int) -> tuple[int, ...]:
    """The tiles a request names (its one extra field): distinct whole numbers below
    ``count``, at least one; raises ValueError otherwise (the request is answered with
    the error, the process goes on)."""
    if len(rest) != 1 or not isinstance(rest[0], tuple) or not rest[0]:
        raise ValueError("a tile request names its tiles")
    tiles = rest[0]
    if len(set(tiles)) != len(tiles) or not all(
            isinstance(t, int) and 0 <= t < count for t in tiles):
        raise ValueError(f"tiles must be distinct whole numbers below {count}")
    return tiles


class _WorkerGL:
    """The worker's GL state: its own context, the terrain (height field ``hf``, colour
    ``texture (H, W, 3) uint8`` or None) and the keyframe renderer."""

    def __init__(self, hf: HeightField, texture: np.ndarray | None, s: WorkerSettings
                 ) -> None:
        from lodsprite.gl.context import GLContext
        from lodsprite.gl.sprite import SpriteDrawer
        from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry

        self.ctx = GLContext()
        made = [self.ctx]
        try:
            made.append(TerrainGeometry(self.ctx, hf, texture))
            made.append(TerrainDrawer(self.ctx, made[-1], s.size[0], s.size[1], s.fov_y_deg))
            self.terrain = made[-1]
            self.sprite = SpriteDrawer(self.terrain, s.lod, s.visibility, border=s.border,
                                       guard_px=s.guard_px, key_scale=s.key_scale)
            made.append(self.sprite)
            self.tiled = None if s.tiles <= 1 else tiled_drawer(self.sprite, s.tiles)
        except BaseException:  # released in the order made, backwards
            for obj in reversed(made):
                obj.release()
            raise
        self.metric = ErrorMetric.for_level(hf, s.lod, s.resampling)
        self.zbuffer = s.zbuffer
        self.estimate_stride = s.estimate_stride

    def render(self, vp: Viewpoint, predicted: bool, asked: float,
               spread: float = 1.0) -> tuple[bytes, bytes]:
        t0 = time.perf_counter()
        frame_projection = self.terrain.projection(vp)
        self.sprite.render_keyframe(vp, t0, frame_projection, spread=spread)
        self.ctx.finish()
        key = self.sprite.keyframe
        c_prime = self.metric.reproject(vp.o, key.projection.matrix() @ vp.view_matrix(),
                                        self.sprite.key_px)
        return keyframe_answer(self.sprite, self.zbuffer, {
            "viewpoint": vp, "frame_projection": frame_projection, "c_prime": c_prime,
            "requested_at": asked, "predicted": predicted}, t0, self.estimate_stride)


    def render_tiles(self, vp: Viewpoint, predicted: bool, asked: float,
                     tiles: tuple[int, ...]) -> tuple[bytes, bytes]:
        """The keyframe's ``tiles`` at ``vp``, rendered and answered
        (:func:`tiles_answer`)."""
        t0 = time.perf_counter()
        frame_projection = self.terrain.projection(vp)
        key = self.sprite.key_projection(frame_projection)
        render_tiles_at(self.tiled, tiles, vp, key)
        self.ctx.finish()
        key_vp = key.matrix() @ vp.view_matrix()
        return tiles_answer(self.tiled, tiles, t0, {
            "viewpoint": vp, "frame_projection": frame_projection, "requested_at": asked,
            "predicted": predicted, "projection": key,
            "c_prime": tile_c_prime(self.metric, self.tiled, tiles, vp, key_vp)})


def tiled_drawer(sprite, tiles: int):
    """A :class:`~lodsprite.gl.sprite_tiles.TiledSpriteDrawer` of ``tiles x tiles`` tiles
    over ``sprite``'s keyframe, as the drawing side's."""
    from lodsprite.gl.sprite_tiles import TiledSpriteDrawer
    from lodsprite.sprite.tiled import ndc_rects, tile_rects

    rects = tile_rects(tiles, sprite.key_size)
    return TiledSpriteDrawer(sprite, rects, ndc_rects(rects, sprite.key_size))


def render_tiles_at(tiled, tiles: tuple[int, ...], vp: Viewpoint, key, drawer=None) -> None:
    """Issue the draws of ``tiles`` of ``tiled`` from ``vp`` through the key projection
    ``key``, each culled by its sub-frustum (``drawer``: the tiles' terrain drawer)."""
    from lodsprite.sprite.tiled import sub_view_proj

    view_proj = key.matrix() @ vp.view_matrix()
    for i in tiles:
        tiled.render_tile(i, vp, key, sub_view_proj(view_proj, tiled.ndc[i]), drawer)


def tile_c_prime(metric, tiled, tiles: tuple[int, ...], vp: Viewpoint, key_vp: np.ndarray):
    """``C'`` of an update of ``tiles`` of ``tiled`` from ``vp`` (key view-projection
    ``key_vp``), reprojected for their sub-frustum
    (:func:`~lodsprite.sprite.tiled.reproject_in_key_view`)."""
    from lodsprite.sprite.tiled import reproject_in_key_view, tiles_frustum

    return reproject_in_key_view(metric, vp.o, key_vp, tiled.sprite.key_px,
                                 tiles_frustum(key_vp, tiled.ndc, tiles))


def tiles_answer(tiled, tiles: tuple[int, ...], t0: float, fields: dict
                 ) -> tuple[bytes, bytes]:
    """The answer for ``tiles`` just rendered into ``tiled``: meta ``fields`` (the key
    ``projection`` and ``c_prime`` among them) with the tiles, their byte sizes
    (``(depth and colour, coarse)`` each) and ``render_ms`` (since ``t0``); data per tile
    its depth, colour and coarse depth bytes
    (:meth:`~lodsprite.gl.sprite_tiles.TiledSpriteDrawer.read_tile`)."""
    parts = [tiled.read_tile(i) for i in tiles]
    fields = {**fields, "tiles": tuple(tiles),
              "tile_bytes": [(len(d), len(c)) for d, _, c in parts],
              "render_ms": (time.perf_counter() - t0) * 1e3}
    return pickle.dumps(fields), b"".join(b for part in parts for b in part)


def keyframe_answer(sprite, zbuffer: str, fields: dict, t0: float,
                    estimate_stride: int | None = None) -> tuple[bytes, bytes]:
    """The answer for the keyframe ``sprite`` (a :class:`~lodsprite.gl.sprite.SpriteDrawer`)
    shows: meta ``fields`` with its projection, z-buffer kind, size and ``render_ms``
    (since ``t0``, ``time.perf_counter`` seconds) pickled; data its depth (``zbuffer``:
    "coarse" or "full") then colour bytes.  ``estimate_stride``: the error estimate on
    the keyframe's own depth (:class:`~lodsprite.sprite.depth_metric.DepthEstimate`,
    that many texels between samples, weighted by its colour's contrast) built here and
    shipped as ``estimate``, so that the drawing loop does not build it on its clock."""
    key = sprite.keyframe
    color = key.target.read_color()
    depth = (key.coarse if zbuffer == "coarse" else key.target).read_depth()
    if estimate_stride is not None and zbuffer == "full":
        from lodsprite.sprite.depth_metric import DepthEstimate

        estimate = DepthEstimate(depth, key.viewpoint, key.projection, estimate_stride,
                                 sprite.texel_scale(key))
        estimate.weigh_by(color)
        fields = {**fields, "estimate": estimate}
    fields = {**fields, "projection": key.projection, "zbuffer": zbuffer,
              "render_ms": (time.perf_counter() - t0) * 1e3, "key_size": key.target.size}
    return pickle.dumps(fields), b"".join((np.ascontiguousarray(depth, np.float32).data,
                                           np.ascontiguousarray(color, np.uint8).data))
