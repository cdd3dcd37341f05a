"""How ``sprite-adaptive`` (:class:`~lodsprite.techniques.adaptive.SpriteAdaptiveTechnique`)
has the adaptive renderer draw LOD-sprite's keyframes: one class per sprite engine, chosen
once when the technique is made (:func:`adaptive_keys`):

* :class:`WholeAdaptiveKeys` — whole keyframes
  (:class:`~lodsprite.techniques.sprite_engines.WholeKeyframes`): each keyframe drawn by
  the adaptive renderer, the selection it was drawn with recorded per keyframe and drawn
  again in the replay;
* :class:`TiledAdaptiveKeys` — tile updates
  (:class:`~lodsprite.techniques.sprite_engines.TiledKeyframes`): each tile drawn by the
  adaptive renderer culled by the tile's sub-frustum, its selection recorded per (update,
  tile) and drawn again in the replay.  An update's stream request is its tiles' own
  selections gathered (``AdaptiveTerrain.gathering``), no whole-view selection; the
  view-dependent proxy is kept from update to update until stale
  (:mod:`lodsprite.sprite.proxy_hold`);
* :class:`WorkerAdaptiveKeys` — whole keyframes from the worker process
  (:class:`~lodsprite.techniques.sprite_engines.WorkerKeyframes`), drawn by its own
  adaptive renderer (:mod:`lodsprite.techniques.adaptive_worker`); each keyframe comes
  with its selection, which the replay draws again here;
* :class:`WorkerTiledAdaptiveKeys` — tiles from the worker process
  (:class:`~lodsprite.techniques.sprite_engines.WorkerTiledKeyframes`), each with its
  selection, drawn again in the replay.

The first two stream the adaptive renderer's tiles between keyframes and, before each
draw, collect the store's level-0 chunks arrived for the error metric (``pump``), neither
waiting.  The classes only wire the GL drivers' hooks; what is drawn is decided in the
sprite engines and the adaptive renderer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.techniques.sprite_engines import (
    SpriteEngine,
    TiledKeyframes,
    WorkerKeyframes,
    WorkerTiledKeyframes,
)

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain


def redraw(adaptive: AdaptiveTerrain, draw: tuple, morphed) -> Callable:
    """A drawer ``(viewpoint, projection, target, cull=None) -> DrawStats`` that draws the
    recorded selection ``draw`` (node keys) with its ``morphed`` nodes again (``cull`` is
    ignored: the selection was culled when it was made)."""

    def again(vp, projection, target, cull=None):
        from lodsprite.gl.terrain import draw_stats

        adaptive.redraw(vp, draw, morphed, projection, target)
        return draw_stats(0, len(draw), projection)

    return again


class _AdaptiveKeys:
    """The hooks both engines share: the whole keyframe drawn adaptively, streaming in
    spriteframes, the metric on the drawn surface, the adaptive proxy."""

    def __init__(self, engine: SpriteEngine, adaptive: AdaptiveTerrain,
                 pump: Callable[[], None]) -> None:
        self.engine = engine
        self.adaptive = adaptive
        self.pump = pump
        self.proxy = None  # an AdaptiveProxySource once use_proxy is called
        self.engine.sprite.sprite.keyframe_drawer = self.draw_keyframe
        self.engine.sprite.engine.between_keyframes = self.between_keyframes

    def draw_keyframe(self, viewpoint: Viewpoint, projection, target):
        """The keyframe hook: collect the level-0 chunks arrived, then draw adaptively."""
        self.pump()
        return self.adaptive.render_into(viewpoint, projection, target)

    def between_keyframes(self) -> int:
        """Each spriteframe: stream the adaptive renderer's tiles and collect the chunks
        arrived for the metric (neither waits)."""
        self.pump()
        return self.adaptive.prefetch()

    def use_surface(self, heights) -> None:
        """The metric's ``C`` from ``heights``, the surface the keyframes show
        (:class:`~lodsprite.techniques.drawn_surface.DrawnSurface`)."""
        policy = self.engine.sprite.engine.policy
        policy.metric = replace(policy.metric, surface=heights)

    def use_proxy(self, source, full, points) -> None:
        """Spriteframes, coarse z-buffers and the error metric on ``source``, the adaptive
        mesh frozen at each keyframe (:class:`~lodsprite.sprite.proxy_metric.ProxyMetric`
        over the ``full`` geometry, ``points`` the drawn surface's or None)."""
        from lodsprite.sprite.proxy_metric import ProxyMetric

        self.proxy = source
        self.engine.sprite.sprite.set_proxy(source)
        policy = self.engine.sprite.engine.policy
        policy.metric = ProxyMetric(source.nodes, full, policy.metric, points=points)

    def warmed_up(self) -> None:
        """Forget what the warm-up drew: the timed run's keyframes only."""
        if self.proxy is not None:
            self.proxy.triangles.clear()

    def tile_drawer(self, update: int, tile: int) -> Callable | None:
        """The drawer that re-renders ``tile`` as update ``update`` drew it (None: no
        tiles)."""
        return None


class WholeAdaptiveKeys(_AdaptiveKeys):
    """Whole keyframes drawn adaptively; each keyframe's selection (and frozen proxy) is
    recorded when it is first shown and drawn again to replay it.  Each keyframe carries
    what it lacks (:meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.
    deficit_px`, set on its ``C'`` as ``deficit_px``) in its error at every frame
    (:func:`~lodsprite.sprite.policy.keyframe_error_px`), so a keyframe drawn while the
    tiles its tolerance needs were streaming is due again until what it lacks is under
    ε."""

    def __init__(self, engine: SpriteEngine, adaptive: AdaptiveTerrain,
                 pump: Callable[[], None]) -> None:
        super().__init__(engine, adaptive, pump)
        self._selections: dict[int, tuple] = {}  # keyframe -> (nodes drawn, morphed)
        self._proxies: dict[int, tuple] = {}  # keyframe -> its frozen proxy selection
        self.deficit_px = 0.0  # what the newest keyframe lacks (pixels)

    def draw_keyframe(self, viewpoint: Viewpoint, projection, target):
        """The keyframe drawn adaptively; what it lacks set on its ``C'``."""
        stats = super().draw_keyframe(viewpoint, projection, target)
        self.deficit_px = self.adaptive.deficit_px()
        c_prime = self.engine.sprite.engine.policy.c_prime
        if c_prime is not None:
            c_prime.deficit_px = self.deficit_px
        return stats

    def record(self, decision: dict[str, Any]) -> None:
        """For a new keyframe, the selection it was drawn with (after the frame's clock
        stopped: nothing draws between the two)."""
        k = decision["keyframe"]
        if k not in self._selections:
            self._selections[k] = (tuple(self.adaptive.last_draw), self.adaptive.last_morphed)
            if self.proxy is not None:
                self._proxies[k] = self.proxy.last

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        """The frame again with its keyframe drawn from the recorded selection."""
        s = self.engine.sprite.sprite
        s.keyframe_drawer = redraw(self.adaptive, *self._selections[decision["keyframe"]])
        if self.proxy is not None:
            self.proxy.force(self._proxies[decision["keyframe"]])
        try:
            return self.engine.replay(viewpoint, decision, self.tile_drawer)
        finally:
            s.keyframe_drawer = self.draw_keyframe
            if self.proxy is not None:
                self.proxy.force(None)


class TiledAdaptiveKeys(_AdaptiveKeys):
    """Tiles drawn adaptively, each culled by its sub-frustum; each frame's tile
    selections are recorded per (update, tile) and drawn again to replay it.  Every
    tile's error is measured on the surface (or proxy) it shows."""

    def __init__(self, engine: TiledKeyframes, adaptive: AdaptiveTerrain,
                 pump: Callable[[], None]) -> None:
        super().__init__(engine, adaptive, pump)
        self.tiled = engine.tiled
        self._drawn: list[tuple] = []  # this frame's tile selections, in draw order
        self._selections: dict[tuple[int, int], tuple] = {}  # (update, tile) -> selection
        self.tiled.drawer = self.draw_tile
        self.tiled.between_keyframes = self.between_keyframes
        self.tiled.after_tiles = self.tiles_done

    def draw_tile(self, viewpoint: Viewpoint, projection, target, cull):
        """A tile by the adaptive renderer, culled by its sub-frustum; its selection is
        kept (references only: recorded in :meth:`record`)."""
        self.pump()
        if self.adaptive.gathering is None:  # the update's first tile
            self.adaptive.gathering = ([], set())
        stats = self.adaptive.render_into(viewpoint, projection, target, cull)
        self._drawn.append((self.adaptive.last_draw, self.adaptive.last_morphed))
        return stats

    def tiles_done(self, viewpoint: Viewpoint, projection) -> None:
        """After an update's tiles: their selections' requests stay the wish list
        (gathered tile by tile; no selection for the whole view is made)."""
        self.adaptive.gathering = None

    def use_surface(self, heights) -> None:
        """Each tile update's ``C`` on the surface it shows as well."""
        super().use_surface(heights)
        self.tiled.metric = replace(self.tiled.metric, surface=heights)

    def use_proxy(self, source, full, points) -> None:
        """The proxy frozen at a tile update and kept by the next ones until stale
        (:class:`~lodsprite.sprite.proxy_hold.ProxyHold`), and every tile's error the proxy
        metric over the samples it serves."""
        from lodsprite.sprite.proxy_hold import ProxyHold
        from lodsprite.sprite.proxy_metric import ProxyMetric

        super().use_proxy(source, full, points)
        self.tiled.tiled.use_proxy()
        self.tiled.hold = ProxyHold(source, self.tiled.metric)
        self.tiled.metric = ProxyMetric(self.tiled.hold.nodes, full, self.tiled.metric,
                                        points=points)

    def warmed_up(self) -> None:
        """Forget the warm-up's tiles too: they are no update's."""
        super().warmed_up()
        self._drawn.clear()

    def record(self, decision: dict[str, Any]) -> None:
        """The selections of the tiles this frame drew, under its update."""
        for t, (draw, morphed) in zip(decision["tiles"], self._drawn, strict=True):
            self._selections[(decision["keyframe"], t)] = (tuple(draw), morphed)
        self._drawn.clear()

    def tile_drawer(self, update: int, tile: int) -> Callable:
        """Re-renders ``tile`` with the selection update ``update`` drew it with."""
        return redraw(self.adaptive, *self._selections[(update, tile)])

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        """The frame's mosaic brought back, each tile drawn from its recorded selection."""
        return self.engine.replay(viewpoint, decision, self.tile_drawer)


class WorkerAdaptiveKeys:
    """Whole keyframes drawn by the worker process's adaptive renderer; the drawing
    side's ``adaptive`` draws none in the timed run.  Its untimed replay draws each
    keyframe from the selection the worker drew it with
    (:attr:`~lodsprite.sprite.worker_engine.WorkerLodSpriteEngine.selections`), its
    tiles read then: the image the worker drew, not what the replay's resident set would
    give."""

    def __init__(self, engine: WorkerKeyframes, adaptive: AdaptiveTerrain) -> None:
        self.engine = engine
        self.adaptive = adaptive

    def record(self, decision: dict[str, Any]) -> None:
        """Nothing: each keyframe's selection came with it."""

    def warmed_up(self) -> None:
        """Nothing: the warm-up drew no keyframe here."""

    def tile_drawer(self, update: int, tile: int) -> Callable | None:
        return None

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        """The frame again, its keyframe drawn from the worker's selection."""
        s = self.engine.sprite.sprite
        s.keyframe_drawer = redraw(self.adaptive,
                                   *self.engine.sprite.engine.selections[decision["keyframe"]])
        try:
            return self.engine.replay(viewpoint, decision, self.tile_drawer)
        finally:
            s.keyframe_drawer = None


class WorkerTiledAdaptiveKeys(WorkerAdaptiveKeys):
    """Tiles drawn by the worker process's adaptive renderer; the untimed replay draws
    each tile from the selection the worker drew it with
    (:attr:`~lodsprite.sprite.worker_tiles.WorkerTiledEngine.selections`)."""

    def tile_drawer(self, update: int, tile: int) -> Callable:
        return redraw(self.adaptive, *self.engine.tiled.selections[(update, tile)])

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        """The frame's mosaic brought back, each tile drawn from the worker's selection."""
        return self.engine.replay(viewpoint, decision, self.tile_drawer)


AdaptiveKeys = (WholeAdaptiveKeys | TiledAdaptiveKeys | WorkerAdaptiveKeys
                | WorkerTiledAdaptiveKeys)


def adaptive_keys(engine: SpriteEngine, adaptive: AdaptiveTerrain,
                  pump: Callable[[], None]) -> AdaptiveKeys:
    """The adaptive keyframes for LOD-sprite's ``engine``, chosen once:
    :class:`TiledAdaptiveKeys` for tile updates, :class:`WorkerAdaptiveKeys` and
    :class:`WorkerTiledAdaptiveKeys` for the worker's keyframes and tiles, else
    :class:`WholeAdaptiveKeys`."""
    if isinstance(engine, WorkerKeyframes):
        return WorkerAdaptiveKeys(engine, adaptive)
    if isinstance(engine, WorkerTiledKeyframes):
        return WorkerTiledAdaptiveKeys(engine, adaptive)
    if isinstance(engine, TiledKeyframes):
        return TiledAdaptiveKeys(engine, adaptive, pump)
    return WholeAdaptiveKeys(engine, adaptive, pump)
