"""The LOD-sprite options a terrain gets when the user gives none (issue 22, must-have 7).

``render --mode sprite`` and ``view`` on a terrain store use, by default, the LOD-sprite
variant ``lodsprite reproduce large`` finds best at equal error against the adaptive
renderer; an in-memory terrain keeps the 1999 algorithm's options (whole keyframes of the
in-memory grid, Chen, Swan & Kaufman 1999).  This module is the one place those defaults
live: :data:`STORE_DEFAULTS` and :data:`MEMORY_DEFAULTS`, option name -> value, for the
options :data:`DEFAULTED`.  :class:`~lodsprite.run.RenderConfig` and
:class:`~lodsprite.viewer.app.ViewOptions` leave an option ``None`` when it was not given
and fill it from here (:func:`fill_defaults`); a value given is kept.

How the reproduction sets them: ``results.json``'s ``equal_error_speedup`` names, per
store side and path, the variant (``whole``, ``tiled``, ``tiled+cache``) and ε with the
best speedup over adaptive at 1 px at RMSE and FLIP at most adaptive's; the options of
the variant that wins at 4k² and 16k² on both paths go into :data:`STORE_DEFAULTS` by
hand, with the run's date beside them (never read from a results file at run time).
Until that finding is in: adaptive keyframes at 0.5 px (``key_sse``), whole keyframes,
no cache, the uniform 16² proxy and the 1999 metric.
"""

from __future__ import annotations

from typing import Any

from lodsprite.sprite.tiled_engine import DEFAULT_TILE_BUDGET_MS
from lodsprite.terrain.lod import DEFAULT_COARSE

#: The options whose default depends on the terrain (``None`` in a config: not given).
DEFAULTED = ("lod", "key_sse", "proxy_sse", "tiles", "tile_budget_ms", "cache_mb", "metric")

#: LOD-sprite on a terrain store.  ``key_sse``: keyframes drawn by the adaptive renderer
#: from the store at this tolerance, pixels (on a store, sprite mode means adaptive
#: keyframes; whole keyframes of the in-memory grid would draw a resampled copy).
#: Set from ``reproduce large`` (module docstring); not yet measured: key_sse 0.5 only.
STORE_DEFAULTS: dict[str, Any] = {
    "lod": DEFAULT_COARSE, "key_sse": 0.5, "proxy_sse": None, "tiles": 1,
    "tile_budget_ms": DEFAULT_TILE_BUDGET_MS, "cache_mb": 0.0, "metric": "warp",
}

#: LOD-sprite on an in-memory terrain (a DEM file, ``fractal:N``, ``jacksboro``): the
#: 1999 algorithm, keyframes of the full-resolution grid (``key_sse`` None).
MEMORY_DEFAULTS: dict[str, Any] = {
    "lod": DEFAULT_COARSE, "key_sse": None, "proxy_sse": None, "tiles": 1,
    "tile_budget_ms": DEFAULT_TILE_BUDGET_MS, "cache_mb": 0.0, "metric": "warp",
}


def terrain_defaults(terrain: str, store: bool | None = None) -> dict[str, Any]:
    """The defaults of :data:`DEFAULTED` for the terrain spec ``terrain``
    (``store``: whether it names a terrain store; None: look)."""
    if store is None:
        from lodsprite.terrain.store import is_store

        store = bool(terrain) and is_store(terrain)
    return dict(STORE_DEFAULTS if store else MEMORY_DEFAULTS)


def fill_defaults(terrain: str, options: dict[str, Any],
                  store: bool | None = None) -> dict[str, Any]:
    """``options`` (name -> value, ``None``: not given) with every :data:`DEFAULTED`
    option not given set to ``terrain``'s default; options given are kept."""
    defaults = terrain_defaults(terrain, store)
    return {**options, **{k: defaults[k] for k in DEFAULTED
                          if k in options and options[k] is None}}


__all__ = ["DEFAULTED", "MEMORY_DEFAULTS", "STORE_DEFAULTS", "fill_defaults",
           "terrain_defaults"]
