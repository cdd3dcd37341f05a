"""The one harness: a technique along a camera path on a surface, timed honestly, with
quality measured in a separate untimed replay.

:func:`run_path` does, for every technique alike:

1. one warm-up (:meth:`~lodsprite.techniques.Technique.warm_up`) at the first
   viewpoint, then ``ctx.finish()``: the same contract for every technique (shaders
   compiled, the first view's data resident: an adaptive renderer's tiles streamed in, a
   LOD-sprite keyframe drawn, a lumigraph's first nodes decoded), so that no technique's
   timed run pays a cold start another's does not.  Its time is measured on its own
   (``first_frame_ms`` in the summary, milliseconds, ``ctx.finish()`` included) and is in
   none of the run's other figures (``total_s``, the percentiles);
2. the timed loop: per frame, :meth:`~lodsprite.techniques.Technique.frame` then
   ``ctx.finish()`` before the clock stops; the frame's decision recorded
   (:meth:`~lodsprite.techniques.Technique.decision`); nothing read back, nothing written;
3. with ``ground_truth`` (or an ``on_image`` callback: saved frames, a video), a replay of
   the same decisions (:meth:`~lodsprite.techniques.Technique.replay`), untimed, each image
   compared with a reference from an independent code path (default: the technique's
   own, else level 0 band-limited, :func:`scene_reference`) every
   ``quality_stride``-th frame: ``rmse, psnr, ssim`` (and ``flip``) per frame, and
   ``flicker`` on consecutive frames (with a stride, the frame after each judged one is
   replayed and judged for it too), their means in the summary.

:func:`write_run` writes ``frames.csv`` (core columns :data:`CORE_COLUMNS`, then the
technique's own, then quality) and ``summary.json`` (core keys :data:`CORE_KEYS`, then
the technique's own), atomically.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.record import (  # the record's rows and summary, here too
    CORE_COLUMNS,
    CORE_KEYS,
    Frame,
    Reference,
    RunResult,
    frame_rows,
    frames_summary,
    timing_summary,
)
from lodsprite.techniques.base import Technique

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.paths import CameraPath
    from lodsprite.progress import Progress

QUALITY_COLUMNS = ("rmse", "psnr", "ssim", "flip", "flicker")

#: ``on_image(frame, image, reference)``: a replayed frame's image ``(h, w, 3) uint8`` and
#: its reference (None without ``ground_truth`` or off the quality stride).
ImageCallback = Callable[[int, np.ndarray, "np.ndarray | None"], None]
def full_resolution(renderer) -> Reference:
    """The renderer's own full-resolution terrain at a viewpoint, one sample a pixel: not
    a reference (it is drawn by the renderers under test), kept for the comparisons that
    ask for it by name."""
    def reference(viewpoint) -> np.ndarray:
        renderer.render(viewpoint, None)
        return renderer.read_color()

    return reference


def level_zero_reference(gl, scene, size: tuple[int, int], fov_y_deg: float,
                         shading: str = "auto", samples: int | None = None):
    """The one reference of a terrain's quality figures: a band-limited
    :class:`~lodsprite.gl.reference.LevelZeroReference` over level 0 of the store
    ``scene`` names (exaggerated as the scene), or over the scene's in-memory field at its
    full grid, frames of ``size = (w, h)`` pixels and ``fov_y_deg`` degrees, ``samples``
    a pixel side (default :data:`~lodsprite.gl.reference.SAMPLES`), coloured by
    ``shading`` as the run (resolved for the scene); None for a scene without terrain.
    Release it after use."""
    from lodsprite.gl.reference import SAMPLES, LevelZeroReference
    from lodsprite.techniques.adaptive import scene_pyramid
    from lodsprite.techniques.terrain import resolve_shading
    from lodsprite.terrain.store import is_store

    if scene.hf is None:
        return None
    shading = resolve_shading(scene, shading)
    texture = None
    if shading == "texture":  # a scene loaded without one draws the renderers' plain grey
        texture = scene.texture if scene.texture is not None else np.full((2, 2, 3), 160,
                                                                          np.uint8)
    field = (scene_pyramid(scene) if scene.terrain_spec and is_store(scene.terrain_spec)
             else scene.hf)
    imagery = None
    samples = SAMPLES if samples is None else samples
    if shading == "texture" and is_store(scene.terrain_spec):  # texels: twice the samples'
        side = min(gl.info.max_texture_size, 2 * samples * max(size))
        imagery = imagery_windows(field, scene.texture_spec, side)
    return LevelZeroReference(gl, field, size, fov_y_deg, shading, texture,
                              samples=samples, imagery=imagery)


def imagery_windows(store, texture_spec: str, max_side: int):
    """For a reference drawn by windows of a store whose texture is its imagery (the
    default texture, ``imagery`` or ``imagery+hillshade``): ``(r0, r1, c0, c1) -> (H, W, 3)
    uint8``, the imagery over those level-0 samples read from the store at level 0's
    detail (at most ``max_side`` texels a side), draped as the scene's texture is
    (:func:`~lodsprite.terrain.textures.drape` over the window's heights); None for any
    other texture."""
    from lodsprite.terrain.heightfield import HeightField
    from lodsprite.terrain.textures import IMAGERY_SPECS, drape

    name = (texture_spec or "terrain").strip().lower()
    if store.imagery is None or name not in ("terrain", *IMAGERY_SPECS):
        return None
    mm = store.minmax(0)
    span = (float(np.nanmin(mm[..., 0])), float(np.nanmax(mm[..., 1])))  # level 0's ramp

    def window(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        rgba = store.imagery_window(r0, r1, c0, c1, max_side)
        h = store.read(0, r0, r1, c0, c1)
        h = np.where(np.isfinite(h), h, np.float32(span[0]))  # nodata: the lowest ground
        hf = HeightField(h, store.dx, store.dy, "window")
        return drape(rgba, hf, name == "imagery+hillshade", span)

    return window


@contextmanager
def scene_reference(renderer, shading: str = "auto", samples: int | None = None
                    ) -> Iterator[Reference]:
    """The reference of a run on ``renderer`` (a :class:`~lodsprite.api.Renderer`) coloured
    by ``shading``: level 0 band-limited (:func:`level_zero_reference`: a store's whole up
    to 4097 samples a side, the part in view beyond, in patches; an in-memory field at its
    full grid), drawn by its own code path, never by a renderer under test.  Its GPU
    objects are released on leaving.  With ``LODSPRITE_REFERENCE_CACHE`` set, frames are
    read from and kept in that folder (:mod:`lodsprite.reference_cache`)."""
    from lodsprite.reference_cache import cache_folder, cached_images

    ref = level_zero_reference(renderer.gl, renderer.scene, renderer.size,
                               renderer.fov_y_deg, shading, samples)
    if ref is None:
        raise InputError("a scene without terrain has no level-0 reference")
    folder = cache_folder()
    try:
        yield ref.image if folder is None else cached_images(ref, folder)
    finally:
        ref.release()


def technique_reference(technique: Technique, path: CameraPath
                        ) -> AbstractContextManager[Callable]:
    """The ground truth of ``technique``'s run along ``path``: its own
    :meth:`~lodsprite.techniques.Technique.reference`, else the scene's terrain at full
    resolution coloured by its :attr:`~lodsprite.techniques.Technique.shading`
    (:func:`scene_reference`); a technique with neither (its scene has
    no terrain) is an :class:`~lodsprite.errors.InputError`, before anything runs."""
    own = technique.reference(path)
    if own is not None:
        return own
    if technique.renderer.scene.hf is None:
        raise InputError(f"{technique.name} gives no ground truth to compare with "
                         f"(its scene has no terrain, and it names no reference)")
    return scene_reference(technique.renderer, technique.shading)


def quality_summary(rows: list[dict]) -> dict[str, float]:
    """Means of the quality columns over the rows that have them: ``rmse_mean``,
    ``ssim_mean`` (and ``flip_mean``, ``flicker_mean`` over the frames judged right after
    a judged one), and ``psnr_mean`` from the mean squared error (an image equal to its
    reference has an infinite PSNR); a technique's extra columns (``rmse_lod`` ...) the
    same way (``rmse_lod_mean`` ...); with a plain coarse level beside it, ``rmse_ratio =
    rmse_mean / rmse_lod_mean``."""
    flickers = [r["flicker"] for r in rows if "flicker" in r]
    rows = [r for r in rows if "rmse" in r]
    if not rows:
        return {}
    out: dict[str, float] = {"quality_frames": len(rows)}
    if flickers:  # judged on consecutive frames, those of the quality stride's or not
        out["flicker_mean"] = float(np.mean(flickers))
    keys = dict.fromkeys(k for r in rows for k in r)
    for key in keys:
        if not key.startswith(QUALITY_COLUMNS) or key.startswith(("psnr", "flicker")):
            continue
        v = np.array([r[key] for r in rows if key in r], dtype=np.float64)
        out[f"{key}_mean"] = float(v.mean())
        if key.startswith("rmse"):
            mse = float(np.mean(v ** 2))
            out[f"psnr{key[4:]}_mean"] = (float("inf") if mse == 0
                                          else float(10 * np.log10(255.0 ** 2 / mse)))
    if "rmse_lod_mean" in out:  # the technique against its plain coarse level
        out["rmse_ratio"] = (out["rmse_mean"] / out["rmse_lod_mean"]
                             if out["rmse_lod_mean"] > 0 else float("nan"))
    return out


def _quality(image: np.ndarray, truth: np.ndarray, flip: bool) -> dict[str, float]:
    from lodsprite import metrics

    q = {"rmse": metrics.rmse(image, truth), "psnr": metrics.psnr(image, truth),
         "ssim": metrics.ssim(image, truth)}
    if flip:
        q["flip"] = metrics.flip(image, truth)
    return q


def warm_up(technique: Technique, viewpoint, finish: Callable[[], None]) -> float:
    """The technique's warm-up at ``viewpoint`` (:meth:`~lodsprite.techniques.Technique.
    warm_up`), ``finish()`` included; its time in milliseconds (``first_frame_ms``)."""
    t0 = time.perf_counter()
    technique.warm_up(viewpoint)
    finish()
    return (time.perf_counter() - t0) * 1e3


def _timed(technique: Technique, path: CameraPath, finish: Callable[[], None],
           progress: Progress | None) -> tuple[list[Frame], list[dict], bool]:
    """The timed loop; stopped by Ctrl-C, it keeps the frames finished so far."""
    frames, decisions = [], []
    n = len(path.viewpoints)
    try:
        for i, vp in enumerate(path.viewpoints):
            t0 = time.perf_counter()
            f = technique.frame(vp)
            finish()
            frames.append(replace(f, ms=(time.perf_counter() - t0) * 1e3))
            decisions.append(technique.decision())
            if progress:
                progress(i + 1, n)
    except KeyboardInterrupt:
        if not frames:
            raise
        return frames, decisions, True
    return frames, decisions, False


def replay_frames(technique: Technique, drawn: Sequence[Viewpoint],
                  judged: Sequence[Viewpoint], decisions: list[dict], rows: list[dict],
                  reference: Reference | None, stride: int, flip: bool,
                  on_image: ImageCallback | None, image_frames) -> None:
    """The untimed replay: frame ``i``'s recorded decision drawn again at ``drawn[i]``
    (the viewpoint it was drawn for) and, every ``stride``-th frame, compared with the
    reference at ``judged[i]`` (the viewpoint it is judged at); its quality columns go
    into ``rows[i]``.  With a stride the frame after each judged one is replayed and
    judged too, for its ``flicker`` only (consecutive frames: stride 1 has them all).  A
    technique's baselines (:meth:`~lodsprite.techniques.Technique.quality_extra`) are
    drawn at ``drawn[i]`` too, so that they carry the same latency."""
    from lodsprite.metrics import flicker

    last: tuple[int, np.ndarray, np.ndarray] | None = None  # the last judged frame
    for i, (vp, at, d) in enumerate(zip(drawn, judged, decisions, strict=True)):
        measured = reference is not None and i % stride == 0
        follows = reference is not None and stride > 1 and i % stride == 1  # its flicker
        shown = on_image is not None and (image_frames is None or i in image_frames)
        if not (measured or follows or shown):
            continue
        image = technique.replay(vp, d)
        truth = None
        if measured or follows:
            truth = reference(at)
            if last is not None and last[0] == i - 1:
                rows[i]["flicker"] = flicker(image, last[1], truth, last[2])
            last = (i, np.array(image), truth)
        if measured:
            rows[i].update(_quality(image, truth, flip))
            rows[i].update(technique.quality_extra(vp, d, truth))
        if shown:
            on_image(i, image, truth if measured else None)


def run_path(technique: Technique, path: CameraPath, *, finish: Callable[[], None] | None = None,
             gl_renderer: str = "", progress: Progress | None = None,
             ground_truth: bool = False, reference: Reference | None = None,
             quality_stride: int = 1, flip: bool = False,
             on_image: ImageCallback | None = None,
             image_frames: Collection[int] | None = None) -> RunResult:
    """Run ``technique`` along ``path`` (module docstring).  ``finish``: the GL context's
    ``finish`` (default: the technique's renderer's); ``gl_renderer``: the driver's name for
    the summary (default: the renderer's); ``reference``: ``viewpoint -> image`` (default:
    :func:`technique_reference`); ``on_image`` is called for the replayed frames
    ``image_frames`` (default: all).  Returns the frames, rows and summary (not written)."""
    if quality_stride < 1:
        raise InputError(f"quality stride must be >= 1, got {quality_stride}")
    if len(path.viewpoints) < 1:
        raise InputError("a run needs a path of at least one viewpoint")
    renderer = technique.renderer
    finish = finish or renderer.gl.finish
    n = len(path.viewpoints)
    planned = set(range(0, n, quality_stride)) if ground_truth else set()
    if quality_stride > 1:  # and the frame after each, for its flicker
        planned |= {i + 1 for i in planned if i + 1 < n}
    if on_image is not None:
        planned |= set(range(n)) if image_frames is None else set(image_frames)
    if planned and not technique.replays:
        raise InputError(f"{technique.name} cannot replay its frames: no ground truth, "
                         "saved frames or video from its runs")
    technique.plan_replay(planned)
    first_ms = warm_up(technique, path.viewpoints[0], finish)
    frames, decisions, interrupted = _timed(technique, path, finish, progress)
    own = technique.summary(frames)  # the timed run's own figures, before any replay
    rows, columns = frame_rows(frames)
    if (ground_truth or on_image) and not interrupted:
        with ExitStack() as stack:
            if ground_truth and reference is None:
                reference = stack.enter_context(technique_reference(technique, path))
            replay_frames(technique, path.viewpoints, path.viewpoints, decisions, rows,
                          reference if ground_truth else None, quality_stride, flip,
                          on_image, image_frames)
        columns += [c for c in quality_columns(rows) if c not in columns]
    summary = {**frames_summary(frames, technique.name, gl_renderer or (
        renderer.info.renderer if renderer else ""), first_ms), **own, **quality_summary(rows)}
    if interrupted:
        summary["interrupted"] = True
    return RunResult(frames, decisions, rows, columns, summary, interrupted)


def quality_columns(rows: list[dict]) -> list[str]:
    """The quality columns the rows have, in the order they first appear."""
    seen: dict[str, None] = {}
    for r in rows:
        if "rmse" in r or "flicker" in r:
            seen.update(dict.fromkeys(k for k in r if k.startswith(QUALITY_COLUMNS)))
    return list(seen)


def write_run(out_dir: Path, result: RunResult, summary: dict[str, Any] | None = None) -> None:
    """``frames.csv`` and ``summary.json`` (``summary``, default the result's) into
    ``out_dir``, each written atomically."""
    from lodsprite.files import write_csv, write_json

    out_dir = Path(out_dir)
    write_csv(out_dir / "frames.csv", result.rows, result.columns)
    if result.ticks:
        write_csv(out_dir / "ticks.csv", result.ticks,
                  list(dict.fromkeys(k for t in result.ticks for k in t)))
    write_json(out_dir / "summary.json", result.summary if summary is None else summary)


__all__ = ["CORE_COLUMNS", "CORE_KEYS", "QUALITY_COLUMNS", "Frame", "RunResult", "frame_rows",
           "frames_summary", "full_resolution", "level_zero_reference", "quality_summary",
           "quality_columns", "replay_frames", "technique_reference",
           "run_path", "scene_reference", "timing_summary", "warm_up", "write_run"]
