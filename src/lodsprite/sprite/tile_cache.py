"""A cache of tile renders for tiled keyframes (Chen, Swan & Kaufman 1999, §5's cache of
keyframes, kept per screen tile of Qu, Wan, Qin & Kaufman 2000's tiled image), GL-free.

Each screen tile ``t`` keeps up to ``K_t`` past renders in a
:class:`~lodsprite.sprite.cache.KeyframeCache` of its own (viewpoint, key projection,
``C'`` carrying the key view-projection, GPU slot), ``K_t`` what ``budget / T`` bytes hold
at the tile's slot size (:meth:`lodsprite.gl.sprite_tiles.TileSlots.tile_bytes`); the
replacement policies are that cache's (``lru``, ``benefit``), never evicting the render a
tile shows.  So the cache's GPU bytes stay within the budget.

**Design** (the simpler one the issue allows, instead of an atlas the spriteframe shader
samples): the mosaic, the one keyframe target the tiled spriteframe samples, holds the
render each tile shows; every render is also copied into its slot, and a tile that
switches to a cached render gets it copied back into its rectangle (GPU-side copies,
:class:`~lodsprite.gl.sprite_tiles.TileSlots`).  The spriteframe shader is unchanged.

**Choice per tile** (:meth:`TileCache.best`), each frame before the tiles to re-render are
selected: a tile whose error is at least :data:`~lodsprite.sprite.cache.SWITCH_FRACTION` ε
evaluates its cached renders (the :data:`~lodsprite.sprite.cache.MAX_CANDIDATES` nearest
eyes, the shown one first) with :func:`~lodsprite.sprite.tiled.render_error` and shows
the lowest; a tile still at or over ε after that is a candidate for re-rendering as
without a cache (:func:`~lodsprite.sprite.tiled.select_tiles`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.sprite.cache import CachedKeyframe as CachedRender
from lodsprite.sprite.cache import KeyframeCache


class TileCache:
    """Per tile, a :class:`KeyframeCache` of its renders within ``budget_bytes / T``
    bytes, ``tile_bytes[t]`` each (at least two per tile: the shown one and a new one;
    :class:`~lodsprite.errors.InputError` otherwise), replaced by ``policy``."""

    def __init__(self, budget_bytes: float, tile_bytes: Sequence[int], policy: str) -> None:
        t = len(tile_bytes)
        self.budget_bytes = float(budget_bytes)
        self.caches = [KeyframeCache(budget_bytes / t, int(b), policy) for b in tile_bytes]
        self.max_resident = 0

    @property
    def resident_bytes(self) -> int:
        """GPU bytes the cached renders hold, all tiles."""
        return sum(c.resident_bytes for c in self.caches)

    @property
    def resident(self) -> int:
        return sum(len(c.entries) for c in self.caches)

    def insert(self, tile: int, update: int, viewpoint: Viewpoint, key_projection: Projection,
               c_prime: np.ndarray, now: int) -> CachedRender:
        """Keep tile ``tile``'s new render (update ``update`` of the engine, seen through
        ``key_projection``, the widened one), shown from now; returns its entry (its
        ``slot`` is where the GPU copy goes)."""
        entry = self.caches[tile].insert(update, viewpoint, key_projection, c_prime, now)
        self.max_resident = max(self.max_resident, self.resident)
        return entry

    def best(self, tile: int, eye: np.ndarray, error_of: Callable[[CachedRender], float],
             now: int) -> tuple[CachedRender | None, float]:
        """``(entry, error px)``: the render of ``tile`` with the lowest ``error_of`` among
        the candidates at ``eye`` (the shown one first, kept on ties), marked shown in
        frame ``now``; ``(None, inf)`` when the tile has none."""
        cache = self.caches[tile]
        cands = cache.candidates(np.asarray(eye, np.float64))
        if not cands:
            return None, float("inf")
        errs = [error_of(e) for e in cands]
        k = int(np.argmin(errs))
        cache.use(cands[k], now)
        return cands[k], float(errs[k])

    def keep(self, tile: int, now: int) -> None:
        """The tile's shown render is shown in frame ``now`` too (recency and uses)."""
        cache = self.caches[tile]
        if cache.shown is not None:
            cache.use(cache.shown, now)
