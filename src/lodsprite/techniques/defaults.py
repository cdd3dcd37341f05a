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
Set from the default ``reproduce large`` of 2026-12-02 (4k² and 16k² fractal stores,
chen1999 and flyover, 120 frames at 256²; figures in ``docs/figures.md``): no variant was
3× faster at equal error; the fastest rows within adaptive's RMSE and FLIP were whole
keyframes on the view-dependent proxy with the resampling metric at 4k² (ε 0.5: 1.49×
on the flyover, 0.82× on chen1999) and at 16k² along chen1999 (ε 0.25, 0.42×), tiles only
on the 16k² flyover (ε 0.25, 0.81×).  So a store gets whole keyframes drawn by the
adaptive renderer at 0.5 px, spriteframes on the proxy at 8 px, the resampling metric, no
cache; ε stays the user's (1 px unless given).

Set on 2026-12-05 from ``benchmarks/sprite_frontier.py`` (4k² store, flyover and
chen1999, 120 frames at 256²; figures in ``docs/figures.md``): spriteframes on the
keyframe's own depth with keyframes at scale 2 (every 8th texel a vertex) stayed under
adaptive's RMSE at 0.5 px on the flyover at every ε (at least 4.7x adaptive's speed at
1 px by the median frame, 2.1x by the path's time), where the proxy geometry at scale 1
never reached adaptive's error; along chen1999 they
reached adaptive's error at 2.5x by the median and 1.05x by the path's time, the proxy
geometry at 4.4x and 0.99x.  So a store's spriteframes draw ``proxy`` depth at ``key_scale`` 2;
no pair (it changed RMSE by under 0.1 there, at 5-10 % more time).  In memory the 1999
algorithm stays.

Set on 2026-12-05 from ``reproduce timecritical`` (jacksboro, the banking path's first
5 s at 256², 60 fps, worker keyframes on the keyframe's own depth, paired; three runs
each): every 4th texel a vertex missed 25 % of the display's slots (RMSE over display
time 3.32), every 8th 2 % (2.58).  So ``--proxy depth`` in memory takes every 8th texel
too, as a store does.
"""

from __future__ import annotations

from typing import Any

from lodsprite.sprite.tiled_engine import DEFAULT_TILE_BUDGET_MS
from lodsprite.terrain.lod import DEFAULT_COARSE

#: The options whose default depends on the terrain (``None`` in a config: not given).
DEFAULTED = ("lod", "key_sse", "proxy_sse", "tiles", "tile_budget_ms", "cache_mb", "metric",
             "proxy", "depth_stride", "key_scale", "pair")

#: LOD-sprite on a terrain store.  ``key_sse``: keyframes drawn by the adaptive renderer
#: from the store at this tolerance, pixels (on a store, sprite mode means adaptive
#: keyframes; whole keyframes of the in-memory grid would draw a resampled copy).
#: Set from ``reproduce large`` (module docstring): the ``whole`` variant.
STORE_DEFAULTS: dict[str, Any] = {
    "lod": DEFAULT_COARSE, "key_sse": 0.5, "proxy_sse": 8.0, "tiles": 1,
    "tile_budget_ms": DEFAULT_TILE_BUDGET_MS, "cache_mb": 0.0, "metric": "resample",
    "proxy": "depth", "depth_stride": 8, "key_scale": 2.0, "pair": False,
}

#: LOD-sprite on an in-memory terrain (a DEM file, ``fractal:N``, ``jacksboro``): the
#: 1999 algorithm, keyframes of the full-resolution grid (``key_sse`` None).
MEMORY_DEFAULTS: dict[str, Any] = {
    "lod": DEFAULT_COARSE, "key_sse": None, "proxy_sse": None, "tiles": 1,
    "tile_budget_ms": DEFAULT_TILE_BUDGET_MS, "cache_mb": 0.0, "metric": "warp",
    "proxy": "geometry", "depth_stride": 8, "key_scale": 1.0, "pair": False,
}


def terrain_defaults(terrain: str, store: bool | None = None) -> dict[str, Any]:
    """The defaults of :data:`DEFAULTED` for the terrain spec ``terrain``
    (``store``: whether it names a terrain store; None: look)."""
    if store is None:
        from lodsprite.terrain.store import is_store

        store = bool(terrain) and is_store(terrain)
    return dict(STORE_DEFAULTS if store else MEMORY_DEFAULTS)


def fill_defaults(terrain: str, options: dict[str, Any],
                  store: bool | None = None, worker: bool = False) -> dict[str, Any]:
    """``options`` (name -> value, ``None``: not given) with every :data:`DEFAULTED`
    option not given set to ``terrain``'s default; options given are kept.  ``worker``
    (keyframes from the worker process): no ``proxy_sse`` default (the adaptive proxy is
    frozen at keyframes drawn inline)."""
    defaults = terrain_defaults(terrain, store)
    if worker:
        defaults["proxy_sse"] = None
    tiles = options.get("tiles")
    if (defaults["tiles"] if tiles is None else tiles) > 1:  # tile updates: scale 1, proxy
        defaults.update(proxy="geometry", key_scale=1.0)
    return {**options, **{k: defaults[k] for k in DEFAULTED
                          if k in options and options[k] is None}}


__all__ = ["DEFAULTED", "MEMORY_DEFAULTS", "STORE_DEFAULTS", "fill_defaults",
           "terrain_defaults"]
