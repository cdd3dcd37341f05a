"""Every technique lodsprite ships, registered by dotted path (nothing imported here).

Adding one: write its class (a :class:`~lodsprite.techniques.Technique`) and add one
:func:`~lodsprite.techniques.register` entry, here or in your own code
(``examples/custom_technique.py``).
"""

from __future__ import annotations

from lodsprite.techniques.registry import Option, TechniqueSpec, register

LOD = Option("lod", int, 16, "coarse level, quads per side (a power of two)")
EPSILON = Option("epsilon", float, 1.0, "LOD-sprite error threshold ε, pixels")
VISIBILITY = Option("visibility", str, "coarse", "LOD-sprite visibility rule")
GUARD = Option("guard_px", int, 32, "keyframe guard band, pixels")
BORDER = Option("border", bool, True, "draw the coarse level's border ribbons")
CACHE_MB = Option("cache_mb", float, 0.0, "LOD-sprite keyframe cache budget, MB (0: off)")
CACHE_POLICY = Option("cache_policy", str, "lru", "keyframe cache replacement: lru | benefit")
METRIC = Option("metric", str, "warp",
                "LOD-sprite error metric: warp (Eq. 1-2) | resample (adds resampling)")
THREADED = Option("threaded", bool, False, "render keyframes on a worker thread")
TILES = Option("tiles", int, 1, "LOD-sprite: N x N keyframe tiles (1: whole keyframes)")
TILE_BUDGET = Option("tile_budget_ms", float, 8.0, "LOD-sprite tiles: tile work per frame, ms")
SSE = Option("sse", float, 1.0, "adaptive: screen-space error tolerance, pixels")
KEY_SSE = Option("key_sse", float, 1.0, "keyframes by the adaptive renderer at this SSE, px")
PROXY_SSE = Option("proxy_sse", float, None,
                   "sprite proxy: the adaptive mesh at this SSE, px (None: the uniform --lod)")
GPU_MB = Option("gpu_mb", float, 256.0, "adaptive: GPU tile cache budget, MB")
SHADING = Option("shading", str, "auto", "colour: auto (heights on a store) | texture | heights")
HOST_MB = Option("host_mb", float, 512.0, "adaptive: host tile cache budget, MB")
GRID = Option("grid", int, 64, "adaptive: node grid, quads a side (16 | 32 | 64 | 128)")
SERVER = Option("server", str, "", "the LOD server, HOST:PORT")
MAX_ERROR = Option("max_error", float, 4.0, "distributed: largest error shown, pixels")
FOLDER = Option("folder", str, "", "the lumigraph folder (default: the scene's)")
LF_OPTIONS = (FOLDER, Option("depth_correction", bool, True, "depth-correct with the proxy"),
              Option("nodes", int, 16, "nodes per frame (arbitrary, projective)"),
              Option("level", int, 1, "subsample: mip level of the node images"),
              Option("reuse", int, 6, "projective: frames a reconstruction is reused"),
              Option("fade", int, 8, "progressive: frames of a fade"),
              Option("target_fps", float, 30.0, "critical: the frame-rate target"),
              Option("texture_mb", float, 4.0, "critical: texture memory, MB"))
TARGET_FPS = Option("target_fps", float, None, "the crowd's frame-rate target (LOD feedback)")
CROWD = Option("crowd", object, None, "the crowd (default: the scene's object set)")
SLOTS = Option("slots", int, 16, "crowd: LOD slots per type in the manager's table")
ACTIVE = Option("active", int, 300, "crowd: objects whose LOD is updated per frame")
NEAR = Option("range_near", float, 5.0, "crowd: distance of the finest LOD, metres")
FAR = Option("range_far", float, 150.0, "crowd: distance of the coarsest LOD, metres")
DIST = Option("dist", object, None, "crowd: the snapshots' distribution (default linear)")

TERRAIN = "lodsprite.techniques.terrain"
ADAPTIVE = "lodsprite.techniques.adaptive"

register(TechniqueSpec("full", f"{TERRAIN}:FullTechnique", (SHADING,), ("terrain",),
                       "the full-resolution terrain (the ground truth)"))
register(TechniqueSpec("lod", f"{TERRAIN}:LodTechnique", (LOD, SHADING), ("terrain",),
                       "one uniform coarse level"))
register(TechniqueSpec("sprite", f"{TERRAIN}:SpriteTechnique",
                       (LOD, EPSILON, THREADED, VISIBILITY, GUARD, BORDER, SHADING, TILES,
                        TILE_BUDGET, CACHE_MB, CACHE_POLICY, METRIC),
                       ("terrain",),
                       "LOD-sprite (Chen, Swan & Kaufman 1999)"))
register(TechniqueSpec("adaptive", f"{ADAPTIVE}:AdaptiveTechnique",
                       (SSE, GPU_MB, HOST_MB, SHADING, GRID), ("terrain",),
                       "the adaptive (CDLOD-style) renderer, stores of any size"))
register(TechniqueSpec("sprite-adaptive", f"{ADAPTIVE}:SpriteAdaptiveTechnique",
                       (LOD, EPSILON, KEY_SSE, GPU_MB, HOST_MB, VISIBILITY, GUARD, BORDER,
                        SHADING, TILES, TILE_BUDGET, CACHE_MB, CACHE_POLICY, METRIC,
                        PROXY_SSE),
                       ("terrain",), "LOD-sprite with keyframes by the adaptive renderer"))
register(TechniqueSpec("distributed", "lodsprite.distributed.technique:create",
                       (SERVER, LOD, EPSILON, MAX_ERROR), ("terrain",),
                       "LOD-sprite client, keyframes from a LOD server (Swan et al. 2002)"))

CROWD_MODES = {"manager": "the LODManager's crowd (Gumbau et al.)",
               "independent": "every object extracts its own LOD (baseline a)",
               "discrete": "discrete LODs by screen size (baseline b)"}
for _mode, _text in CROWD_MODES.items():
    register(TechniqueSpec(_mode, "lodsprite.manager.technique:create",
                           (CROWD, TARGET_FPS, SLOTS, ACTIVE, NEAR, FAR, DIST),
                           ("objects",), _text, fixed={"mode": _mode}))

LUMIGRAPH_METHODS = {
    "critical": "time-critical reconstruction (Sloan, Cohen & Gortler 1997)",
    "full": "every node of the lumigraph", "arbitrary": "nearest nodes, any count",
    "fixed": "a fixed node set", "line": "nodes on a line",
    "projective": "projective texture reuse", "progressive": "progressive refinement",
    "subsample": "a subsampled lumigraph"}
for _method, _text in LUMIGRAPH_METHODS.items():
    register(TechniqueSpec(f"lumigraph-{_method}", "lodsprite.lumigraph.technique:create",
                           LF_OPTIONS, ("lightfield",), _text, mode=_method,
                           fixed={"method": _method}))

SCENE_OPTIONS = (
    Option("world", object, None, "the world (default: the scene file's)"),
    Option("terrain_mode", str, "adaptive", "scene: the terrain's technique: full | lod | "
                                            "adaptive | sprite | sprite-adaptive"),
    Option("schedule", str, "none", "scene: the frame budget: none | scheduler | independent"),
    Option("target_fps", float, None, "scene: the frame-rate target of the budget"),
    Option("keyframes", str, "static", "scene, LOD-sprite: keyframes hold the static layers "
                                       "(static) or the terrain only (terrain)"),
    Option("exponent", float, 1.0, "scene: the objects' LOD exponent (0: full meshes)"),
    Option("nodes", int, 8, "scene: the light fields' node budget"),
    Option("ground_truth", bool, False, "scene: the full-detail reference"),
    Option("frame_s", float, 1.0 / 30.0, "scene: seconds of world time a frame"),
    LOD, EPSILON, SSE, SHADING, GPU_MB, HOST_MB)
register(TechniqueSpec("scene", "lodsprite.layered.technique:create", SCENE_OPTIONS,
                       ("terrain", "objects"),
                       "terrain, objects and light fields composited by depth (issue 23)"))
