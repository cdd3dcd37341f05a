"""Rendering a camera path with timings: the engine behind ``lodsprite render``.

:func:`render_path` makes the registry's technique for the config
(:mod:`lodsprite.techniques`: ``full``, ``lod``, ``sprite``, ``adaptive``, and
``sprite-adaptive`` for ``--mode sprite --key-sse``) and runs it through the one harness
(:func:`lodsprite.harness.run_path`): one untimed warm-up, per-frame time with
``ctx.finish()`` inside the clock, nothing read back in the timed loop; saved frames,
video and quality (``--ground-truth``, every technique) come from an untimed replay of the
same decisions.  The distributed mode is not core: the command line hands it to
:func:`lodsprite.distributed.run.render_distributed` (this module never imports
:mod:`lodsprite.distributed`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import write_json, write_png
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import (
    DEFAULT_GUARD_PX,
    DEFAULT_VISIBILITY,
    VISIBILITY_MODES,
)
from lodsprite.gl.sprite_tiles import MAX_TILES
from lodsprite.gl.terrain import SHADINGS
from lodsprite.harness import RunResult, run_path, scene_reference, timing_summary, write_run
from lodsprite.paths import CameraPath, get_path
from lodsprite.progress import Progress
from lodsprite.scene import Scene, load_scene
from lodsprite.sprite.cache import POLICIES as CACHE_POLICIES
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX
from lodsprite.sprite.policy import METRICS
from lodsprite.techniques.terrain import resolve_shading
from lodsprite.terrain import DEFAULT_EXAGGERATION
from lodsprite.terrain.loaders import load_level0
from lodsprite.terrain.lod import level_step
from lodsprite.terrain.store import is_store
from lodsprite.workers import peak_rss_mb

MAX_TILE_GRID = math.isqrt(MAX_TILES)  # --tiles N: N x N keyframe tiles
#: The techniques that draw a store itself, never the scene's in-memory grid (full: level 0).
LIGHT_TECHNIQUES = ("adaptive", "sprite-adaptive", "full")


def _modes() -> tuple[str, ...]:
    """``--mode`` choices: the registry's terrain techniques run in this process (the
    distributed client is handed on by the command line; sprite-adaptive is ``sprite``
    with ``--key-sse``)."""
    from lodsprite import techniques

    return tuple(n for n in techniques.names(("terrain",))
                 if n not in ("distributed", "sprite-adaptive"))


MODES = _modes()  # the built-in ones (a technique registered later joins _modes())
MAX_GUARD_PX = 1024


@dataclass(frozen=True)
class RenderConfig:
    """What to render: terrain, texture and path specs, mode, level, image size, frames."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    path: str = "chen1999"
    mode: str = "full"
    lod: int | None = None    # None: the terrain's default (lodsprite.techniques.defaults)
    size: tuple[int, int] = (512, 512)
    frames: int | None = None
    grid: int | None = None
    exaggeration: float = DEFAULT_EXAGGERATION
    fov_y_deg: float | None = None  # None: the path's own (45° for the built-in paths)
    save_frames: bool = False
    epsilon: float = DEFAULT_EPSILON_PX
    ground_truth: bool = False
    quality_stride: int = 1
    visibility: str = DEFAULT_VISIBILITY
    border: bool = True
    guard_px: int = DEFAULT_GUARD_PX
    sse: float = 1.0          # adaptive: screen-space error tolerance, pixels
    key_sse: float | None = None  # sprite: keyframes by the adaptive renderer at this SSE
    #                             (None: the terrain's default, 0.5 px on a store)
    gpu_mb: float = 256.0     # adaptive: GPU tile cache budget
    host_mb: float = 512.0    # adaptive: host tile cache budget
    proxy_sse: float | None = None  # sprite proxy: the adaptive mesh at this SSE (needs key_sse)
    flip: bool = False        # with ground_truth: FLIP per frame too
    shading: str = "auto"     # colour: auto (heights on a store) | texture | heights
    tiles: int | None = None  # sprite: an N x N grid of keyframe tiles (1: whole keyframes)
    tile_budget_ms: float | None = None  # sprite, tiles > 1: tile work per frame, ms
    cache_mb: float | None = None  # sprite: keyframe cache budget, MB (0: off)
    cache_policy: str = "lru"  # sprite: keyframe cache replacement, lru | benefit
    metric: str | None = None  # sprite: "warp" (Eq. 1-2) or "resample" (adds resampling)
    # lod, key_sse, proxy_sse, tiles, tile_budget_ms, cache_mb, metric: None is the
    # terrain's default (resolved(); lodsprite.techniques.defaults), a value is kept
    save_every: int = 1       # with save_frames: save every n-th frame of the replay only

    def resolved(self, store: bool | None = None) -> RenderConfig:
        """This config with every option left None filled from the terrain's defaults
        (:func:`lodsprite.techniques.defaults.fill_defaults`: LOD-sprite on a store gets
        the store's, any other mode or terrain the 1999 options; ``store=False``: the
        1999 options whatever the terrain, as the distributed client); values given are
        kept."""
        from lodsprite.techniques.defaults import DEFAULTED, fill_defaults

        given = {k: getattr(self, k) for k in DEFAULTED}
        if all(v is not None for k, v in given.items() if k not in ("key_sse", "proxy_sse")) \
                and (self.key_sse is not None or self.mode != "sprite" or store is False):
            return self  # nothing to fill
        if self.mode != "sprite":
            store = False
        filled = fill_defaults(self.terrain, given, store)
        return replace(self, **filled)

    @property
    def technique(self) -> str:
        """The registry's name of what this config renders."""
        c = self.resolved()
        return "sprite-adaptive" if c.mode == "sprite" and c.key_sse else c.mode

    def technique_options(self) -> dict:
        """The options of the config the technique declares (the registry picks them)."""
        self = self.resolved()
        return {"lod": self.lod, "epsilon": self.epsilon, "visibility": self.visibility,
                "guard_px": self.guard_px, "border": self.border, "sse": self.sse,
                "key_sse": self.key_sse, "gpu_mb": self.gpu_mb, "host_mb": self.host_mb,
                "proxy_sse": self.proxy_sse, "threaded": False, "shading": self.shading,
                "tiles": self.tiles, "tile_budget_ms": self.tile_budget_ms,
                "cache_mb": self.cache_mb, "cache_policy": self.cache_policy,
                "metric": self.metric}

    def validate(self) -> None:
        """Raise :class:`InputError` for a bad option (checked with the defaults filled)."""
        self = self.resolved()
        modes = _modes()  # the registry's now: a technique registered later is one too
        if self.mode not in modes:
            raise InputError(f"unknown mode '{self.mode}': use one of {', '.join(modes)}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be between 16 and 8192 pixels, got {w}x{h}")
        if self.frames is not None and self.frames < 2:
            raise InputError(f"--frames must be at least 2, got {self.frames}")
        if not self.epsilon > 0:
            raise InputError(f"--epsilon must be > 0 pixels, got {self.epsilon}")
        if self.visibility not in VISIBILITY_MODES:
            raise InputError(f"unknown visibility '{self.visibility}': use one of "
                             f"{', '.join(VISIBILITY_MODES)}")
        if not (isinstance(self.guard_px, int) and 0 <= self.guard_px <= MAX_GUARD_PX):
            raise InputError(f"--guard must be a whole number of pixels in 0..{MAX_GUARD_PX}, "
                             f"got {self.guard_px}")
        if self.shading not in SHADINGS:
            raise InputError(f"unknown shading '{self.shading}': use one of "
                             f"{', '.join(SHADINGS)}")
        if self.metric not in METRICS:
            raise InputError(f"unknown metric '{self.metric}': use one of "
                             f"{', '.join(METRICS)}")
        if self.quality_stride < 1:
            raise InputError(f"quality stride must be >= 1, got {self.quality_stride}")
        if self.save_every < 1:
            raise InputError(f"save_every must be >= 1, got {self.save_every}")
        if self.key_sse is not None and (self.mode != "sprite" or not self.key_sse > 0):
            raise InputError("--key-sse goes with --mode sprite and must be > 0 pixels")
        if not (isinstance(self.tiles, int) and 1 <= self.tiles <= MAX_TILE_GRID
                and self.tile_budget_ms >= 0):
            raise InputError(f"--tiles must be a whole number in 1..{MAX_TILE_GRID} and "
                             f"--tile-budget-ms >= 0, got {self.tiles}, {self.tile_budget_ms}")
        if self.tiles > 1 and self.mode != "sprite":
            raise InputError("--tiles goes with --mode sprite")
        if not self.cache_mb >= 0 or self.cache_policy not in CACHE_POLICIES:
            raise InputError(f"--cache-mb must be >= 0 and --cache-policy lru or benefit, "
                             f"got {self.cache_mb}, {self.cache_policy!r}")
        if self.proxy_sse is not None and (self.key_sse is None or not self.proxy_sse > 0):
            raise InputError("--proxy-sse needs adaptive keyframes (--mode sprite --key-sse PX, "
                             "whose tile caches the proxy shares) and must be > 0 pixels")
        if not (self.sse > 0 and self.gpu_mb > 0 and self.host_mb > 0):
            raise InputError(f"--sse, --gpu-mb and --host-mb must be > 0, got {self.sse}, "
                             f"{self.gpu_mb}, {self.host_mb}")


def parse_size(text: str) -> tuple[int, int]:
    """``'WxH'`` or ``'N'`` to ``(width, height)`` pixels."""
    parts = text.lower().split("x")
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) == 1:
        vals = vals * 2
    if len(vals) != 2:
        raise InputError(f"size must look like 512x512, got '{text}'")
    return vals[0], vals[1]


def prepare(config: RenderConfig, light: bool = True) -> tuple[Scene, CameraPath]:
    """Validate the config and load scene and path (all user errors surface here).

    Over a store, the modes that draw the store itself (:data:`LIGHT_TECHNIQUES`) get a
    light scene (:func:`~lodsprite.scene.load_scene` ``light=True``, with ``ground_truth``
    too: its reference is level 0, :func:`lodsprite.harness.scene_reference`), and no
    colour texture where frames are shaded from heights.  ``light=False``: the working
    grid whatever the mode (the distributed client, whose server loads the scene so)."""
    config = config.resolved()
    config.validate()
    level0 = None
    store = is_store(config.terrain)
    if config.mode == "full" and store:  # level 0's own samples, whole
        level0 = load_level0(config.terrain, config.exaggeration)  # (refused if too large)
    light = light and store and config.technique in LIGHT_TECHNIQUES
    textured = resolve_shading(Scene(terrain_spec=config.terrain), config.shading) == "texture"
    scene = load_scene(config.terrain, config.texture, config.grid, config.exaggeration,
                       light=light, textured=textured or not light)
    if level0 is not None:  # the texture stays the working grid's: the same extent
        scene = replace(scene, hf=level0)
    if config.mode in ("lod", "sprite"):  # the level checked before any GL work
        level_step(scene.hf.quads, config.lod)
    return scene, get_path(config.path, scene.hf, config.frames)


def field_of_view(config: RenderConfig, path: CameraPath) -> float:
    """The vertical field of view (degrees) to render ``path`` with: the config's if set,
    else the path's own (a path file keeps the field of view it was recorded with)."""
    return path.fov_y_deg if config.fov_y_deg is None else config.fov_y_deg


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


def run_technique(renderer, path: CameraPath, config: RenderConfig,
                  progress: Progress | None = None, on_image=None,
                  keyframes: list | None = None, image_frames=None,
                  reference: Callable | None = None) -> RunResult:
    """The registry's technique for ``config`` on ``renderer`` (a
    :class:`~lodsprite.api.Renderer`) along ``path``, through the harness (``on_image``
    for the replayed frames ``image_frames``, default all; quality against ``reference``,
    default :func:`~lodsprite.harness.scene_reference`); a LOD-sprite run's rows get
    ``key_x, key_y, key_z`` (the eye, metres, of the keyframe each frame shows) and
    ``keyframes``, if given, is extended with the engine's keyframe log."""
    from lodsprite import techniques

    if reference is None and config.ground_truth:
        with scene_reference(renderer, config.shading) as own:
            return run_technique(renderer, path, config, progress, on_image, keyframes,
                                 image_frames, own)
    technique = techniques.get(config.technique).create(
        renderer, **techniques.get(config.technique).bind(config.technique_options()))
    try:
        result = run_path(technique, path, progress=progress,
                          ground_truth=config.ground_truth, reference=reference,
                          quality_stride=config.quality_stride, flip=config.flip,
                          on_image=on_image, image_frames=image_frames)
        log = getattr(technique, "keyframe_log", None)  # tiled LOD-sprite: tile updates
        if log is None:
            log = getattr(getattr(technique, "sprite", None), "keyframes", None)
        if log is not None:
            for row in result.rows:
                eye = log[row["keyframe"]].viewpoint.o
                row.update(key_x=float(eye[0]), key_y=float(eye[1]), key_z=float(eye[2]))
            result.columns[result.columns.index("keyframe") + 2:
                           result.columns.index("keyframe") + 2] = ["key_x", "key_y", "key_z"]
            if keyframes is not None:
                keyframes.extend(log)
        return result
    finally:
        technique.release()


def sprite_frames(pr: PathRenderer, path: CameraPath, config: RenderConfig,
                  progress: Progress | None = None, on_image=None,
                  keyframes: list | None = None) -> list[dict]:
    """The rows of a LOD-sprite run (``config.mode == "sprite"``) on ``pr``'s GL state
    (:func:`run_technique`): ``kind, ms, triangles, error_px, keyframe, keyframes,
    key_x..z`` and, with ``config.ground_truth``, the replay's quality columns."""
    from lodsprite.api import Renderer

    with Renderer.wrap(pr) as renderer:
        return run_technique(renderer, path, config, progress, on_image, keyframes).rows


def render_path(config: RenderConfig, out_dir: Path, progress: Progress | None = None,
                video: Path | None = None) -> dict:
    """Render ``config``'s path; write ``frames.csv``, ``summary.json`` (and in sprite mode
    ``keyframes.json``, every keyframe rendered, indexed by the ``keyframe`` column) and
    optionally PNG frames to ``out_dir``; return the summary.

    ``video``: an MP4 file of the frames shown (:mod:`lodsprite.report.video`); with
    ``config.ground_truth`` each video frame is full resolution | technique | difference.
    Saved frames and video come from the untimed replay.
    """
    from lodsprite.api import Renderer
    from lodsprite.report.video import VideoWriter, check_video_path, side_by_side

    if video is not None:
        check_video_path(video)
    config = config.resolved()
    scene, path = prepare(config)
    out_dir = Path(out_dir)
    keyframes: list = []
    with Renderer(scene, config.size, field_of_view(config, path)) as renderer, \
            ExitStack() as stack:
        writer = stack.enter_context(VideoWriter(video)) if video is not None else None
        reference = (stack.enter_context(scene_reference(renderer, config.shading))
                     if config.ground_truth else None)

        def on_image(i: int, image: np.ndarray, truth: np.ndarray | None) -> None:
            if config.save_frames:
                write_png(out_dir / "frames" / f"frame_{i:05d}.png", image)
            if writer is not None:
                if config.ground_truth:
                    if truth is None:
                        truth = reference(path.viewpoints[i])
                    image = side_by_side(truth, image)
                writer.append(image)

        wanted = on_image if config.save_frames or writer is not None else None
        only = (range(0, len(path.viewpoints), config.save_every)
                if writer is None and config.save_every > 1 else None)
        result = run_technique(renderer, path, config, progress, wanted, keyframes, only,
                               reference)
        info = renderer.info
        renderer.gl.check_error("render_path")
    summary = {
        **result.summary, "mode": config.mode, "terrain": config.terrain,
        "texture": config.texture, "path": config.path,
        "size": list(config.size), "grid": scene.hf.quads,
        "exaggeration": config.exaggeration, "gl_version": info.version,
        "config": asdict(config),
    }
    if "rmse_mean" in summary and "rmse_lod_mean" in summary:
        summary["rmse_ratio"] = (summary["rmse_mean"] / summary["rmse_lod_mean"]
                                 if summary["rmse_lod_mean"] > 0 else float("nan"))
    write_run(out_dir, result, summary)
    if config.mode == "sprite":
        write_json(out_dir / "keyframes.json",
                   {"keyframes": keyframe_records(keyframes, result.rows)})
    return summary


__all__ = ["MODES", "RenderConfig", "field_of_view", "keyframe_records", "parse_size",
           "peak_rss_mb", "prepare", "render_path", "run_technique", "sprite_frames",
           "timing_summary"]
