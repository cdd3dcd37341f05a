"""The terrain techniques: ``full`` (full resolution), ``lod`` (one uniform coarse level),
``sprite`` (LOD-sprite, Chen, Swan & Kaufman 1999), ``adaptive`` (the CDLOD-style adaptive
renderer over a store or an in-memory pyramid) and ``sprite-adaptive`` (LOD-sprite with
keyframes drawn by the adaptive renderer).  Registered in :mod:`lodsprite.techniques.builtin`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX, FRAME_TYPES, KEYFRAME
from lodsprite.sprite.tiled import TILES
from lodsprite.sprite.tiled_engine import DEFAULT_TILE_BUDGET_MS
from lodsprite.techniques.base import FALLBACK_TINT, Frame, Param, Technique
from lodsprite.terrain.lod import DEFAULT_COARSE, level_step

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from lodsprite.api import LodSprite, Renderer
    from lodsprite.camera import Projection, Viewpoint


def resolve_shading(scene, shading: str = "auto") -> str:
    """``texture`` or ``heights`` for a ``shading`` choice (:data:`~lodsprite.gl.terrain.
    SHADINGS`): ``auto`` shades a terrain store from its heights (per-pixel normals, level-0
    detail) and keeps any other scene's texture."""
    from lodsprite.errors import InputError
    from lodsprite.gl.terrain import SHADINGS
    from lodsprite.terrain.store import is_store

    if shading not in SHADINGS:
        raise InputError(f"unknown shading '{shading}': use one of {', '.join(SHADINGS)}")
    if shading == "auto":
        return "heights" if scene.terrain_spec and is_store(scene.terrain_spec) else "texture"
    return shading


def set_shading(renderer: Renderer, shading: str) -> str:
    """Colour ``renderer``'s terrain frames (full, levels, keyframes, LOD-sprite's
    fallback) by ``shading`` resolved for its scene; returns the resolved one."""
    resolved = resolve_shading(renderer.scene, shading)
    renderer.paths.renderer.shading = resolved
    return resolved


class FullTechnique(Technique):
    """The full-resolution terrain: the ground truth."""

    name = "full"

    def __init__(self, renderer: Renderer, shading: str = "auto") -> None:
        super().__init__(renderer)
        self.shading = set_shading(renderer, shading)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, None)
        return Frame("full", (time.perf_counter() - t0) * 1e3, stats.triangles)

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"lod": self.renderer.scene.hf.quads, "shading": self.shading}


class LodTechnique(Technique):
    """One uniform coarse level ``lod`` (quads per side): fast, with geometric error."""

    name = "lod"

    def __init__(self, renderer: Renderer, lod: int = DEFAULT_COARSE,
                 shading: str = "auto") -> None:
        super().__init__(renderer)
        self.shading = set_shading(renderer, shading)
        self.quads = renderer.scene.hf.quads
        level_step(self.quads, lod)
        self.lod = lod

    def params(self) -> dict[str, Param]:
        return {"lod": Param("lod", self.lod, 2, self.quads, 2.0, "quads", integer=True)}

    def set_param(self, name: str, value: float) -> None:
        if name != "lod":
            super().set_param(name, value)
        level_step(self.quads, int(value))
        self.lod = int(value)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        t0 = time.perf_counter()
        stats = self.renderer.render(viewpoint, self.lod)
        return Frame("lod", (time.perf_counter() - t0) * 1e3, stats.triangles)

    def coarse_level(self) -> int | None:
        return self.lod

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"lod": self.lod, "shading": self.shading}


def level0_reader(geometry, lod: int, border: bool):
    """Over a store's level 0 (``geometry.full.heights`` a
    :class:`~lodsprite.terrain.storefield.LazyHeights`): the proxy and its ribbons read
    now, then the heights' reader process started, so that no frame reads the store
    (:mod:`lodsprite.terrain.storefield`); returns the heights (close them with the
    technique), or None for a field in memory."""
    heights = getattr(geometry.full, "heights", None)
    if not hasattr(heights, "start_reader"):
        return None
    geometry.proxy(lod, border)
    heights.start_reader()
    return heights


def coarse_baseline(terrain, viewpoint, lod: int, truth: np.ndarray) -> dict[str, float]:
    """A LOD-sprite run's baseline columns: the plain coarse level ``lod`` (quads a side)
    and the coarse level with LOD-sprite's border ribbons, drawn untimed by ``terrain`` (a
    :class:`~lodsprite.gl.terrain.TerrainRenderer`) at ``viewpoint`` and compared with
    the same reference ``truth (h, w, 3) uint8``: ``rmse_lod, psnr_lod, ssim_lod,
    rmse_lod_border``."""
    from lodsprite.metrics import psnr, rmse, ssim

    terrain.render(viewpoint, lod)
    plain = terrain.target.read_color()
    terrain.render_proxy(viewpoint, lod, border=True)
    ribbons = terrain.target.read_color()
    return {"rmse_lod": rmse(plain, truth), "psnr_lod": psnr(plain, truth),
            "ssim_lod": ssim(plain, truth), "rmse_lod_border": rmse(ribbons, truth)}


class SpriteTechnique(Technique):
    """LOD-sprite: keyframes on a worker thread (``threaded``) or inline (the 1999
    algorithm, what batch runs time).  Records per frame the keyframe shown; its replay
    renders that keyframe from its logged viewpoint and projection, then the frame.

    ``tiles > 1``: keyframes refreshed tile by tile within ``tile_budget_ms`` per frame
    (:class:`~lodsprite.sprite.tiled_engine.TiledSpriteEngine`, inline only); each frame
    records its mosaic (per tile, the viewpoint it was last rendered from), which the
    replay brings the tiles to."""

    name = "sprite"

    def __init__(self, renderer: Renderer, lod: int = DEFAULT_COARSE,
                 epsilon: float = DEFAULT_EPSILON_PX, threaded: bool = False,
                 visibility: str | None = None, guard_px: int | None = None,
                 border: bool = True, shading: str = "auto", tiles: int = 1,
                 tile_budget_ms: float = DEFAULT_TILE_BUDGET_MS, cache_mb: float = 0.0,
                 cache_policy: str = "lru", metric: str = "warp") -> None:
        super().__init__(renderer)
        from lodsprite.gl.sprite import DEFAULT_GUARD_PX, DEFAULT_VISIBILITY
        from lodsprite.sprite.tiled_engine import TiledSpriteEngine

        if not (isinstance(tiles, int) and tiles >= 1) or (tiles > 1 and threaded):
            raise InputError(f"--tiles must be a whole number >= 1 (inline keyframes only "
                             f"when > 1), got {tiles}")

        self.shading = set_shading(renderer, shading)

        level_step(renderer.scene.hf.quads, lod)
        self.threaded = threaded
        self.metric = metric
        self.sprite: LodSprite = renderer.sprite(
            epsilon, lod, threaded=threaded, visibility=visibility or DEFAULT_VISIBILITY,
            guard_px=DEFAULT_GUARD_PX if guard_px is None else guard_px, border=border,
            cache_mb=0.0 if tiles > 1 else cache_mb, cache_policy=cache_policy,
            metric=metric)  # with tiles, the tiled engine keeps the cache (of tile renders)
        self.cache_mb = float(cache_mb)
        self._tint = False
        self._replayed: int | None = None
        self._last = None
        self.tiled: TiledSpriteEngine | None = None
        if tiles > 1:
            try:
                self.tiled = TiledSpriteEngine(self.sprite.sprite, epsilon, tiles,
                                               tile_budget_ms, metric, cache_mb, cache_policy)
            except BaseException:
                self.sprite.release()
                raise
            self._shown = np.full(self.tiled.tiled.count, -1)  # replay: update per tile
        self.heights = level0_reader(renderer.paths.geometry, lod, border)

    @property
    def engine(self):
        return self.sprite.engine

    @property
    def keyframe_log(self) -> list | None:
        """With tiles: every viewpoint tiles were rendered from (the ``keyframe`` column
        indexes it: the latest update by the frame); None: the engine's keyframes."""
        return None if self.tiled is None else self.tiled.updates

    def params(self) -> dict[str, Param]:
        return {"epsilon": Param("epsilon", self.sprite.epsilon_px, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "epsilon":
            super().set_param(name, value)
        self.sprite.epsilon_px = value
        if self.tiled is not None:
            self.tiled.epsilon_px = float(value)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Shaders compiled on a keyframe and a spriteframe drawn outside the engine, so
        that the timed run starts with no keyframe, as the 1999 algorithm does; over a
        store, the level-0 chunks those asked of the reader arrived (the first view
        resident, as every technique's warm-up leaves it)."""
        if self.threaded:
            self.frame(viewpoint)
        else:
            self._warm_inline(viewpoint)
        if self.heights is not None and not self.heights.settle():
            log.warning("warm-up: the store's level-0 chunks of the first view did not all "
                        "arrive in time; the first timed frames may still read them")

    def _warm_inline(self, viewpoint: Viewpoint) -> None:
        s = self.sprite.sprite
        s.render_keyframe(viewpoint, 0.0)
        s.render_spriteframe(viewpoint)
        if self.tiled is not None:  # tiles drawn, untimed; the timed run starts with none
            from lodsprite.sprite.policy import KeyChoice

            key = KeyChoice(viewpoint, s.terrain.projection(viewpoint), False)
            self.tiled.render_tiles(range(self.tiled.tiled.count), key, measure=False)
            self.tiled.tiled.render_spriteframe(viewpoint)
        self.renderer.gl.finish()

    def frame(self, viewpoint: Viewpoint) -> Frame:
        if self.tiled is not None:
            f = self._last = self.tiled.frame(viewpoint)
            return Frame(f.type, f.ms, f.triangles, f.error_px,
                         {"keyframe": f.keyframe, "keyframes": len(self.tiled.updates),
                          "tiles": len(self.tiled.last_tiles),
                          "cache_tiles": self.tiled.cache_tiles})
        f = self.sprite.frame(viewpoint)
        self._last = f
        return Frame(f.type, f.ms, f.triangles, f.error_px,
                     {"keyframe": f.keyframe, "keyframes": len(self.sprite.keyframes)})

    def decision(self) -> dict[str, Any]:
        if self.tiled is not None:
            return {"keyframe": self._last.keyframe, "kind": self._last.type,
                    "shows_keyframe": self.tiled.shows_keyframe,
                    "mosaic": tuple(int(u) for u in self.tiled.mosaic),
                    "tiles": self.tiled.last_tiles}
        return {"keyframe": self._last.keyframe, "kind": self._last.type,
                "shows_keyframe": (not self.threaded) and self.engine.shows_keyframe}

    def tile_drawer(self, update: int, tile: int) -> Callable | None:
        """The drawer that re-renders ``tile`` as update ``update`` drew it (None: the
        full-resolution terrain)."""
        return None

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        if self.tiled is not None:
            return self.tiled.replay(viewpoint, decision["mosaic"],
                                     decision["shows_keyframe"], self._shown,
                                     self.tile_drawer, decision["keyframe"])
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

    def quality_extra(self, viewpoint: Viewpoint, decision: dict[str, Any],
                      truth: np.ndarray) -> dict[str, float]:
        """The plain coarse level and the coarse level with LOD-sprite's border ribbons
        against the same reference (:func:`coarse_baseline`)."""
        return coarse_baseline(self.renderer.paths.renderer, viewpoint, self.sprite.lod, truth)

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        """Keyframe count and fraction, mean time per frame kind (ms), mean error (px)."""
        out: dict[str, Any] = {"lod": self.sprite.lod, "epsilon": self.sprite.epsilon_px,
                               "visibility": self.sprite.sprite.visibility,
                               "shading": self.shading,
                               "metric": self.metric,
                               "keyframes": sum(f.kind == KEYFRAME for f in frames)}
        if self.tiled is None:
            out["tiles_rendered"] = out["keyframes"]  # a whole keyframe is 1 x 1 tile
        else:
            out["tiles"] = self.tiled.tiles
            out["tile_budget_ms"] = self.tiled.tile_budget_ms
            out["tiles_rendered"] = sum(int(f.extra.get("tiles", 0)) for f in frames)
            ms = [f.ms for f in frames if f.kind == TILES]
            out[f"mean_ms_{TILES}"] = float(np.mean(ms)) if ms else float("nan")
        for t in FRAME_TYPES:
            ms = [f.ms for f in frames if f.kind == t]
            out[f"mean_ms_{t}"] = float(np.mean(ms)) if ms else float("nan")
        out["keyframe_fraction"] = out["keyframes"] / max(1, len(frames))
        out["mean_error_px"] = float(np.mean([f.error_px for f in frames]))
        return {**out, **self.cache_summary(frames)}

    def cache_summary(self, frames: list[Frame]) -> dict[str, Any]:
        """``cache_hits`` (frames shown from a keyframe other than the newest rendered),
        ``cache_keyframes`` (most keyframes resident at once) and ``cache_mb``.  With tiles:
        ``cache_hits`` sums, over the frames, the tiles shown from a cached render other
        than their newest; ``cache_keyframes`` is the most tile renders resident at once."""
        if self.tiled is not None and self.tiled.cache is not None:
            return {"cache_hits": sum(int(f.extra.get("cache_tiles", 0)) for f in frames),
                    "cache_keyframes": self.tiled.cache.max_resident,
                    "cache_mb": self.cache_mb}
        cache = None if self.threaded or self.tiled is not None else self.engine.cache
        if cache is None:  # two alternating slots; the newest keyframe is always shown
            keys = sum(f.kind == KEYFRAME for f in frames)
            return {"cache_hits": 0, "cache_keyframes": min(2, keys), "cache_mb": 0.0}
        hits = sum(f.extra["keyframe"] != f.extra["keyframes"] - 1 for f in frames)
        return {"cache_hits": int(hits), "cache_keyframes": cache.max_resident,
                "cache_mb": self.cache_mb}

    def draw_to(self, framebuffer=None) -> None:
        if self.tiled is not None and self.tiled.shows_keyframe:
            s = self.sprite.sprite  # the tiled keyframe's centre, as LodSprite.draw_to
            tex, (w, h), g = self.tiled.tiled.target.color, self.tiled.tiled.target.size, \
                s.guard_px
            self.renderer.present(tex, (g / w, g / h, 1 - g / w, 1 - g / h), framebuffer)
            return
        self.sprite.draw_to(framebuffer)

    def read_image(self) -> np.ndarray:
        if self.tiled is not None:
            return self.tiled.read_image()
        return self.sprite.read_image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        if self.tiled is not None:  # the latest tile update's view
            if not self.tiled.updates:
                return None
            key = self.tiled.updates[-1]
            return key.viewpoint, self.sprite.sprite.key_projection(key.projection)
        return self.sprite.key_view()

    def coarse_level(self) -> int | None:
        return self.sprite.lod

    def set_fallback_tint(self, on: bool) -> None:
        self.sprite.sprite.fallback_tint = FALLBACK_TINT if on else (*FALLBACK_TINT[:3], 0.0)

    def status(self) -> str:
        if self.tiled is not None:
            cache = self.tiled.cache
            return (f"keyframes: {self.tiled.tiles}x{self.tiled.tiles} tiles, budget "
                    f"{self.tiled.tile_budget_ms:g} ms; last frame {len(self.tiled.last_tiles)}"
                    + ("" if cache is None else f"; cache {cache.resident} tile renders"))
        if not self.threaded:
            cache = self.engine.cache
            return "keyframes: inline" + ("" if cache is None else (
                f"; cache {len(cache.entries)}/{cache.capacity} ({cache.policy}, "
                f"{cache.evicted} evicted)"))
        engine = self.engine
        w = engine.worker
        state = f"failed: {w.error}" if w.error is not None else (
            "rendering" if w.busy else "idle")
        return (f"keyframes: worker thread, {state}; {w.rendered} rendered, "
                f"{engine.discarded} discarded, lead {w.lead_s * 1e3:.0f} ms")

    def release(self) -> None:
        if self.tiled is not None:
            self.tiled.release()
        self.sprite.release()
        if self.heights is not None:
            self.heights.close()
            self.heights = None
