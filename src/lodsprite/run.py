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

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import write_json, write_png
from lodsprite.gl.paths import PathRenderer
from lodsprite.harness import RunResult, run_path, scene_reference, timing_summary, write_run
from lodsprite.paths import CameraPath, get_path
from lodsprite.progress import Progress
from lodsprite.scene import Scene, load_scene
from lodsprite.techniques.configs import TechniqueOptions, takes_options
from lodsprite.techniques.terrain import resolve_shading
from lodsprite.terrain import DEFAULT_EXAGGERATION
from lodsprite.terrain.loaders import load_level0
from lodsprite.terrain.lod import level_step
from lodsprite.terrain.store import is_store
from lodsprite.workers import peak_rss_mb


def render_modes() -> tuple[str, ...]:
    """``--mode`` choices: the registry's terrain techniques that ``render`` runs itself
    (:attr:`~lodsprite.techniques.TechniqueSpec.batch`; the distributed client is handed
    on by the command line, sprite-adaptive is ``sprite`` with ``--key-sse``), plug-ins
    included."""
    from lodsprite import techniques

    return tuple(s.name for s in techniques.specs(("terrain",)) if s.batch)


def __getattr__(name: str):
    if name == "MODES":  # the registry's now (plug-ins are discovered when first asked)
        return render_modes()
    raise AttributeError(name)


@takes_options
@dataclass(frozen=True)
class RenderConfig(TechniqueOptions):
    """What to render: terrain, texture and path specs, mode, image size, frames, and the
    technique's options (``options``: name -> value given, each declared once by the
    technique's :class:`~lodsprite.techniques.Option`; also taken as keywords,
    ``RenderConfig(mode="sprite", epsilon=2.0)``, and read as attributes, ``c.epsilon``).
    An option with a terrain-dependent default (``lod``, ``key_sse``, ``tiles``...) left
    out is filled by :meth:`resolved` (:mod:`lodsprite.techniques.defaults`)."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    path: str = "chen1999"
    mode: str = "full"
    size: tuple[int, int] = (512, 512)
    frames: int | None = None
    grid: int | None = None
    exaggeration: float = DEFAULT_EXAGGERATION
    fov_y_deg: float | None = None  # None: the path's own (45° for the built-in paths)
    save_frames: bool = False
    ground_truth: bool = False
    quality_stride: int = 1
    flip: bool = False        # with ground_truth: FLIP per frame too
    save_every: int = 1       # with save_frames: save every n-th frame of the replay only
    options: dict = field(default_factory=dict)

    def resolved(self, store: bool | None = None) -> RenderConfig:
        """This config with every option left out that has a terrain default filled
        (:func:`lodsprite.techniques.defaults.fill_defaults`: LOD-sprite on a store gets
        the store's, any other mode or terrain the 1999 options; ``store=False``: the
        1999 options whatever the terrain, as the distributed client); values given are
        kept."""
        from lodsprite.techniques.defaults import DEFAULTED, fill_defaults

        given = {k: self.options.get(k) for k in DEFAULTED}
        if all(v is not None for k, v in given.items() if k not in ("key_sse", "proxy_sse")) \
                and ("key_sse" in self.options or self.mode != "sprite" or store is False):
            return self  # nothing to fill
        if self.mode != "sprite":
            store = False
        filled = fill_defaults(self.terrain, given, store)
        return replace(self, options={**self.options, **filled})

    @property
    def technique(self) -> str:
        """The registry's name of what this config renders."""
        c = self.resolved()
        return "sprite-adaptive" if c.mode == "sprite" and c.options.get("key_sse") else c.mode

    def technique_options(self) -> dict:
        """The options given (terrain defaults filled); keyframes are rendered in the
        frame that needs them (a timed run)."""
        return {**self.resolved().options, "threaded": False}

    def validate(self) -> None:
        """Raise :class:`InputError` for a bad option (checked with the defaults filled):
        each option's value by its declaration (:meth:`Option.check`), then what goes
        with what."""
        from lodsprite import techniques

        self = self.resolved()
        modes = render_modes()
        if self.mode not in modes:
            raise InputError(f"unknown mode '{self.mode}': use one of {', '.join(modes)}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be between 16 and 8192 pixels, got {w}x{h}")
        if self.frames is not None and self.frames < 2:
            raise InputError(f"--frames must be at least 2, got {self.frames}")
        if self.quality_stride < 1:
            raise InputError(f"quality stride must be >= 1, got {self.quality_stride}")
        if self.save_every < 1:
            raise InputError(f"save_every must be >= 1, got {self.save_every}")
        spec, known = techniques.get(self.technique), techniques.all_options()
        for name, value in self.options.items():
            mine = [o for o in spec.options if o.name == name]
            (mine[0] if mine else known[name]).check(value)
        if "key_sse" in self.options and self.mode != "sprite":
            raise InputError("--key-sse goes with --mode sprite")
        if self.options.get("tiles", 1) > 1 and self.mode != "sprite":
            raise InputError("--tiles goes with --mode sprite")
        if "proxy_sse" in self.options and "key_sse" not in self.options:
            raise InputError("--proxy-sse needs adaptive keyframes (--mode sprite --key-sse "
                             "PX, whose tile caches the proxy shares)")


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

    Over a store, the techniques that draw the store itself (their spec's ``light``) get a
    light scene (:func:`~lodsprite.scene.load_scene` ``light=True``, with ``ground_truth``
    too: its reference is level 0, :func:`lodsprite.harness.scene_reference`), and no
    colour texture where frames are shaded from heights.  ``light=False``: the working
    grid whatever the mode (the distributed client, whose server loads the scene so)."""
    from lodsprite import techniques

    config = config.resolved()
    config.validate()
    level0 = None
    store = is_store(config.terrain)
    if config.mode == "full" and store:  # level 0's own samples, whole
        level0 = load_level0(config.terrain, config.exaggeration)  # (refused if too large)
    light = light and store and techniques.get(config.technique).light
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
        "technique": config.technique, "config": config.flat(),
    }
    if "rmse_mean" in summary and "rmse_lod_mean" in summary:
        summary["rmse_ratio"] = (summary["rmse_mean"] / summary["rmse_lod_mean"]
                                 if summary["rmse_lod_mean"] > 0 else float("nan"))
    write_run(out_dir, result, summary)
    if config.mode == "sprite":
        write_json(out_dir / "keyframes.json",
                   {"keyframes": keyframe_records(keyframes, result.rows)})
    return summary


__all__ = ["RenderConfig", "render_modes", "field_of_view", "keyframe_records", "parse_size",
           "peak_rss_mb", "prepare", "render_path", "run_technique", "sprite_frames",
           "timing_summary"]
