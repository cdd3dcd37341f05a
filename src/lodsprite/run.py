"""The one batch driver: any technique of the registry on any scene along a camera path,
timed, measured and written the same way (its core, :func:`lodsprite.driver.drive`).

* :func:`run_scene` makes the registry's technique on a :class:`~lodsprite.api.Renderer`
  over a :class:`~lodsprite.scene.Scene` (any layers) and drives it.
* :func:`render_path` is ``lodsprite render``: a :class:`RenderConfig` (a terrain, or any
  scene spec in ``scene``) opened by :func:`~lodsprite.runconfig.prepare`, then
  :func:`run_scene`.

The other batch commands are shortcuts onto it: ``render --scene FILE`` (the ``scene``
technique, :func:`lodsprite.layered.technique.render_scene`), ``crowd``
(:func:`lodsprite.manager.run.run_crowd`), ``lumigraph render``
(:func:`lodsprite.lumigraph.run.render_lumigraph`) and ``client``
(:func:`lodsprite.distributed.run.run_client`, a technique on the client's own GL
context, through :func:`drive`).  This module never imports those packages.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lodsprite.driver import Measure, drive
from lodsprite.errors import InputError
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.harness import RunResult, timing_summary
from lodsprite.paths import CameraPath
from lodsprite.progress import Progress
from lodsprite.runconfig import (  # noqa: F401  (their public home was here)
    RenderConfig,
    field_of_view,
    parse_size,
    prepare,
    render_modes,
)
from lodsprite.techniques.terrain import keyframe_records
from lodsprite.workers import peak_rss_mb

if TYPE_CHECKING:
    from lodsprite.scene import Scene


def __getattr__(name: str):
    if name == "MODES":  # the registry's now (plug-ins are discovered when first asked)
        return render_modes()
    raise AttributeError(name)


def run_scene(scene: Scene, mode: str, options: Mapping[str, Any], path: CameraPath,
              size: tuple[int, int], out_dir: Path | None = None,
              measure: Measure | None = None, *, fov_y_deg: float | None = None,
              progress: Progress | None = None,
              summary: Mapping[str, Any] | None = None) -> RunResult:
    """The registry's technique ``mode`` with ``options`` (checked by its declarations) on
    a renderer of ``size = (w, h)`` pixels over ``scene``, along ``path`` (field of view:
    ``fov_y_deg``, default the path's), through :func:`drive`.  A technique that draws a
    layer ``scene`` lacks is an :class:`~lodsprite.errors.InputError`."""
    from lodsprite import techniques
    from lodsprite.api import Renderer

    measure = measure or Measure()
    measure.check()  # before anything is made
    spec = techniques.get(mode)
    missing = set(spec.layers) - set(scene.layers)
    if missing:
        usable = ", ".join(s.short for s in techniques.specs(scene.layers)) or "none"
        raise InputError(f"{spec.short} draws {', '.join(sorted(missing))}, which "
                         f"{scene.name} lacks; its techniques: {usable}")
    fov = path.fov_y_deg if fov_y_deg is None else fov_y_deg
    with Renderer(scene, size, fov) as renderer:
        technique = spec.create(renderer, **options)
        try:
            result = drive(technique, path, out_dir, measure, progress=progress,
                           summary={**(summary or {}), "gl_version": renderer.info.version})
        finally:
            technique.release()
        renderer.gl.check_error(f"run {mode}")
    return result


def technique_for(scene: Scene, mode: str | None):
    """:func:`lodsprite.techniques.for_scene`: the spec ``mode`` names for ``scene``."""
    from lodsprite import techniques

    return techniques.for_scene(scene, mode)


def render_spec(spec: str, out_dir: Path, mode: str | None = None,
                options: Mapping[str, Any] | None = None, path: str | None = None,
                frames: int | None = None, size: tuple[int, int] = (512, 512),
                measure: Measure | None = None, progress: Progress | None = None) -> dict:
    """``lodsprite render --scene SPEC`` for any scene kind (:func:`lodsprite.scene.
    open_scene`: ``crowd[:OBJECTS[:TREES]]``, a lumigraph folder, a plug-in's): the
    technique ``mode`` (default: the scene's) with ``options`` (those it declares) along
    ``path`` (default: the scene's own, e.g. a crowd's ``walk``, a lumigraph's ``arc``) of
    ``frames``, through :func:`run_scene`; writes the run to ``out_dir``, returns the
    summary."""
    from lodsprite.files import writable_folder
    from lodsprite.techniques.scenes import open_scene

    writable_folder(out_dir)  # before the scene is opened
    if measure is not None:
        measure.check()  # before the scene is opened
    scene = open_scene(spec, light=True, **(options or {}))
    technique = technique_for(scene, mode)
    mine = {o.name for o in technique.options}
    name = path or scene.default_path or "chen1999"
    cam = scene.path(name, frames)
    result = run_scene(scene, technique.name,
                       {k: v for k, v in (options or {}).items() if k in mine}, cam,
                       size, Path(out_dir), measure, progress=progress,
                       summary={"mode": technique.short, "technique": technique.name,
                                "scene": spec, "path": name, "size": list(size)})
    return result.summary


def run_technique(renderer, path: CameraPath, config: RenderConfig,
                  progress: Progress | None = None, on_image=None,
                  keyframes: list | None = None, image_frames=None,
                  reference: Callable | None = None) -> RunResult:
    """The registry's technique for ``config`` on ``renderer`` (a
    :class:`~lodsprite.api.Renderer`) along ``path``, through :func:`drive` without
    writing (``on_image`` for the replayed frames ``image_frames``, default all; quality
    against ``reference``, default the technique's); ``keyframes``, if given, is extended
    with a LOD-sprite run's keyframe log (whose rows get ``key_x, key_y, key_z``)."""
    from lodsprite import techniques

    spec = techniques.get(config.technique)
    technique = spec.create(renderer, **spec.bind(config.technique_options()))
    try:
        result = drive(technique, path, None, Measure.of(config), reference=reference,
                       progress=progress, on_image=on_image, image_frames=image_frames)
        if keyframes is not None and hasattr(technique, "keyframe_log"):
            keyframes.extend(technique.keyframe_log)
        return result
    finally:
        technique.release()


def sprite_frames(pr: TerrainGL, path: CameraPath, config: RenderConfig,
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
    """``lodsprite render``: ``config``'s scene and path (:func:`~lodsprite.runconfig.
    prepare`) drawn by its technique through :func:`run_scene`; writes ``frames.csv``,
    ``summary.json`` (and the technique's files: a LOD-sprite run's ``keyframes.json``,
    every keyframe rendered, indexed by the ``keyframe`` column) and optionally PNG frames
    and an MP4 ``video`` (with ``config.ground_truth`` each video frame is full
    resolution | technique | difference) to ``out_dir`` (checked first:
    :func:`~lodsprite.files.writable_folder`); returns the summary."""
    from lodsprite.files import writable_folder
    from lodsprite.report.video import check_video_path

    writable_folder(out_dir)
    if video is not None:
        check_video_path(video)
    config = config.resolved()
    scene, path = prepare(config)
    from lodsprite import techniques

    summary = {"mode": config.mode, "terrain": config.terrain, "texture": config.texture,
               "path": config.path, "size": list(config.size), "grid": scene.hf.quads,
               "exaggeration": config.exaggeration, "technique": config.technique,
               "config": config.flat()}
    options = techniques.get(config.technique).bind(config.technique_options())
    result = run_scene(scene, config.technique, options, path, config.size, Path(out_dir),
                       Measure.of(config, video), fov_y_deg=field_of_view(config, path),
                       progress=progress, summary=summary)
    return result.summary


__all__ = ["Measure", "RenderConfig", "render_modes", "drive", "field_of_view",
           "keyframe_records", "parse_size", "peak_rss_mb", "prepare", "render_path",
           "render_spec", "run_scene", "run_technique", "sprite_frames", "technique_for",
           "timing_summary"]
