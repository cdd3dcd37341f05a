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

from lodsprite.sprite.engine import DEFAULT_EPSILON_PX, FRAME_TYPES, KEYFRAME
from lodsprite.sprite.tiled_engine import DEFAULT_TILE_BUDGET_MS
from lodsprite.techniques.base import FALLBACK_TINT, Frame, Param, Technique
from lodsprite.techniques.defaults import MEMORY_DEFAULTS
from lodsprite.techniques.sprite_engines import SpriteEngine, sprite_engine
from lodsprite.terrain.lod import DEFAULT_COARSE, level_step

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from lodsprite.camera import Projection, Viewpoint
    from lodsprite.paths import CameraPath
    from lodsprite.record import RunResult
    from lodsprite.techniques.base import RendererLike, SpriteLike


def resolve_shading(scene, shading: str = "auto") -> str:
    """``texture`` or ``heights`` for a ``shading`` choice (:data:`~lodsprite.gl.terrain.
    SHADINGS`): ``auto`` drapes a terrain store's imagery where it has some, shades any
    other store from its heights (per-pixel normals, level-0 detail) and keeps any other
    scene's texture; ``imagery`` (a store's imagery, drawn as its texture: the scene's
    texture is the imagery, :func:`lodsprite.scene.model.scene_texture`) is refused for a
    scene without."""
    from lodsprite.errors import InputError
    from lodsprite.gl.terrain import SHADINGS
    from lodsprite.scene.model import store_imagery
    from lodsprite.terrain.store import is_store

    if shading not in SHADINGS:
        raise InputError(f"unknown shading '{shading}': use one of {', '.join(SHADINGS)}")
    spec = scene.terrain_spec
    if shading == "imagery":
        if not store_imagery(spec):
            raise InputError(f"--shading imagery: {spec or 'this scene'} is not a terrain "
                             "store tiled with --imagery")
        name = (scene.texture_spec or "terrain").strip().lower()
        if name not in ("terrain", "imagery", "imagery+hillshade"):
            raise InputError(f"--shading imagery draws the store's imagery, not --texture "
                             f"{scene.texture_spec}")
        return "texture"
    if shading == "auto":
        if spec and is_store(spec):
            return "texture" if store_imagery(spec) else "heights"
        return "texture"
    return shading


def set_shading(renderer: RendererLike, shading: str) -> str:
    """Colour ``renderer``'s terrain frames (full, levels, keyframes, LOD-sprite's
    fallback) by ``shading`` resolved for its scene; returns the resolved one."""
    resolved = resolve_shading(renderer.scene, shading)
    renderer.terrain_gl.drawer.shading = resolved
    if resolved == "texture":
        attach_clipmap(renderer)
    return resolved


def attach_clipmap(renderer: RendererLike) -> None:
    """Stream the imagery finer than the scene's texture around the eye (a clipmap,
    :mod:`lodsprite.terrain.clipmap`) when the scene's texture is a store's imagery
    (the default texture or ``imagery``) of more than :data:`~lodsprite.scene.model.
    IMAGERY_SIDE` texels a side; once per renderer.  ``imagery+hillshade`` keeps its one
    texture (the clip levels hold the imagery without the hillshade)."""
    from lodsprite.terrain.remote import location
    from lodsprite.terrain.store import TerrainStore

    geometry = renderer.terrain_gl.geometry
    scene = renderer.scene
    if geometry.clip.core is not None or not clipped(scene.terrain_spec, scene.texture_spec):
        return
    store = TerrainStore(location(scene.terrain_spec),
                         float(scene.hf.meta.get("exaggeration", 1.0)))
    use_clipmap(geometry, store)


def clipped(terrain_spec: str, texture_spec: str) -> bool:
    """Whether a scene of ``terrain_spec`` textured by ``texture_spec`` drapes a store's
    imagery that a clipmap refines (the default texture or ``imagery`` over a store with
    imagery; whether it is finer than the texture is the clipmap's to say)."""
    from lodsprite.scene import model

    name = (texture_spec or "terrain").strip().lower()
    return name in ("terrain", "imagery") and model.store_imagery(terrain_spec)


def use_clipmap(geometry, store) -> None:
    """Give ``geometry`` (a :class:`~lodsprite.gl.terrain.TerrainGeometry`) the clipmap
    of ``store``'s imagery finer than the scene's texture, if it has any."""
    from lodsprite.scene import model
    from lodsprite.terrain.clipmap import Clipmap

    core = Clipmap(store, model.IMAGERY_SIDE)
    if len(core):
        geometry.use_clipmap(core)
    else:
        core.close()


class FullTechnique(Technique):
    """The full-resolution terrain: the ground truth."""

    name = "full"

    def __init__(self, renderer: RendererLike, shading: str = "auto") -> None:
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

    def __init__(self, renderer: RendererLike, lod: int = DEFAULT_COARSE,
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
    :class:`~lodsprite.gl.terrain.TerrainDrawer`) at ``viewpoint`` and compared with
    the same reference ``truth (h, w, 3) uint8``: ``rmse_lod, psnr_lod, ssim_lod,
    rmse_lod_border``."""
    from lodsprite.metrics import psnr, rmse, ssim

    terrain.render(viewpoint, lod)
    plain = terrain.target.read_color()
    terrain.render_proxy(viewpoint, lod, border=True)
    ribbons = terrain.target.read_color()
    return {"rmse_lod": rmse(plain, truth), "psnr_lod": psnr(plain, truth),
            "ssim_lod": ssim(plain, truth), "rmse_lod_border": rmse(ribbons, truth)}


def keyframe_records(keyframes: list, rows: list[dict]) -> list[dict]:
    """JSON records of the keyframes a LOD-sprite run rendered: ``keyframes`` is the
    engine's log (:class:`~lodsprite.sprite.policy.KeyChoice` in order); ``rows`` the
    run's frames with their ``keyframe`` index.  Each record holds the viewpoint, the frame
    projection, the frame that rendered it and ``ahead`` (placed ahead of the viewer by
    look-ahead)."""
    first: dict[int, int] = {}
    for i, row in enumerate(rows):
        first.setdefault(row["keyframe"], i)
    return [{"frame": first.get(k, -1), "viewpoint": key.viewpoint.to_dict(),
             "projection": {"fov_y_deg": key.projection.fov_y_deg,
                            "aspect": key.projection.aspect, "near": key.projection.near,
                            "far": key.projection.far},
             "ahead": bool(key.predicted)}
            for k, key in enumerate(keyframes)]


class SpriteTechnique(Technique):
    """LOD-sprite (Chen, Swan & Kaufman 1999): one technique over three engines
    (:mod:`lodsprite.techniques.sprite_engines`), chosen once from the options: whole
    keyframes inline (the 1999 algorithm, what batch runs time), whole keyframes from a
    worker process (``keyframes="worker"``), or keyframes refreshed tile by tile within
    ``tile_budget_ms`` per frame (``tiles > 1``; from the worker too, without a budget).
    ``store``: the worker's keyframes drawn by the adaptive renderer (a
    :class:`~lodsprite.sprite.worker_settings.StoreKeys`, given by ``sprite-adaptive``).
    Records per frame the keyframe (or tile mosaic) shown; its replay renders that from
    its logged viewpoints and projections, then the frame."""

    name = "sprite"

    def __init__(self, renderer: RendererLike, lod: int = DEFAULT_COARSE,
                 epsilon: float = DEFAULT_EPSILON_PX, keyframes: str = "inline",
                 visibility: str | None = None, guard_px: int | None = None,
                 border: bool = True, shading: str = "auto", tiles: int = 1,
                 tile_budget_ms: float = DEFAULT_TILE_BUDGET_MS, cache_mb: float = 0.0,
                 cache_policy: str = "lru", metric: str = "warp", store=None,
                 proxy: str = MEMORY_DEFAULTS["proxy"],
                 depth_stride: int = MEMORY_DEFAULTS["depth_stride"],
                 key_scale: float = MEMORY_DEFAULTS["key_scale"],
                 pair: bool = MEMORY_DEFAULTS["pair"]) -> None:
        super().__init__(renderer)
        from lodsprite.gl.sprite import DEFAULT_GUARD_PX, DEFAULT_VISIBILITY

        self.shading = set_shading(renderer, shading)
        level_step(renderer.scene.hf.quads, lod)
        self.metric = metric
        self.engine: SpriteEngine = sprite_engine(
            renderer, epsilon, lod, keyframes == "worker", visibility or DEFAULT_VISIBILITY,
            DEFAULT_GUARD_PX if guard_px is None else guard_px, border, tiles,
            tile_budget_ms, cache_mb, cache_policy, metric, store,
            None if proxy == "geometry" else depth_stride, key_scale, pair)
        self.sprite: SpriteLike = self.engine.sprite
        self.sprite.sprite.use_depth_proxy(proxy)
        self.heights = level0_reader(renderer.terrain_gl.geometry, lod, border)

    @property
    def keyframe_log(self) -> list:
        """Every view keyframes (or, with tiles, tile updates) were rendered from; the
        ``keyframe`` column indexes it."""
        return self.engine.keyframes

    def outputs(self, result: RunResult, path: CameraPath) -> dict[str, Any]:
        """Each row gets ``key_x, key_y, key_z`` (the eye, metres, of the keyframe or tile
        update it shows), after its ``keyframe`` and ``keyframes`` columns; the files:
        ``keyframes.json`` (:func:`keyframe_records`)."""
        log = self.keyframe_log
        for row in result.rows:
            eye = log[row["keyframe"]].viewpoint.o
            row.update(key_x=float(eye[0]), key_y=float(eye[1]), key_z=float(eye[2]))
        at = result.columns.index("keyframe") + 2
        result.columns[at:at] = ["key_x", "key_y", "key_z"]
        return {"keyframes.json": {"keyframes": keyframe_records(log, result.rows)}}

    def params(self) -> dict[str, Param]:
        return {"epsilon": Param("epsilon", self.sprite.epsilon_px, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "epsilon":
            super().set_param(name, value)
        self.engine.set_epsilon(value)

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """The engine's warm-up (shaders compiled; the timed run starts with no keyframe,
        as the 1999 algorithm does, or with the worker's first); over a store, the level-0
        chunks those asked of the reader arrived (the first view resident, as every
        technique's warm-up leaves it)."""
        self.engine.warm_up(viewpoint)
        if self.heights is not None and not self.heights.settle():
            log.warning("warm-up: the store's level-0 chunks of the first view did not all "
                        "arrive in time; the first timed frames may still read them")

    def frame(self, viewpoint: Viewpoint) -> Frame:
        return self.engine.frame(viewpoint)

    def decision(self) -> dict[str, Any]:
        return self.engine.decision()

    def tile_drawer(self, update: int, tile: int) -> Callable | None:
        """The drawer that re-renders ``tile`` as update ``update`` drew it (None: the
        full-resolution terrain)."""
        return None

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        return self.engine.replay(viewpoint, decision, self.tile_drawer)

    def quality_extra(self, viewpoint: Viewpoint, decision: dict[str, Any],
                      truth: np.ndarray) -> dict[str, float]:
        """The plain coarse level and the coarse level with LOD-sprite's border ribbons
        against the same reference (:func:`coarse_baseline`)."""
        return coarse_baseline(self.renderer.terrain_gl.drawer, viewpoint, self.sprite.lod, truth)

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        """Keyframe count and fraction, the engine's work (tiles rendered), mean time per
        frame kind (ms), mean error (px), the cache's counts, how spriteframes are drawn."""
        d = self.sprite.sprite
        out: dict[str, Any] = {"lod": self.sprite.lod, "epsilon": self.sprite.epsilon_px,
                               "visibility": self.sprite.sprite.visibility,
                               "shading": self.shading,
                               "metric": self.metric,
                               "proxy": proxy_name(d),
                               "depth_stride": None if d.depth_mesh is None
                               else d.depth_mesh.stride,
                               "key_scale": d.key_scale, "pair": d.pair,
                               "keyframes": sum(f.kind == KEYFRAME for f in frames),
                               **self.engine.work_summary(frames)}
        for t in FRAME_TYPES:
            ms = [f.ms for f in frames if f.kind == t]
            out[f"mean_ms_{t}"] = float(np.mean(ms)) if ms else float("nan")
        out["keyframe_fraction"] = out["keyframes"] / max(1, len(frames))
        out["mean_error_px"] = float(np.mean([f.error_px for f in frames]))
        return {**out, **self.engine.cache_summary(frames)}

    def draw_to(self, framebuffer=None) -> None:
        self.engine.draw_to(framebuffer)

    def read_image(self) -> np.ndarray:
        return self.engine.read_image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        return self.engine.key_view()

    def coarse_level(self) -> int | None:
        return self.sprite.lod

    def set_fallback_tint(self, on: bool) -> None:
        self.sprite.sprite.fallback_tint = FALLBACK_TINT if on else (*FALLBACK_TINT[:3], 0.0)

    def status(self) -> str:
        return self.engine.status()

    def release(self) -> None:
        self.engine.release()
        if self.heights is not None:
            self.heights.close()
            self.heights = None


def proxy_name(drawer) -> str:
    """What ``drawer`` (a :class:`~lodsprite.gl.sprite.SpriteDrawer`) draws spriteframes
    on: the proxy ``geometry``, the keyframe's ``depth`` mesh (``depth-refined``) or its
    depth ``search``."""
    return "geometry" if drawer.depth_mesh is None else drawer.depth_mesh.kind
