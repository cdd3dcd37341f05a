"""Rendering a camera path with timings: the engine behind ``lodsprite render``.

:func:`render_path` makes the registry's technique for the config
(:mod:`lodsprite.techniques`: ``full``, ``lod``, ``sprite``, ``adaptive``, and
``sprite-adaptive`` for ``--mode sprite --key-sse``) and runs it through the one harness
(:func:`lodsprite.harness.run_path`): one untimed warm-up, per-frame time with
``ctx.finish()`` inside the clock, nothing read back in the timed loop; saved frames,
video and quality (``--ground-truth``, every technique) come from an untimed replay of the
same decisions.  What a run renders (:class:`RenderConfig`, :func:`prepare`) is in
:mod:`lodsprite.runconfig`.  The distributed mode is not core: the command line hands it to
:func:`lodsprite.distributed.run.render_distributed` (this module never imports
:mod:`lodsprite.distributed`).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from lodsprite.files import write_json, write_png
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.harness import RunResult, run_path, scene_reference, timing_summary, write_run
from lodsprite.paths import CameraPath
from lodsprite.progress import Progress
from lodsprite.runconfig import (  # noqa: F401  (their public home was here)
    RenderConfig,
    field_of_view,
    parse_size,
    prepare,
    render_modes,
)
from lodsprite.workers import peak_rss_mb


def __getattr__(name: str):
    if name == "MODES":  # the registry's now (plug-ins are discovered when first asked)
        return render_modes()
    raise AttributeError(name)


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
