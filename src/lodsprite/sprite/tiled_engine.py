"""The tiled LOD-sprite frame loop (Qu, Wan, Qin & Kaufman 2000; Chen, Swan & Kaufman 1999
Eq. 1-2 per tile): the GL driver of :mod:`lodsprite.sprite.tiled`.

Each frame: the error of every tile at the current view (:func:`~lodsprite.sprite.tiled.
tile_errors`), the tiles to re-render chosen by benefit/cost within ``tile_budget_ms``
(:func:`~lodsprite.sprite.tiled.select_tiles`), each re-rendered at the current viewpoint
through the key projection there (scissored, culled by its sub-frustum), then the tiled
spriteframe.  A frame that re-rendered every tile is a keyframe (shown as it is, its
centre); one that re-rendered some is of kind ``tiles``; the others are spriteframes.
With a view-dependent proxy (:attr:`TiledSpriteEngine.hold`) a tile update keeps the
proxy frozen at an earlier one until it is stale (:mod:`lodsprite.sprite.proxy_hold`:
the rule), and records the update it was frozen for (:attr:`~TiledSpriteEngine.
frozen_for`), which the replay freezes again.

Each tile's cost is its last measured time (ms, GL finished after it; the first frame
renders every tile and measures each).  The frame's time covers the errors, the
selection, the tiles, ``C'`` of the new viewpoint and the spriteframe, up to
``ctx.finish()``; it returns a :class:`~lodsprite.record.Frame` as
:class:`~lodsprite.sprite.engine.LodSpriteEngine` does.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.sprite_tiles import TileDrawer, TiledSpriteDrawer, TileSlots
from lodsprite.record import Frame
from lodsprite.sprite.cache import SWITCH_FRACTION, TileCache, far_error_px
from lodsprite.sprite.engine import sprite_frame
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import KEYFRAME, SPRITE, KeyChoice, resampling_metric
from lodsprite.sprite.tiled import (
    TILES,
    combined_error,
    ndc_rects,
    render_error,
    reproject_in_key_view,
    select_tiles,
    sub_view_proj,
    tile_errors,
    tile_rects,
    tiles_frustum,
)

DEFAULT_TILE_BUDGET_MS = 8.0


class TiledSpriteEngine:
    """LOD-sprite with keyframes refreshed tile by tile: ``tiles x tiles`` tiles, error
    threshold ``epsilon_px``, ``tile_budget_ms`` of tile work per frame.

    :attr:`updates` lists every viewpoint tiles were rendered from (a
    :class:`~lodsprite.sprite.policy.KeyChoice`); :attr:`mosaic` gives, per tile, the
    index in it of the update the tile shows now; :attr:`last_tiles` the tiles the last
    frame re-rendered.  :attr:`drawer` draws a tile's terrain (None: full resolution).
    ``metric``: ``"warp"`` (Eq. 1-2) or ``"resample"`` (the resampling term added per tile,
    through each tile's key view: :func:`~lodsprite.sprite.tiled.tile_errors`).

    ``cache_mb > 0``: a cache of tile renders within that many MB of GPU memory, replaced
    by ``cache_policy`` (:class:`lodsprite.sprite.cache.TileCache`): each frame a tile at or over
    half ε shows its cached render with the lowest error (the far term of
    :func:`~lodsprite.sprite.cache.far_error_px` included), and only tiles still over ε are
    re-rendered; :attr:`cache_tiles` counts, per frame, the tiles shown from a render other
    than their newest."""

    def __init__(self, sprite: SpriteDrawer, epsilon_px: float, tiles: int,
                 tile_budget_ms: float = DEFAULT_TILE_BUDGET_MS, metric: str = "warp",
                 cache_mb: float = 0.0, cache_policy: str = "lru") -> None:
        if not epsilon_px > 0:
            raise InputError(f"error threshold epsilon must be > 0 pixels, got {epsilon_px}")
        if not tile_budget_ms >= 0:
            raise InputError(f"--tile-budget-ms must be >= 0, got {tile_budget_ms}")
        self.sprite = sprite
        rects = tile_rects(tiles, sprite.key_size)
        self.tiled = TiledSpriteDrawer(sprite, rects, ndc_rects(rects,
                                                                  sprite.key_size))
        self.tiles = tiles
        self.epsilon_px = float(epsilon_px)
        self.tile_budget_ms = float(tile_budget_ms)
        self.metric = ErrorMetric.for_level(sprite.terrain.geometry.full, sprite.coarse_quads,
                                            resampling_metric(metric))
        count = self.tiled.count
        self.c_primes: list = [None] * count
        self.costs_ms = np.zeros(count)
        self.updates: list[KeyChoice] = []
        self.mosaic = np.full(count, -1, np.intp)
        self.last_tiles: tuple[int, ...] = ()
        self.drawer: TileDrawer | None = None
        self.between_keyframes = None  # called in frames that render no tile, timed
        # Called after a frame's tiles, timed: (viewpoint, key projection) -> None (the
        # adaptive renderer streams for the whole key view there).
        self.after_tiles = None
        self._shows_keyframe = False
        self.cache: TileCache | None = None
        self.slots: TileSlots | None = None
        self.newest = np.full(count, -1, np.intp)  # per tile, the update last rendered
        self.cache_tiles = 0  # the last frame's tiles shown from a render not their newest
        self.proxy_selections: list = []  # per update, a view-dependent proxy's selection
        # A view-dependent proxy kept between tile updates until stale (a ProxyHold of
        # lodsprite.sprite.proxy_hold; None: frozen again at every update)
        self.hold = None
        self.frozen_for: list[int] = []  # per update, the update whose key froze its proxy
        self._now = 0
        if not cache_mb >= 0:
            raise InputError(f"cache_mb must be >= 0 MB, got {cache_mb}")
        if cache_mb > 0:
            self.cache = TileCache(cache_mb * 2 ** 20,
                                   [TileSlots.tile_bytes(r) for r in rects], cache_policy)
            self.slots = TileSlots(sprite.ctx, self.tiled.target, self.tiled.coarse, rects)

    @property
    def keyframes(self) -> list[KeyChoice]:
        """The viewpoints tiles were rendered from (:attr:`updates`)."""
        return self.updates

    @property
    def shows_keyframe(self) -> bool:
        return self._shows_keyframe

    def errors(self, viewpoint: Viewpoint) -> tuple[np.ndarray, np.ndarray]:
        """``(errors (T,) px, served (T,))`` of the tiles at ``viewpoint``."""
        s = self.sprite
        projection = s.terrain.projection(viewpoint)
        view_proj = projection.matrix() @ viewpoint.view_matrix()
        key = s.key_projection(projection)
        return tile_errors(self.metric, self.c_primes, self.tiled.view_projs, self.tiled.ndc,
                           viewpoint.o, view_proj, key.matrix() @ viewpoint.view_matrix(),
                           projection.pixel_angle_rad(s.target.height), s.target.size)

    def render_tiles(self, chosen: Iterable[int], key: KeyChoice,
                     drawer: TileDrawer | None = None, measure: bool = True,
                     freeze: KeyChoice | None = None) -> int:
        """Render tiles ``chosen`` from ``key`` (finishing after each, to measure its cost
        when ``measure``); returns the triangles drawn.  ``freeze``: the key a
        view-dependent proxy is frozen for first (None: the one frozen is kept)."""
        key_proj = self.sprite.key_projection(key.projection)
        view_proj = key_proj.matrix() @ key.viewpoint.view_matrix()
        tris = 0
        ctx = self.sprite.terrain.ctx
        if freeze is not None:  # a view-dependent proxy, frozen for this update's key
            self.tiled.freeze(freeze.viewpoint, self.sprite.key_projection(freeze.projection))
        for i in chosen:
            t = time.perf_counter()
            stats = self.tiled.render_tile(int(i), key.viewpoint, key_proj,
                                           sub_view_proj(view_proj, self.tiled.ndc[i]),
                                           drawer or self.drawer)
            tris += stats.triangles
            if measure:
                ctx.finish()
                self.costs_ms[i] = (time.perf_counter() - t) * 1e3
        return tris

    def frame(self, viewpoint: Viewpoint) -> Frame:
        """Render the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        s = self.sprite
        projection = s.terrain.projection(viewpoint)
        errors, served = self.errors(viewpoint)
        rendered = np.array([c is not None for c in self.c_primes])
        self._now += 1
        if self.cache is not None and rendered.all() and self._use_cache(viewpoint, errors):
            errors, served = self.errors(viewpoint)
        decision = combined_error(errors, served) if rendered.any() else 0.0
        chosen = select_tiles(errors, self.epsilon_px, self.costs_ms, served,
                              self.tile_budget_ms, rendered)
        tris = 0
        if len(chosen):
            key = KeyChoice(viewpoint, projection, False)
            self.updates.append(key)
            key_proj = s.key_projection(projection)
            # C' first: a stale view-dependent proxy is selected for it, then frozen by the
            # tiles; a fresh one is kept (lodsprite.sprite.proxy_hold)
            key_vp = key_proj.matrix() @ viewpoint.view_matrix()
            why = self._refreeze(viewpoint, key_proj)
            c_prime = reproject_in_key_view(self.metric, viewpoint.o, key_vp, s.key_px,
                                            tiles_frustum(key_vp, self.tiled.ndc, chosen))
            tris += self.render_tiles(chosen, key, freeze=key if why else None)
            if why and self.hold is not None:
                self.hold.frozen(viewpoint.o, why)
            self.proxy_selections.append(getattr(s.proxy, "last", None))
            if self.after_tiles is not None:
                self.after_tiles(viewpoint, key_proj)
            for i in chosen:
                self.c_primes[i] = c_prime
                errors[i] = 0.0
            self.mosaic[chosen] = self.newest[chosen] = len(self.updates) - 1
            self._cache_new(chosen, viewpoint, key_proj, c_prime)
        elif self.between_keyframes is not None:
            self.between_keyframes()
        self.last_tiles = tuple(int(i) for i in chosen)
        self.cache_tiles = int(np.sum(self.mosaic != self.newest))
        whole = len(chosen) == self.tiled.count
        self._shows_keyframe = whole and s.keyframe_is_frame  # else drawn from the tiles
        if not self._shows_keyframe:
            tris += self.tiled.render_spriteframe(viewpoint, projection).triangles
        kind = KEYFRAME if whole else (TILES if len(chosen) else SPRITE)
        shown = 0.0 if whole else combined_error(errors, served)
        s.terrain.ctx.finish()
        return sprite_frame(kind, (time.perf_counter() - t0) * 1e3, tris, shown,
                            len(self.updates) - 1, decision)

    def _refreeze(self, viewpoint: Viewpoint, key_proj) -> str | None:
        """Why this update freezes the proxy again (None: the held one is kept, its
        nodes the metric's): every update without a :attr:`hold`, else when the held
        proxy is stale (:mod:`lodsprite.sprite.proxy_hold`); logs :attr:`frozen_for`."""
        why = "update" if self.hold is None else self.hold.stale(viewpoint, key_proj)
        if why or not self.frozen_for:
            self.frozen_for.append(len(self.updates) - 1)
        else:
            self.frozen_for.append(self.frozen_for[-1])
        if self.hold is not None:
            self.hold.held = why is None
        return why

    def _use_cache(self, viewpoint: Viewpoint, errors: np.ndarray) -> bool:
        """Each tile at or over ``SWITCH_FRACTION`` ε shows its cached render with the
        lowest error, the tile's and the far term over the render's samples
        (:func:`~lodsprite.sprite.cache.far_error_px`) in quadrature (copied into the
        mosaic when not the one shown); True if any changed."""
        s = self.sprite
        projection = s.terrain.projection(viewpoint)
        view_proj = projection.matrix() @ viewpoint.view_matrix()
        beta = projection.pixel_angle_rad(s.target.height)
        changed = False
        for i in range(self.tiled.count):
            if errors[i] < SWITCH_FRACTION * self.epsilon_px:
                self.cache.keep(i, self._now)
                continue
            shown = self.cache.caches[i].shown
            entry, _ = self.cache.best(i, viewpoint.o, lambda e, i=i: math.hypot(render_error(
                self.metric, e.c_prime, e.projection.matrix() @ e.viewpoint.view_matrix(),
                self.tiled.ndc[i], viewpoint.o, view_proj, beta, s.target.size),
                far_error_px(self.metric, e.c_prime, e.viewpoint.o, viewpoint.o, view_proj,
                             beta)), self._now)
            if entry is None or entry is shown:
                continue
            self.slots.load((i, entry.slot))
            self.tiled.set_tile(i, entry.viewpoint, entry.projection)
            self.c_primes[i] = entry.c_prime
            self.mosaic[i] = entry.index
            changed = True
        return changed

    def _cache_new(self, chosen: Iterable[int], viewpoint: Viewpoint, key_proj,
                   c_prime) -> None:
        """Keep the tiles just rendered in the cache: each copied into its slot."""
        if self.cache is None:
            return
        for i in chosen:
            entry = self.cache.insert(int(i), len(self.updates) - 1, viewpoint, key_proj,
                                      c_prime, self._now)
            self.slots.store((int(i), entry.slot))

    def read_image(self) -> np.ndarray:
        """The last frame's image, ``(H, W, 3) uint8``, row 0 at the top."""
        if self._shows_keyframe:
            return self.tiled.keyframe_color()
        return self.sprite.target.read_color()

    def replay(self, viewpoint: Viewpoint, mosaic: Sequence[int], shows_keyframe: bool,
               shown: np.ndarray,
               drawer_for: Callable[[int, int], TileDrawer | None] | None = None,
               latest: int | None = None) -> np.ndarray:
        """Untimed: bring every tile to the update ``mosaic[t]`` of :attr:`updates` (tiles
        whose ``shown[t]`` already is that update are kept; ``shown`` is updated) and
        return the frame's image.  ``drawer_for(update, tile)``: the drawer that renders
        the tile as that update did (None, or returning None: :attr:`drawer`).  With a
        view-dependent proxy, each update's recorded selection is frozen again for its
        tiles, and the spriteframe draws that of update ``latest`` (the frame's newest;
        default the mosaic's newest)."""
        force = getattr(self.sprite.proxy, "force", None)
        try:
            for t, u in enumerate(mosaic):
                if shown[t] != u:
                    drawer = None if drawer_for is None else drawer_for(int(u), t)
                    if force is not None:
                        force(self.proxy_selections[u])
                    self.render_tiles([t], self.updates[u], drawer, measure=False,
                                      freeze=self.updates[self.frozen_for[u]])
                    shown[t] = u
            if shows_keyframe:
                return self.tiled.keyframe_color()
            if force is not None:
                u = int(max(mosaic)) if latest is None else int(latest)
                force(self.proxy_selections[u])
                key = self.updates[self.frozen_for[u]]
                self.tiled.freeze(key.viewpoint, self.sprite.key_projection(key.projection))
            self.tiled.render_spriteframe(viewpoint)
            return self.sprite.target.read_color()
        finally:
            if force is not None:
                force(None)

    def release(self) -> None:
        if self.slots is not None:
            self.slots.release()
        self.tiled.release()
