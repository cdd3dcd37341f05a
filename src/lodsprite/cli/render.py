"""``lodsprite info``, ``render`` and ``view``: terrain rendering, batch and live.

``render`` and ``view`` take ``options`` (name -> value): :mod:`lodsprite.cli` registers
them through :func:`lodsprite.cli.options.with_technique_options`, which gives them one
``--OPTION`` per technique option of the registry."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from lodsprite.cli.common import (
    ExagOpt,
    FramesOpt,
    GridOpt,
    GroundTruthOpt,
    MaxErrorOpt,
    PaceOpt,
    QualityStrideOpt,
    TerrainOpt,
    TextureOpt,
    out,
    progress_bar,
)
from lodsprite.terrain import DEFAULT_EXAGGERATION


def info(
    dataset: Annotated[str | None, typer.Argument(
        help="a GeoTIFF, a terrain store, fractal:N or jacksboro: its CRS, extent, "
             "resolution, nodata and levels (without: this machine's GL and the "
             "techniques)")] = None,
) -> None:
    """Print a dataset's CRS, extent, resolution, nodata and levels; without one, the
    OpenGL renderer, version and maximum texture size, and the registered techniques with
    their options."""
    if dataset is not None:
        from lodsprite.terrain.describe import describe

        t = Table(show_header=False)
        for k, v in describe(dataset).items():
            t.add_row(k, v)
        out.print(t)
        return
    from lodsprite import techniques
    from lodsprite.gl.context import GLContext

    with GLContext() as ctx:
        i = ctx.info
    t = Table(show_header=False)
    for k, v in (("renderer", i.renderer), ("version", i.version), ("vendor", i.vendor),
                 ("max texture size", str(i.max_texture_size)), ("backend", ctx.backend)):
        t.add_row(k, v)
    out.print(t)
    t = Table(title="techniques (entry points of lodsprite.techniques)")
    for col in ("technique", "layers", "options", "description"):
        t.add_column(col)
    for spec in techniques.specs():
        opts = ", ".join(o.cli if o.on_command_line else o.name for o in spec.options)
        t.add_row(spec.name, " ".join(spec.layers), opts or "-", spec.description)
    out.print(t)


def _check_mode(mode: str, ground_truth: bool, video: Path | None,
                metric: str | None = None) -> bool:
    """Check ``--mode`` and what goes with it; True for ``distributed``."""
    from lodsprite.errors import InputError
    from lodsprite.run import render_modes

    modes = render_modes()
    if mode not in (*modes, "distributed"):
        raise InputError(f"unknown mode '{mode}': use one of {', '.join(modes)}, distributed")
    distributed = mode == "distributed"  # not a core mode: the distributed layer runs it
    if distributed and video is not None:
        raise InputError(f"--video is for --mode {', '.join(modes)}")
    if distributed and metric not in (None, "warp"):
        raise InputError("--metric resample is for --mode sprite: the distributed client "
                         "and server decide with the 1999 metric")
    return distributed


def _print_render(s: dict, out_dir: Path) -> None:
    t = Table(title=f"{s['frames']} frames, {s['mode']}, {s['terrain']} ({s['grid']}² grid)")
    for col in ("median ms", "mean ms", "p95 ms", "total s", "triangles"):
        t.add_column(col, justify="right")
    t.add_row(f"{s['median_ms']:.2f}", f"{s['mean_ms']:.2f}", f"{s['p95_ms']:.2f}",
              f"{s['total_s']:.2f}", f"{s['triangles_mean']:.0f}")
    out.print(t)
    from lodsprite import techniques

    for line in techniques.get(s.get("technique", s["mode"])).summary:
        try:
            out.print(line.format(**s))
        except (KeyError, ValueError, TypeError):  # a summary without those figures
            pass
    if "rmse_time_weighted" in s:  # played in time: what was on screen, tick by tick
        flip = (f", FLIP {s['flip_time_weighted']:.4f}" if "flip_time_weighted" in s
                else "")
        flicker = f", flicker {s['flicker']:.2f}" if "flicker" in s else ""
        out.print(f"RMSE over display time vs the band-limited reference (untimed replay, "
                  f"{s['ticks']} ticks): {s['rmse_time_weighted']:.2f} grey levels, worst "
                  f"second {s['rmse_worst_second']:.2f}{flicker}{flip}")
        if "cvvdp_jod" in s:
            a, b = s["cvvdp_window_s"]
            out.print(f"ColorVideoVDP ({s['cvvdp_display']}, {a:.2f}-{b:.2f} s of the "
                      f"path): {s['cvvdp_jod']:.2f} JOD (10: indistinguishable)")
    elif "rmse_mean" in s:
        plain = (f", plain {s['lod']}² {s['rmse_lod_mean']:.2f}" if "rmse_lod_mean" in s
                 else "")
        flip = f", FLIP {s['flip_mean']:.4f}" if "flip_mean" in s else ""
        flicker = f", flicker {s['flicker_mean']:.2f}" if "flicker_mean" in s else ""
        out.print(f"RMSE vs the band-limited reference (untimed replay): "
                  f"{s['rmse_mean']:.2f}{plain} grey levels, PSNR {s['psnr_mean']:.1f} dB, "
                  f"SSIM {s['ssim_mean']:.3f}{flip}{flicker}")
    out.print(f"GL: {s['gl_renderer']}   wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


def render(
    terrain: TerrainOpt = "jacksboro",
    texture: TextureOpt = "terrain",
    path: Annotated[str | None, typer.Option(
        "--path", help="chen1999 (the default) | swan2002 | flyover[:HEIGHT_M[:TRACK_M]] | "
                       "patrol[:HEIGHT_M[:TRACK_M[:PASSES]]] | bank[:HEIGHT_M[:TRACK_M]] | "
                       "weave[:HEIGHT_M[:HALF_M[:TURNS]]] | FILE.json; a --scene's own "
                       "by default (walk, arc, the file's [view] path)")] = None,
    mode: Annotated[str | None, typer.Option(
        "--mode", help="a technique of the registry (lodsprite info) that draws the "
                       "scene: full | lod | sprite (adaptive keyframes on a store or with "
                       "--key-sse) | adaptive (view-dependent, --sse) | distributed (starts "
                       "a local LOD server) | a plug-in's (default full); with --scene "
                       "FILE.toml the terrain's (default the file's [terrain] mode, else "
                       "adaptive); with a crowd or lumigraph --scene its techniques "
                       "(default manager, critical)")] = None,
    size: Annotated[str | None, typer.Option(
        "--size", help="image size WxH in pixels (default 512x512; with --scene the "
                       "file's [view] size if it gives one)")] = None,
    frames: FramesOpt = None,
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out"),
    save_frames: Annotated[bool, typer.Option("--save-frames", help="write PNG frames")] = False,
    video: Annotated[Path | None, typer.Option(
        "--video", help="write the frames to an MP4 file (with --ground-truth: full | "
                        "LOD-sprite | difference side by side)")] = None,
    grid: GridOpt = None,
    exaggeration: ExagOpt = DEFAULT_EXAGGERATION,
    ground_truth: GroundTruthOpt = False,
    quality_stride: QualityStrideOpt = 1,
    flip: Annotated[bool, typer.Option(
        "--flip", help="with --ground-truth: FLIP per frame too")] = False,
    pace: PaceOpt = "needed",
    max_error: MaxErrorOpt = None,
    play: Annotated[bool, typer.Option(
        "--play", help="play the path in time: the camera moves at the path's speed, "
                       "frames drawn as often as the technique can (or --display-fps), each "
                       "judged at its display time's viewpoint (always so with --keyframes "
                       "worker)")] = False,
    display_fps: Annotated[float | None, typer.Option(
        "--display-fps", help="with --play or --keyframes worker: draw at most this many "
                              "frames a second (default: as often as it can)")] = None,
    vdp: Annotated[float | None, typer.Option(
        "--vdp", help="with --play and --ground-truth: ColorVideoVDP (JOD) over this many "
                      "seconds of the run, centred (needs the vdp extra)")] = None,
    scene: Annotated[str | None, typer.Option(
        "--scene", help="a scene instead of --terrain: a scene file (TOML: its terrain "
                        "drawn by --mode, objects and light fields composited by depth "
                        "along its [view] path), crowd[:OBJECTS[:TREES]] (along walk), a "
                        "lumigraph folder (along arc), a plug-in's kind")] = None,
    target_fps: Annotated[float | None, typer.Option(
        "--target-fps", help="with --scene: one frame budget over the layers "
                             "(the scheduler) at this frame rate")] = None,
    options: dict | None = None,
) -> None:
    """Render a camera path; write DIR/frames.csv and DIR/summary.json (and PNG frames)."""
    from lodsprite import RenderConfig, render_path
    from lodsprite.driver import Measure
    from lodsprite.files import writable_folder
    from lodsprite.run import parse_size
    from lodsprite.scene.kinds import scene_kind

    writable_folder(out_dir)  # before any work: one line if it cannot be

    options = options or {}
    if scene is not None and scene_kind(scene) is None:  # a terrain, as --terrain
        terrain, scene = scene, None
    if scene is not None and scene_kind(scene) != "scene-file":
        _render_spec(scene, out_dir, mode, path, frames, size, target_fps, options,
                     Measure(ground_truth, quality_stride, flip, save_frames, video=video))
        return
    if scene is not None or target_fps is not None:
        _render_scene(scene, out_dir, None if size is None else parse_size(size), frames,
                      mode, target_fps, ground_truth, flip, path,
                      Measure(ground_truth, quality_stride, flip, save_frames, video=video),
                      **options)
        return

    mode, path = mode or "full", path or "chen1999"
    distributed = _check_mode(mode, ground_truth, video, options.get("metric"))
    config = RenderConfig(terrain=terrain, texture=texture, path=path,
                          mode="sprite" if distributed else mode,
                          size=parse_size(size or "512x512"), frames=frames, grid=grid,
                          exaggeration=exaggeration, save_frames=save_frames,
                          ground_truth=ground_truth, quality_stride=quality_stride,
                          flip=flip, display_fps=display_fps, play=play, vdp_seconds=vdp,
                          options=options)
    with progress_bar(f"render {mode}") as update:
        if distributed:
            from lodsprite.distributed.run import parse_max_error, render_distributed

            s = render_distributed(config, out_dir, update, pace=pace,
                                   max_error=parse_max_error(max_error))
        else:
            s = render_path(config, out_dir, update, video)
    _print_render(s, out_dir)


def _render_spec(scene: str, out_dir: Path, mode: str | None, path: str | None,
                 frames: int | None, size: str | None, target_fps: float | None,
                 options: dict, measure) -> None:
    """``render --scene SPEC`` for a scene kind (a crowd, a lumigraph folder, a plug-in's):
    the batch driver's :func:`~lodsprite.run.render_spec`."""
    from lodsprite.run import parse_size, render_spec

    if target_fps is not None:  # a crowd technique's LOD feedback
        options = {**options, "target_fps": target_fps}
    with progress_bar(f"render {scene}") as update:
        s = render_spec(scene, out_dir, mode, options, path, frames,
                        parse_size(size or "512x512"), measure, update)
    quality = (f"; RMSE {s['rmse_mean']:.2f}, PSNR {s['psnr_mean']:.1f} dB, SSIM "
               f"{s['ssim_mean']:.3f}" if "rmse_mean" in s else "")
    out.print(f"{s['frames']} frames of {scene} ({s['mode']}): median {s['median_ms']:.2f} "
              f"ms, p99 {s['p99_ms']:.2f} ms{quality}; wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


def _render_scene(scene: str | None, out_dir: Path, size: tuple[int, int] | None,
                  frames: int | None, mode: str | None, target_fps: float | None,
                  ground_truth: bool, flip: bool, path: str | None = None,
                  measure=None, **options) -> None:
    """``render --scene``: the layered technique over a scene file's world (``options``:
    the scene technique's and its terrain technique's)."""
    from lodsprite import techniques
    from lodsprite.errors import InputError
    from lodsprite.layered.technique import render_scene

    if scene is None:
        raise InputError("--target-fps is for --scene: a scene file (its frame budget) or "
                         "a crowd (its LOD feedback)")
    terrain = techniques.get(mode).options if mode else techniques.all_options(("terrain",))
    takes = {o.name for o in techniques.get("scene").options} | {
        o if isinstance(o, str) else o.name for o in terrain}
    with progress_bar("render scene") as update:
        s = render_scene(scene, out_dir, size, frames, mode, target_fps, ground_truth,
                         flip, path, progress=update, measure=measure,
                         **{k: v for k, v in options.items() if k in takes})
    shares = ", ".join(f"{k[6:]} {v:.0%}" for k, v in s.items() if k.startswith("share_"))
    out.print(f"{s['frames']} frames of {scene}: median {s['median_ms']:.1f} ms, p99 "
              f"{s['p99_ms']:.1f} ms; shares: {shares}; wrote {out_dir}")


def view(
    terrain: Annotated[str, typer.Argument(
        help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy) | a lumigraph "
             "folder | crowd[:OBJECTS[:TREES]] | a scene file")] = "jacksboro",
    texture: TextureOpt = "terrain",
    grid: GridOpt = None,
    mode: Annotated[str | None, typer.Option(
        "--mode", help="a technique of the registry that draws the scene's layers "
                       "(lodsprite info); terrain: sprite (default; on a store "
                       "sprite-adaptive), full, lod, adaptive, distributed (needs "
                       "--server); lumigraph: critical (default) ...; crowd: manager "
                       "(default) ...; keys 1-9 switch")] = None,
    size: Annotated[str | None, typer.Option(
        "--size", help="window size WxH (default 1024x768; a scene file's [view] size if it "
                       "gives one)")] = None,
    fps: Annotated[float, typer.Option(
        "--fps", help="frame rate cap (0: none); the keyframe worker uses the time left")] = 60,
    inline: Annotated[bool, typer.Option(
        "--inline-keyframes", help="sprite mode: render keyframes in the frame that needs "
                                   "them (the 1999 algorithm) instead of in a worker "
                                   "process")] = False,
    play: Annotated[str | None, typer.Option(
        "--play", help="play a path (chen1999 | swan2002 | FILE.json; lumigraph: arc | "
                       "FILE.json; crowd: walk | FILE.json) instead of flying")] = None,
    frames: FramesOpt = None,
    screenshots: Annotated[Path | None, typer.Option(
        "--screenshots", help="folder for screenshots (key p; with --play every K "
                              "frames)")] = None,
    every: Annotated[int, typer.Option("--every", help="with --play: screenshot every K "
                                                       "frames")] = 1,
    exit_: Annotated[bool, typer.Option("--exit", help="with --play: quit at the end")] = False,
    out_dir: Annotated[Path | None, typer.Option(
        "--out", help="with --play: write DIR/frames.csv and DIR/summary.json")] = None,
    record: Annotated[Path | None, typer.Option(
        "--record", help="save the flight as a path FILE.json for render and "
                         "reproduce")] = None,
    target_fps: Annotated[float | None, typer.Option(
        "--target-fps", help="crowd: bend the LODs to hold this frame rate ([ ] step it)")
    ] = None,
    options: dict | None = None,
) -> None:
    """Fly through a terrain with live LOD-sprite, or round a lumigraph (WASD/QE, mouse, tab
    orbit)."""
    from lodsprite.files import writable_folder
    from lodsprite.run import parse_size
    from lodsprite.viewer.app import ViewOptions
    from lodsprite.viewer.app import view as run_view

    if out_dir is not None:
        writable_folder(out_dir)  # before any work: one line if it cannot be

    opts = ViewOptions(terrain=terrain, texture=texture, grid=grid, mode=mode,
                       size=None if size is None else parse_size(size),
                       fps=fps, threaded=not inline,
                       play=play, frames=frames, screenshots=screenshots, every=every,
                       exit=exit_, out=out_dir, record=record,
                       target_fps=target_fps, options=options or {})
    s = run_view(opts)
    if s:
        out.print(f"{s['frames']} frames, {s['mode']}: median {s['median_ms']:.2f} ms, "
                  f"p99 {s['p99_ms']:.2f} ms, mean {s['mean_ms']:.2f} ms; keyframes "
                  f"{s['keyframes']}; GL {s['gl_renderer']}")
    if out_dir is not None and s:
        out.print(f"wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")
    if record is not None:
        out.print(f"wrote {record}")
