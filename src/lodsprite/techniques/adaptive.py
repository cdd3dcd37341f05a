"""The adaptive terrain renderer (:mod:`lodsprite.techniques.adaptive_terrain`) as techniques:
``adaptive`` draws every frame with it; ``sprite-adaptive`` is LOD-sprite whose keyframes
it draws (``--key-sse``), streaming between keyframes.  Both fly a store of any size
(the scene's terrain spec names the store) or the scene's in-memory height field.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.sprite.policy import KEYFRAME
from lodsprite.techniques.adaptive_keys import (
    AdaptiveKeys,
    WorkerAdaptiveKeys,
    adaptive_keys,
)
from lodsprite.techniques.adaptive_terrain import ADAPTIVE_COLUMNS
from lodsprite.techniques.base import Frame, Param, Technique
from lodsprite.techniques.defaults import MEMORY_DEFAULTS, STORE_DEFAULTS
from lodsprite.techniques.terrain import (
    SpriteTechnique,
    attach_clipmap,
    clipped,
    resolve_shading,
    set_shading,
)
from lodsprite.workers import peak_rss_mb

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.techniques.base import RendererLike


def scene_pyramid(scene):
    """What the adaptive renderer draws for ``scene``: the store itself when its terrain
    spec names one, else its height field as an in-memory pyramid (the field full
    resolution draws)."""
    from lodsprite.terrain.pyramid import MemoryPyramid
    from lodsprite.terrain.remote import location
    from lodsprite.terrain.store import TerrainStore, is_store

    if is_store(scene.terrain_spec):
        return TerrainStore(location(scene.terrain_spec),
                            float(scene.hf.meta.get("exaggeration", 1.0)))
    return MemoryPyramid.from_heightfield(scene.hf)


#: The keyframe worker process's handler over a store (its module builds what this one's
#: ``sprite-adaptive`` builds for keyframes, and imports neither this module nor the api).
WORKER_FACTORY = "lodsprite.techniques.adaptive_worker:store_keyframe_handler"

#: Node grids the adaptive renderer takes (quads a node side); 64 is the default.
GRIDS = (16, 32, 64, 128)


def make_adaptive(renderer: RendererLike, sse: float, gpu_mb: float, host_mb: float,
                  shading: str = "auto", grid: int = 64):
    """An :class:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain` on ``renderer``'s context
    and target, coloured with the scene's texture or shaded from its heights (``shading``,
    :func:`~lodsprite.techniques.terrain.resolve_shading`); ``grid`` quads a node side
    (:data:`GRIDS`: a smaller grid has smaller nodes, so a coarser tolerance draws fewer
    triangles, at more draws a frame)."""
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain

    if int(grid) != grid or int(grid) not in GRIDS:
        raise InputError(f"grid must be one of {', '.join(map(str, GRIDS))} quads, got {grid}")
    pr = renderer.terrain_gl
    heights = resolve_shading(renderer.scene, shading) == "heights"
    if not heights:
        attach_clipmap(renderer)
    return AdaptiveTerrain(pr.ctx, scene_pyramid(renderer.scene), pr.drawer.target,
                           renderer.fov_y_deg, sse, grid=int(grid), gpu_mb=gpu_mb,
                           host_mb=host_mb, color=None if heights else pr.geometry.color_tex,
                           clip=None if heights else pr.geometry.clip)


def tile_status(terrain) -> str:
    """The HUD's line of tiles: resident on the GPU, loaded so far, in flight."""
    loader = terrain.loader
    return (f"tiles: {len(terrain.slots.slots)} resident, {loader.loaded} loaded, "
            f"{getattr(loader, 'in_flight_tiles', 0)} in flight")


def reader_mb(terrain) -> float:
    """The tile reader process's peak resident memory, MB (0 without one)."""
    return getattr(terrain.loader, "reader_peak_mb", lambda: 0.0)()


def reader_restarts(terrain) -> int:
    """How many times the tile reader process was started again after dying (0 without
    a reader process)."""
    worker = getattr(terrain.loader, "worker", None)
    return 0 if worker is None else min(int(worker.deaths), int(worker.restarts))


def process_age_s() -> float:
    """Seconds since this process started (``/proc/self/stat`` starttime against
    ``/proc/uptime``, clock-tick resolution); NaN where ``/proc`` cannot be read."""
    import os

    try:
        with open("/proc/self/stat") as f:
            start = int(f.read().rpartition(")")[2].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")
    return uptime - start / os.sysconf("SC_CLK_TCK")


def tile_summary(terrain) -> dict[str, Any]:
    """Peak memory (with the tile reader process's), the tile caches' counts, tiles that
    could not be read and the reader's restarts."""
    reader = reader_mb(terrain)
    return {"peak_rss_mb": peak_rss_mb() + reader, "peak_rss_mb_reader": reader,
            "reader_restarts": reader_restarts(terrain),
            "tiles_resident": len(terrain.slots.slots), "tiles_loaded": terrain.loader.loaded,
            "tiles_evicted": terrain.slots.evicted, "tiles_bad": len(terrain.loader.bad),
            "gpu_cache_tiles": terrain.slots.capacity, "levels": terrain.tree.levels,
            "gpu_cache_mb": terrain.slots.capacity * (terrain.tree.g + 1) ** 2 * 4 / 2 ** 20}


def level0_reader_mb(heights) -> float:
    """The level-0 reader process's peak resident memory, MB (0 without one)."""
    reader = getattr(heights, "reader", None)
    return 0.0 if reader is None else reader.peak_mb()


def level0_summary(heights) -> dict[str, Any]:
    """The level-0 reads of LOD-sprite's metric and proxy over a store (``heights`` a
    :class:`~lodsprite.terrain.storefield.LazyHeights`, or None: nothing)."""
    if heights is None:
        return {}
    return {"peak_rss_mb_level0_reader": level0_reader_mb(heights),
            "level0_chunks_read": heights.chunks_read,
            "level0_samples_approximate": heights.approximate,
            "level0_chunks_bad": len(heights.bad),
            "level0_reader_restarts": heights.reader_restarts}


class AdaptiveTechnique(Technique):
    """Every frame by the adaptive renderer at ``sse`` pixels of screen-space error,
    tiles through caches of ``gpu_mb`` and ``host_mb``, nodes of ``grid`` quads a side.
    Its warm-up streams the first view's tiles until none is left to load and draws it
    (:meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.settle`: shaders
    compiled, the first view resident), as every technique's warm-up does; when that
    first frame is done, from the process's start, is ``first_frame_s``; from the
    technique's making ``first_frame_s_technique``.  Records each frame's selection; its
    replay reads those tiles and draws the same selection."""

    name = "adaptive"

    def __init__(self, renderer: RendererLike, sse: float = 1.0, gpu_mb: float = 256.0,
                 host_mb: float = 512.0, shading: str = "auto", grid: int = 64) -> None:
        super().__init__(renderer)
        self._t0 = time.perf_counter()
        # the renderer's full resolution (the default reference) is coloured the same way
        self.shading = set_shading(renderer, shading)
        self.terrain = make_adaptive(renderer, sse, gpu_mb, host_mb, shading, grid)
        self.first_frame_s = self.first_frame_s_technique = float("nan")

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """The first view's tiles streamed in and drawn (untimed: the harness's
        ``first_frame_ms``); the timed run starts with them resident."""
        self.terrain.settle(viewpoint)
        self._first_frame()

    def _first_frame(self) -> None:
        if self.first_frame_s_technique != self.first_frame_s_technique:  # NaN: first
            self.first_frame_s_technique = time.perf_counter() - self._t0
            self.first_frame_s = process_age_s()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self.terrain.frame(viewpoint)
        self._first_frame()  # a window's first frame (no warm-up there)
        return replace(f, extra={k: f.extra[k] for k in ADAPTIVE_COLUMNS if k != "bad"})

    def decision(self) -> dict[str, Any]:
        return {"draw": tuple(self.terrain.last_draw), "morphed": self.terrain.last_morphed}

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        self.terrain.redraw(viewpoint, decision["draw"], decision["morphed"])
        return self.read_image()

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"sse": self.terrain.sse, "first_frame_s": self.first_frame_s,
                "shading": self.shading,
                "first_frame_s_technique": self.first_frame_s_technique,
                **tile_summary(self.terrain)}

    def status(self) -> str:
        return f"sse {self.terrain.sse:g} px; {tile_status(self.terrain)}"

    def params(self) -> dict[str, Param]:
        """The tolerance, live: a key press or a frame-time controller turns it."""
        return {"sse": Param("sse", self.terrain.sse, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "sse":
            super().set_param(name, value)
        self.terrain.set_sse(value)

    def outside_mb(self) -> float:
        return reader_mb(self.terrain)

    def release(self) -> None:
        self.terrain.release()


class SpriteAdaptiveTechnique(SpriteTechnique):
    """LOD-sprite with keyframes drawn by the adaptive renderer at ``key_sse`` pixels
    (inline keyframes); it streams between keyframes.  Over a store the coarse proxy,
    ribbons and the metric's coarse triangles come from the store's coarse level held
    whole (:meth:`~lodsprite.terrain.storefield.LazyHeights.from_coarse`: no level-0 chunk
    is read at setup), and the metric's ``C`` from each keyframe's own drawn nodes
    (:mod:`lodsprite.techniques.drawn_surface`).  Each keyframe's selection is
    recorded; the replay draws it again with the same nodes (their tiles read then).
    ``proxy_sse``: spriteframes draw the adaptive mesh at that tolerance, selected at each
    keyframe and frozen (:mod:`lodsprite.techniques.sprite_proxy`), with the error metric
    of :mod:`lodsprite.sprite.proxy_metric`; the replay freezes the recorded selection.
    With ``tiles > 1`` the proxy is frozen at a tile update and kept by the next ones until
    stale (:mod:`lodsprite.sprite.proxy_hold`; its coarse z-buffers and the spriteframes
    draw it) and every tile's error is the proxy
    metric over the samples it serves (:mod:`lodsprite.sprite.tiled_engine`).  The hooks
    on LOD-sprite's engine, whole keyframes or tiles, are :attr:`keys`
    (:mod:`lodsprite.techniques.adaptive_keys`), chosen once with the engine.

    A whole keyframe carries what it lacks in its error: the screen-space error of the
    coarser nodes it drew because the tiles its tolerance needs had not arrived
    (:meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.deficit_px`, added to
    the metric's error at every frame), so a held view is keyed again as tiles arrive.

    ``keyframes="worker"``: whole keyframes drawn by a worker process with its own
    adaptive renderer and tile streaming (:mod:`lodsprite.techniques.adaptive_worker`);
    the drawing side's adaptive renderer only draws each keyframe's recorded selection
    again in the untimed replay (the summary's tile counts are then that renderer's, the
    replay's reads).  With ``tiles > 1`` the worker draws the tiles asked for, each with
    its selection and what it lacks (:mod:`lodsprite.sprite.worker_tiles`).  Not with
    ``proxy_sse``."""

    name = "sprite-adaptive"

    def __init__(self, renderer: RendererLike, lod: int = 16, epsilon: float = 1.0,
                 key_sse: float = STORE_DEFAULTS["key_sse"], gpu_mb: float = 256.0,
                 host_mb: float = 512.0,
                 visibility: str | None = None, guard_px: int | None = None,
                 border: bool = True, shading: str = "auto", tiles: int = 1,
                 tile_budget_ms: float = 8.0, cache_mb: float = 0.0,
                 cache_policy: str = "lru", metric: str = "warp",
                 proxy_sse: float | None = None, keyframes: str = "inline",
                 proxy: str = MEMORY_DEFAULTS["proxy"],
                 depth_stride: int = MEMORY_DEFAULTS["depth_stride"],
                 key_scale: float = MEMORY_DEFAULTS["key_scale"],
                 pair: bool = MEMORY_DEFAULTS["pair"]) -> None:
        from lodsprite.sprite.worker_settings import StoreKeys
        from lodsprite.terrain.store import TerrainStore
        from lodsprite.terrain.storefield import store_field

        worker = keyframes == "worker"
        if worker and proxy_sse is not None:
            raise InputError("adaptive keyframes from the worker are drawn under the "
                             "uniform coarse level: no proxy_sse")
        heights = resolve_shading(renderer.scene, shading) == "heights"
        scene = renderer.scene
        store = StoreKeys(WORKER_FACTORY, scene.terrain_spec, key_sse, gpu_mb, host_mb,
                          heights, not heights and clipped(scene.terrain_spec,
                                                           scene.texture_spec)
                          ) if worker else None

        self.adaptive = make_adaptive(renderer, key_sse, gpu_mb, host_mb, shading)
        field = None
        try:
            if isinstance(self.adaptive.tree.p, TerrainStore):
                field = store_field(self.adaptive.tree.p)
                renderer.terrain_gl.geometry.set_full(field)
            # the proxy, ribbons and the metric's coarse triangles from the store's coarse
            # level held whole (no level-0 chunk at setup), then level 0 without blocking
            with nullcontext() if field is None else field.heights.from_coarse():
                super().__init__(renderer, lod, epsilon, keyframes, visibility, guard_px,
                                 border, shading=shading, tiles=tiles,
                                 tile_budget_ms=tile_budget_ms, cache_mb=cache_mb,
                                 cache_policy=cache_policy, metric=metric, store=store,
                                 proxy=proxy, depth_stride=depth_stride,
                                 key_scale=key_scale, pair=pair)
        except BaseException:
            self.adaptive.release()
            if field is not None:
                field.heights.close()
            raise
        # the adaptive renderer's hooks on the engine, whole keyframes or tiles
        self.keys: AdaptiveKeys = adaptive_keys(self.engine, self.adaptive, self._pump)
        self.surface = self.proxy = None  # the metric's C from the keyframe's drawn nodes
        self.first_frame_s = float("nan")  # from the process's start
        if worker:  # both on the worker's side
            return
        if field is not None:
            from lodsprite.techniques.drawn_surface import DrawnSurface

            self.surface = DrawnSurface(self.adaptive)
            self.keys.use_surface(self.surface.heights)
        self.proxy = None if proxy_sse is None else self._adaptive_proxy(renderer, proxy_sse)

    def tile_drawer(self, update: int, tile: int) -> Callable | None:
        """Re-renders ``tile`` with the selection update ``update`` drew it with."""
        return self.keys.tile_drawer(update, tile)

    def _pump(self) -> None:
        if self.heights is not None:
            self.heights.pump()

    def _adaptive_proxy(self, renderer: RendererLike, proxy_sse: float):
        """Spriteframes, coarse z-buffers and the error metric on the adaptive mesh at
        ``proxy_sse`` px (:mod:`lodsprite.techniques.sprite_proxy`)."""
        from lodsprite.techniques.sprite_proxy import AdaptiveProxySource

        source = AdaptiveProxySource(self.adaptive, proxy_sse, self.sprite.sprite.target.height)
        self.keys.use_proxy(source, renderer.terrain_gl.geometry.full,
                            None if self.surface is None else self.surface.points)
        return source

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """The keyframe's view (its guard band too) streamed in by the adaptive renderer
        until no tile is left to load, then LOD-sprite's warm-up (a keyframe and a
        spriteframe drawn, untimed): the timed run starts with the first view resident,
        as the adaptive technique's does."""
        s = self.sprite.sprite
        if not isinstance(self.keys, WorkerAdaptiveKeys):  # a worker fills its own
            self.adaptive.fill(viewpoint,
                               s.key_projection(s.terrain.projection(viewpoint)).matrix())
        super().warm_up(viewpoint)
        if self.first_frame_s != self.first_frame_s:  # NaN: the first frame
            self.first_frame_s = process_age_s()
        self.keys.warmed_up()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = super().frame(viewpoint)
        # a keyframe shown as it is: its error is what it lacks (a worker's start-up frame
        # is a spriteframe, whose error has it already)
        if f.kind == KEYFRAME and not isinstance(self.keys, WorkerAdaptiveKeys):
            f = replace(f, error_px=f.error_px + getattr(self.keys, "deficit_px", 0.0))
        if self.first_frame_s != self.first_frame_s:  # NaN: the first frame
            self.first_frame_s = process_age_s()
        return f

    def decision(self) -> dict[str, Any]:
        """The keyframe shown; for a new one, the selection it was drawn with (recorded
        here, after the frame's clock stopped: nothing draws between the two)."""
        d = super().decision()
        self.keys.record(d)
        return d

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        return self.keys.replay(viewpoint, decision)

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        out = {**super().summary(frames), "key_sse": self.adaptive.sse,
               "first_frame_s": self.first_frame_s, **tile_summary(self.adaptive),
               **level0_summary(self.heights), "proxy_sse": None}
        out["peak_rss_mb"] += out.get("peak_rss_mb_level0_reader", 0.0)
        if self.proxy is not None:
            tris = self.proxy.triangles
            out.update(proxy_sse=self.proxy.sse,
                       mean_proxy_triangles=float(np.mean(tris)) if tris else float("nan"))
        return out

    def status(self) -> str:
        if isinstance(self.keys, WorkerAdaptiveKeys):
            return f"adaptive keyframes, sse {self.adaptive.sse:g} px; {super().status()}"
        return f"keyframes: adaptive, sse {self.adaptive.sse:g} px; {tile_status(self.adaptive)}"

    def outside_mb(self) -> float:
        return reader_mb(self.adaptive) + level0_reader_mb(self.heights)

    def release(self) -> None:
        super().release()  # the level-0 reader too
        if self.proxy is not None:
            self.proxy.release()
        self.adaptive.release()
