"""LOD-sprite's three engines behind the one ``sprite`` technique
(:class:`~lodsprite.techniques.terrain.SpriteTechnique`), chosen once when it is made:

* :class:`WholeKeyframes` — the 1999 algorithm inline: whole keyframes rendered in the
  frame that needs them (:class:`~lodsprite.sprite.engine.LodSpriteEngine`), optionally
  from a keyframe cache; what batch runs time;
* :class:`WorkerKeyframes` — whole keyframes rendered ahead by a worker process (the
  ``keyframes="worker"`` option), the drawing loop only draws spriteframes
  (:class:`~lodsprite.sprite.worker_engine.WorkerLodSpriteEngine`);
* :class:`TiledKeyframes` — the keyframe refreshed tile by tile within a per-frame budget
  (:class:`~lodsprite.sprite.tiled_engine.TiledSpriteEngine`), inline.

Each is a :class:`SpriteEngine`: it turns a viewpoint into a technique
:class:`~lodsprite.techniques.base.Frame`, says what the frame decided, replays a decision
untimed to the same image, and gives its own summary, cache and status lines.  The
decisions themselves stay in the GL-free cores (:mod:`lodsprite.sprite.policy`,
:mod:`lodsprite.sprite.tiled`); these classes only adapt the GL drivers to the
technique interface.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lodsprite.errors import InputError
from lodsprite.sprite.policy import KEYFRAME
from lodsprite.sprite.tiled import TILES
from lodsprite.techniques.base import Frame

if TYPE_CHECKING:
    from lodsprite.camera import Projection, Viewpoint
    from lodsprite.sprite.tiled_engine import TiledSpriteEngine
    from lodsprite.sprite.worker_settings import StoreKeys
    from lodsprite.techniques.base import RendererLike, SpriteLike

TileDrawerFor = Callable[[int, int], Callable | None]


class SpriteEngine(Protocol):
    """What :class:`~lodsprite.techniques.terrain.SpriteTechnique` delegates to.

    ``sprite``: the :class:`~lodsprite.api.LodSprite` whose sprite renderer draws the
    spriteframes (and whole keyframes); ``keyframes``: every view keyframes (or tiles)
    were rendered from, in order, which a frame's ``keyframe`` column indexes."""

    sprite: SpriteLike

    @property
    def keyframes(self) -> list: ...

    def set_epsilon(self, value: float) -> None: ...

    def warm_up(self, viewpoint: Viewpoint) -> None: ...

    def frame(self, viewpoint: Viewpoint) -> Frame: ...

    def decision(self) -> dict[str, Any]: ...

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any],
               drawer_for: TileDrawerFor) -> np.ndarray: ...

    def work_summary(self, frames: list[Frame]) -> dict[str, Any]: ...

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]: ...

    def draw_to(self, framebuffer=None) -> None: ...

    def read_image(self) -> np.ndarray: ...

    def key_view(self) -> tuple[Viewpoint, Projection] | None: ...

    def status(self) -> str: ...

    def release(self) -> None: ...


def slot_summary(frames: list[Frame]) -> dict[str, Any]:
    """Without a cache: two alternating keyframe slots, the newest keyframe always shown
    (``cache_hits`` 0, at most 2 resident, ``cache_mb`` 0)."""
    keys = sum(f.kind == KEYFRAME for f in frames)
    return {"cache_hits": 0, "cache_keyframes": min(2, keys), "cache_mb": 0.0}


class _Whole:
    """Whole keyframes on ``sprite`` (inline or from the worker): the frame, its decision and
    its untimed replay (the logged keyframe rendered again, then the spriteframe)."""

    def __init__(self, sprite: SpriteLike) -> None:
        self.sprite = sprite
        self._last = None
        self._replayed: int | None = None

    @property
    def keyframes(self) -> list:
        return self.sprite.keyframes

    def set_epsilon(self, value: float) -> None:
        self.sprite.epsilon_px = value

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self._last = self.sprite.frame(viewpoint)
        return Frame(f.type, f.ms, f.triangles, f.error_px,
                     {"keyframe": f.keyframe, "keyframes": len(self.sprite.keyframes)})

    def read_image(self) -> np.ndarray:
        return self.sprite.read_image()

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any],
               drawer_for: TileDrawerFor) -> np.ndarray:
        s = self.sprite.sprite
        k = decision["keyframe"]
        if k != self._replayed:
            key = self.sprite.keyframes[k]
            s.render_keyframe(key.viewpoint, 0.0, key.projection)
            self._replayed = k
        if decision["shows_keyframe"]:
            return s.keyframe_color()
        s.render_spriteframe(viewpoint)
        return s.target.read_color()

    def work_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """A whole keyframe is 1 x 1 tile: ``tiles_rendered`` counts the keyframes."""
        return {"tiles_rendered": sum(f.kind == KEYFRAME for f in frames)}

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        """The shown keyframe's viewpoint and (guard-band widened) projection."""
        return self.sprite.key_view()

    def draw_to(self, framebuffer=None) -> None:
        """The keyframe's centre or the spriteframe (:meth:`LodSprite.draw_to
        <lodsprite.api.LodSprite.draw_to>`)."""
        self.sprite.draw_to(framebuffer)

    def release(self) -> None:
        self.sprite.release()


class WholeKeyframes(_Whole):
    """The 1999 algorithm inline: a keyframe rendered in the frame whose error reached ε
    (:class:`~lodsprite.sprite.engine.LodSpriteEngine`); with ``cache_mb > 0`` a frame
    may show an older keyframe from the cache."""

    def __init__(self, sprite: SpriteLike, renderer: RendererLike, cache_mb: float) -> None:
        super().__init__(sprite)
        self.renderer = renderer
        self.cache_mb = float(cache_mb)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """A keyframe and a spriteframe drawn outside the engine (shaders compiled), so
        that the timed run starts with no keyframe, as the 1999 algorithm does."""
        s = self.sprite.sprite
        s.render_keyframe(viewpoint, 0.0)
        s.render_spriteframe(viewpoint)
        self.renderer.gl.finish()

    def decision(self) -> dict[str, Any]:
        return {"keyframe": self._last.keyframe, "kind": self._last.type,
                "shows_keyframe": self.sprite.engine.shows_keyframe}

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """``cache_hits`` (frames shown from a keyframe other than the newest rendered),
        ``cache_keyframes`` (most keyframes resident at once) and ``cache_mb``."""
        cache = self.sprite.engine.cache
        if cache is None:
            return slot_summary(frames)
        hits = sum(f.extra["keyframe"] != f.extra["keyframes"] - 1 for f in frames)
        return {"cache_hits": int(hits), "cache_keyframes": cache.max_resident,
                "cache_mb": self.cache_mb}

    def status(self) -> str:
        cache = self.sprite.engine.cache
        return "keyframes: inline" + ("" if cache is None else (
            f"; cache {len(cache.entries)}/{cache.capacity} ({cache.policy}, "
            f"{cache.evicted} evicted)"))


class WorkerKeyframes(_Whole):
    """Whole keyframes from a worker process with its own context; every frame is a
    spriteframe and never waits for a keyframe after the first
    (:class:`~lodsprite.sprite.worker_engine.WorkerLodSpriteEngine`)."""

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """One frame drawn: the first keyframe is waited for there (the worker's
        context and shaders ready), so the timed run starts with it."""
        self.frame(viewpoint)

    def decision(self) -> dict[str, Any]:
        return {"keyframe": self._last.keyframe, "kind": self._last.type,
                "shows_keyframe": False}

    def work_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """The keyframes, and what the guard band that follows the predictor did
        (:meth:`lodsprite.sprite.guard.GuardBand.summary`; none when it is fixed)."""
        guard = self.sprite.engine.worker.guard
        return {**super().work_summary(frames), **({} if guard is None else guard.summary())}

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """No frame here is a keyframe: ``keyframes`` counts the worker's keyframes the
        frames showed, ``keyframes_rendered`` all it rendered (``keyframes_discarded``:
        those never adopted)."""
        shown = len({f.keyframe for f in frames})
        engine = self.sprite.engine
        return {**slot_summary(frames), "cache_keyframes": min(2, shown),
                "keyframes": shown, "keyframes_rendered": engine.worker.rendered,
                "keyframes_discarded": engine.discarded}

    def status(self) -> str:
        engine = self.sprite.engine
        w = engine.worker
        state = f"failed: {w.error}" if w.error is not None else (
            "rendering" if w.busy else "idle")
        return (f"keyframes: worker process, {state}; {w.rendered} rendered, "
                f"{engine.discarded} discarded, lead {w.lead_s * 1e3:.0f} ms")


class TiledKeyframes:
    """The keyframe refreshed tile by tile, ``tiles x tiles`` tiles within
    ``tile_budget_ms`` of tile work per frame, inline
    (:class:`~lodsprite.sprite.tiled_engine.TiledSpriteEngine`, :attr:`tiled`); each
    frame's decision records its mosaic (per tile, the update it shows), which the replay
    brings the tiles to.  ``cache_mb > 0``: a cache of tile renders."""

    def __init__(self, sprite: SpriteLike, renderer: RendererLike, epsilon: float, tiles: int,
                 tile_budget_ms: float, metric: str, cache_mb: float,
                 cache_policy: str) -> None:
        from lodsprite.sprite.tiled_engine import TiledSpriteEngine

        self.sprite = sprite
        self.renderer = renderer
        self.cache_mb = float(cache_mb)
        self.tiled: TiledSpriteEngine = TiledSpriteEngine(
            sprite.sprite, epsilon, tiles, tile_budget_ms, metric, cache_mb, cache_policy)
        self._shown = np.full(self.tiled.tiled.count, -1)  # replay: the update per tile
        self._last = None

    @property
    def keyframes(self) -> list:
        """Every viewpoint tiles were rendered from (the ``keyframe`` column indexes it:
        the latest update by the frame)."""
        return self.tiled.updates

    def set_epsilon(self, value: float) -> None:
        self.sprite.epsilon_px = value
        self.tiled.epsilon_px = float(value)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """A whole keyframe, a spriteframe and every tile drawn, untimed: the timed run
        starts with no tile rendered."""
        from lodsprite.sprite.policy import KeyChoice

        s = self.sprite.sprite
        s.render_keyframe(viewpoint, 0.0)
        s.render_spriteframe(viewpoint)
        key = KeyChoice(viewpoint, s.terrain.projection(viewpoint), False)
        self.tiled.render_tiles(range(self.tiled.tiled.count), key, measure=False)
        self.tiled.tiled.render_spriteframe(viewpoint)
        self.renderer.gl.finish()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self._last = self.tiled.frame(viewpoint)
        return Frame(f.type, f.ms, f.triangles, f.error_px,
                     {"keyframe": f.keyframe, "keyframes": len(self.tiled.updates),
                      "tiles": len(self.tiled.last_tiles),
                      "cache_tiles": self.tiled.cache_tiles})

    def decision(self) -> dict[str, Any]:
        return {"keyframe": self._last.keyframe, "kind": self._last.type,
                "shows_keyframe": self.tiled.shows_keyframe,
                "mosaic": tuple(int(u) for u in self.tiled.mosaic),
                "tiles": self.tiled.last_tiles}

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any],
               drawer_for: TileDrawerFor) -> np.ndarray:
        return self.tiled.replay(viewpoint, decision["mosaic"], decision["shows_keyframe"],
                                 self._shown, drawer_for, decision["keyframe"])

    def work_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """The grid, the budget, the tiles rendered and the mean time of frames that
        rendered some tiles (ms)."""
        ms = [f.ms for f in frames if f.kind == TILES]
        return {"tiles": self.tiled.tiles, "tile_budget_ms": self.tiled.tile_budget_ms,
                "tiles_rendered": sum(int(f.extra.get("tiles", 0)) for f in frames),
                f"mean_ms_{TILES}": float(np.mean(ms)) if ms else float("nan")}

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """``cache_hits`` sums, over the frames, the tiles shown from a cached render other
        than their newest; ``cache_keyframes`` is the most tile renders resident at once."""
        if self.tiled.cache is None:
            return slot_summary(frames)
        return {"cache_hits": sum(int(f.extra.get("cache_tiles", 0)) for f in frames),
                "cache_keyframes": self.tiled.cache.max_resident, "cache_mb": self.cache_mb}

    def draw_to(self, framebuffer=None) -> None:
        """The tiled keyframe's centre, or the spriteframe (the renderer's image: the
        whole-keyframe engine beside it never drew a frame, so its own choice would show
        the warm-up's keyframe)."""
        if not self.tiled.shows_keyframe:
            self.renderer.draw_to(framebuffer)
            return
        target = self.tiled.tiled.target  # the tiled keyframe's centre, as LodSprite.draw_to
        (w, h), g = target.size, self.sprite.sprite.guard_px
        self.renderer.present(target.color, (g / w, g / h, 1 - g / w, 1 - g / h),
                              framebuffer)

    def read_image(self) -> np.ndarray:
        return self.tiled.read_image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        """The latest tile update's view."""
        if not self.tiled.updates:
            return None
        key = self.tiled.updates[-1]
        return key.viewpoint, self.sprite.sprite.key_projection(key.projection)

    def status(self) -> str:
        cache = self.tiled.cache
        return (f"keyframes: {self.tiled.tiles}x{self.tiled.tiles} tiles, budget "
                f"{self.tiled.tile_budget_ms:g} ms; last frame {len(self.tiled.last_tiles)}"
                + ("" if cache is None else f"; cache {cache.resident} tile renders"))

    def release(self) -> None:
        self.tiled.release()
        self.sprite.release()


class WorkerTiledKeyframes(TiledKeyframes):
    """Tiles rendered by a worker process with its own context
    (:class:`~lodsprite.sprite.worker_tiles.WorkerTiledEngine`, :attr:`tiled`); every
    frame is a tiled spriteframe and never waits for a tile after the first update."""

    def __init__(self, sprite: SpriteLike, renderer: RendererLike, epsilon: float, tiles: int,
                 metric: str, store: StoreKeys | None = None) -> None:
        from lodsprite.sprite.worker_tiles import WorkerTiledEngine

        self.sprite = sprite
        self.renderer = renderer
        self.cache_mb = 0.0
        self.tiled = WorkerTiledEngine(sprite.sprite, renderer.scene, renderer.fov_y_deg,
                                       epsilon, tiles, metric=metric, store=store)
        self._shown = np.full(self.tiled.tiled.count, -1)
        self._last = None

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """One frame drawn: the first update (every tile) is waited for there."""
        self.frame(viewpoint)

    def work_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """As inline tiles', with no ``tile_budget_ms`` (None): the worker's tiles cost
        the display no tile work, so ``--tile-budget-ms`` does not apply."""
        return {**super().work_summary(frames), "tile_budget_ms": None}

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """``keyframes`` counts the updates the frames showed, ``keyframes_rendered`` all
        the worker delivered; ``tiles_discarded`` the tiles delivered and not adopted."""
        shown = len({f.keyframe for f in frames})
        w = self.tiled.worker
        return {**slot_summary(frames), "keyframes": shown, "keyframes_rendered": w.rendered,
                "tiles_discarded": self.tiled.discarded}

    def status(self) -> str:
        w = self.tiled.worker
        state = f"failed: {w.error}" if w.error is not None else (
            "rendering" if w.busy else "idle")
        return (f"keyframes: {self.tiled.tiles}x{self.tiled.tiles} tiles from a worker "
                f"process, {state}; {w.rendered} updates, {self.tiled.discarded} tiles "
                f"discarded, lead {w.lead_s * 1e3:.0f} ms")


def sprite_engine(renderer: RendererLike, epsilon: float, lod: int, threaded: bool,
                  visibility: str, guard_px: int, border: bool, tiles: int,
                  tile_budget_ms: float, cache_mb: float, cache_policy: str,
                  metric: str, store=None, depth_stride: int | None = None,
                  key_scale: float = 1.0, pair: bool = False) -> SpriteEngine:
    """The engine the options ask for, chosen once: for ``tiles > 1``
    :class:`TiledKeyframes` (inline) or :class:`WorkerTiledKeyframes` (``threaded``),
    else :class:`WorkerKeyframes` or :class:`WholeKeyframes`
    (``store``: the worker's keyframes over a terrain store,
    :class:`~lodsprite.sprite.worker_settings.StoreKeys`).  Raises
    :class:`~lodsprite.errors.InputError` for a bad ``tiles``."""
    if not (isinstance(tiles, int) and tiles >= 1):
        raise InputError(f"--tiles must be a whole number >= 1, got {tiles}")
    if tiles > 1 and depth_stride is not None:
        raise InputError("tile updates draw on the proxy geometry: --proxy depth and "
                         "search need --tiles 1")
    if tiles > 1 and threaded and cache_mb > 0:
        raise InputError("tiles from the keyframe worker keep no cache (--cache-mb)")
    sprite = renderer.sprite(
        epsilon, lod, threaded=threaded and tiles == 1, visibility=visibility,
        guard_px=guard_px,
        border=border, cache_mb=0.0 if tiles > 1 else cache_mb, cache_policy=cache_policy,
        metric=metric, store=store if tiles == 1 else None,  # tiles: the tiled engine's
        depth_stride=depth_stride, key_scale=key_scale, pair=pair)
    if tiles == 1:
        return (WorkerKeyframes(sprite) if threaded
                else WholeKeyframes(sprite, renderer, cache_mb))
    try:
        if threaded:
            return WorkerTiledKeyframes(sprite, renderer, epsilon, tiles, metric, store)
        return TiledKeyframes(sprite, renderer, epsilon, tiles, tile_budget_ms, metric,
                              cache_mb, cache_policy)
    except BaseException:
        sprite.release()
        raise
