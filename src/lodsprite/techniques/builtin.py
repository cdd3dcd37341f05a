"""The terrain techniques lodsprite ships, as specs (each named by an entry point of the
group ``lodsprite.techniques`` in ``pyproject.toml``), and the options they declare,
each once.

A spec's factory imports its class when called, so reading these specs (the command
line's ``--help``) imports no GL.  Adding a technique: its class, its spec with one
:class:`~lodsprite.techniques.Option` line per option, and its entry point (or
:func:`~lodsprite.techniques.register` in your own code, ``examples/custom_technique.py``).
"""

from __future__ import annotations

from typing import Any

from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import TechniqueSpec

_TERRAIN = "the terrain's (lodsprite.techniques.defaults)"

LOD = Option("lod", int, None, "coarse level: N x N quads over the terrain (a power of two)",
             min=2, unit="quads", none=_TERRAIN)
EPSILON = Option("epsilon", float, 1.0, "LOD-sprite: error threshold ε", min=0, above=True,
                 unit="px")
VISIBILITY = Option("visibility", str, "coarse", "LOD-sprite: where the sprite is used",
                    choices=("coarse", "triangle", "fragment"))
GUARD = Option("guard_px", int, 32, "LOD-sprite: keyframe guard band on every side",
               min=0, max=1024, unit="px", flag="guard")
BORDER = Option("border", bool, True, "LOD-sprite: draw the terrain's full-resolution "
                "outline (border ribbons) with the coarse level")
CACHE_MB = Option("cache_mb", float, None, "LOD-sprite: keep keyframes in a GPU cache of "
                  "this size and show the one with the lowest error (0: off)", min=0,
                  unit="MB", none=_TERRAIN)
CACHE_POLICY = Option("cache_policy", str, "lru", "LOD-sprite: keyframe cache replacement",
                      choices=("lru", "benefit"))
METRIC = Option("metric", str, None, "LOD-sprite: the keyframe error metric: warp (Chen et "
                "al. Eq. 1-2), resample (adds the keyframe image's resampling error) or "
                "depth (Eq. 1-2 on the keyframe's own depth mesh, with resampling and the "
                "uncovered area; needs --proxy depth)",
                choices=("warp", "resample", "depth"), none=_TERRAIN)
KEYFRAMES = Option("keyframes", str, "inline", "LOD-sprite: where keyframes are rendered: "
                   "in the frame that needs them (inline, the 1999 algorithm) or by a worker "
                   "process beside the display (worker: render plays the path in time; the "
                   "window's default)",
                   choices=("inline", "worker"))
TILES = Option("tiles", int, None, "LOD-sprite: refresh keyframes tile by tile on an N x N "
               "grid of screen tiles (1: whole keyframes)", min=1, max=4, none=_TERRAIN)
TILE_BUDGET = Option("tile_budget_ms", float, None, "LOD-sprite with tiles > 1: tile work "
                     "per frame (a tile over 2 ε is rendered even beyond it)", min=0,
                     unit="ms", none=_TERRAIN)
SSE = Option("sse", float, 1.0, "adaptive: screen-space error tolerance", min=0,
             above=True, unit="px")
KEY_SSE = Option("key_sse", float, None, "LOD-sprite: keyframes by the adaptive renderer at "
                 "this tolerance", min=0, above=True, unit="px",
                 none="the terrain's: 0.5 on a store; in memory none for sprite, 0.5 "
                      "for sprite-adaptive")
PROXY_SSE = Option("proxy_sse", float, None, "LOD-sprite with adaptive keyframes: "
                   "spriteframes draw the adaptive mesh at this tolerance instead of the "
                   "uniform --lod level", min=0, above=True, unit="px", none=_TERRAIN)
GPU_MB = Option("gpu_mb", float, 256.0, "adaptive: GPU tile cache budget", min=0,
                above=True, unit="MB")
HOST_MB = Option("host_mb", float, 512.0, "adaptive: host tile cache budget", min=0,
                 above=True, unit="MB")
SHADING = Option("shading", str, "auto", "terrain colour: auto (a store's imagery, else "
                 "heights on a store, else the texture) | imagery | texture | heights",
                 choices=("auto", "imagery", "texture", "heights"))
GRID = Option("grid", int, 64, "adaptive: node grid, quads a side",
              choices=(16, 32, 64, 128), flag="node-grid")
PROXY = Option("proxy", str, None, "LOD-sprite: what spriteframes draw the keyframe "
               "on: its proxy geometry (the --lod level, or the adaptive mesh at "
               "--proxy-sse), a mesh from the keyframe's own depth (refined: split "
               "finer where it is not planar), or a search per pixel through it",
               choices=("geometry", "depth", "depth-refined", "search"), none=_TERRAIN)
DEPTH_STRIDE = Option("depth_stride", int, None, "LOD-sprite with --proxy depth: keyframe "
                      "texels between the depth mesh's vertices", min=1, max=16,
                      unit="texels", none=_TERRAIN)
KEY_SCALE = Option("key_scale", float, None, "LOD-sprite: keyframe texels a display pixel "
                   "side (2: four samples a pixel, four times the memory)",
                   choices=(1.0, 1.5, 2.0), none=_TERRAIN)
PAIR = Option("pair", bool, None, "LOD-sprite with --proxy depth: draw the keyframe shown "
              "before the current one too, where the current one drew nothing",
              none=_TERRAIN)
SPRITE_OPTIONS = (LOD, EPSILON, KEYFRAMES, VISIBILITY, GUARD, BORDER, SHADING, TILES,
                  TILE_BUDGET, CACHE_MB, CACHE_POLICY, METRIC, PROXY, DEPTH_STRIDE,
                  KEY_SCALE, PAIR)
SPRITE_SUMMARY = ("keyframes: {keyframes} of {frames}; mean ms keyframe "
                  "{mean_ms_keyframe:.1f}, first spriteframe {mean_ms_first_sprite:.1f}, "
                  "spriteframe {mean_ms_sprite:.1f}",)


def with_terrain_defaults(renderer: Any, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` with those left ``None`` that have a terrain default filled with the
    terrain's own (:mod:`lodsprite.techniques.defaults`: a store's, or the 1999
    algorithm's in memory), as ``render`` and ``view`` fill them
    (:meth:`lodsprite.run.RenderConfig.resolved`)."""
    from lodsprite.techniques.defaults import fill_defaults

    return fill_defaults(renderer.scene.terrain_spec, options,
                         worker=options.get("keyframes") == "worker")


def on_store(renderer: Any) -> bool:
    """Whether ``renderer``'s scene flies a terrain store."""
    from lodsprite.terrain.store import is_store

    spec = renderer.scene.terrain_spec
    return bool(spec) and is_store(spec)


def full(renderer: Any, **options: Any) -> Any:
    from lodsprite.techniques.terrain import FullTechnique

    return FullTechnique(renderer, **options)


def lod(renderer: Any, **options: Any) -> Any:
    from lodsprite.techniques.terrain import LodTechnique

    return LodTechnique(renderer, **with_terrain_defaults(renderer, options))


def sprite(renderer: Any, **options: Any) -> Any:
    """LOD-sprite; over a store with adaptive keyframes, as ``render --mode sprite`` draws
    a store (its working grid would be a resampled copy)."""
    from lodsprite.techniques.terrain import SpriteTechnique

    if on_store(renderer):  # every terrain default the store has, as render fills them
        from lodsprite.techniques.defaults import DEFAULTED

        return sprite_adaptive(renderer, **{**dict.fromkeys(DEFAULTED), **options})
    return SpriteTechnique(renderer, **with_terrain_defaults(renderer, options))


def adaptive(renderer: Any, **options: Any) -> Any:
    from lodsprite.techniques.adaptive import AdaptiveTechnique

    return AdaptiveTechnique(renderer, **options)


def sprite_adaptive(renderer: Any, **options: Any) -> Any:
    from lodsprite.techniques.adaptive import SpriteAdaptiveTechnique

    given = with_terrain_defaults(renderer, options)  # None left: the class's own default
    return SpriteAdaptiveTechnique(renderer, **{k: v for k, v in given.items()
                                                if v is not None})


FULL = TechniqueSpec("full", full, (SHADING,), ("terrain",),
                     "the full-resolution terrain (the ground truth)", order=10, light=True)
LOD_SPEC = TechniqueSpec("lod", lod, (LOD, SHADING), ("terrain",), "one uniform coarse level",
                         order=20, knob="lod")
SPRITE = TechniqueSpec("sprite", sprite, SPRITE_OPTIONS, ("terrain",),
                       "LOD-sprite (Chen, Swan & Kaufman 1999); adaptive keyframes on a "
                       "store or with --key-sse", order=30, knob="epsilon",
                       summary=SPRITE_SUMMARY)
ADAPTIVE = TechniqueSpec("adaptive", adaptive, (SSE, GPU_MB, HOST_MB, SHADING, GRID),
                         ("terrain",), "the adaptive (CDLOD-style) renderer, stores of any "
                         "size", order=40, light=True, knob="sse",
                         summary=("{sse:g} px: first frame {first_frame_s:.2f} s; tiles "
                                  "resident {tiles_resident}, loaded {tiles_loaded}, evicted "
                                  "{tiles_evicted}, unreadable {tiles_bad}",))
SPRITE_ADAPTIVE = TechniqueSpec(
    "sprite-adaptive", sprite_adaptive,
    (LOD, EPSILON, KEY_SSE, KEYFRAMES, GPU_MB, HOST_MB, VISIBILITY, GUARD, BORDER, SHADING,
     TILES, TILE_BUDGET, CACHE_MB, CACHE_POLICY, METRIC, PROXY_SSE, PROXY, DEPTH_STRIDE,
     KEY_SCALE, PAIR),
    ("terrain",), "LOD-sprite with keyframes by the adaptive renderer (render: --mode "
    "sprite --key-sse)", order=50, light=True, batch=False, knob="epsilon",
    summary=SPRITE_SUMMARY)
