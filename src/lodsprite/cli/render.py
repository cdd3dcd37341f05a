"""``lodsprite info``, ``render`` and ``view``: terrain rendering, batch and live."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from lodsprite.cli.common import (
    BorderOpt,
    CachePolicyOpt,
    EpsOpt,
    ExagOpt,
    FramesOpt,
    GridOpt,
    GroundTruthOpt,
    GuardOpt,
    MaxErrorOpt,
    PaceOpt,
    PathOpt,
    QualityStrideOpt,
    TerrainOpt,
    TextureOpt,
    VisOpt,
    out,
    progress_bar,
)
from lodsprite.terrain import DEFAULT_EXAGGERATION

ShadingOpt = Annotated[str, typer.Option(
    "--shading", help="terrain colour: auto (heights on a store, else the texture) | "
                      "texture | heights (height ramp and sun, normals per pixel)")]


def info() -> None:
    """Print the OpenGL renderer, version and maximum texture size."""
    from lodsprite.gl.context import GLContext

    with GLContext() as ctx:
        i = ctx.info
    t = Table(show_header=False)
    for k, v in (("renderer", i.renderer), ("version", i.version), ("vendor", i.vendor),
                 ("max texture size", str(i.max_texture_size)), ("backend", ctx.backend)):
        t.add_row(k, v)
    out.print(t)


def _check_mode(mode: str, ground_truth: bool, video: Path | None,
                metric: str | None = None) -> bool:
    """Check ``--mode`` and what goes with it; True for ``distributed``."""
    from lodsprite.errors import InputError
    from lodsprite.run import MODES

    if mode not in (*MODES, "distributed"):
        raise InputError(f"unknown mode '{mode}': use one of {', '.join(MODES)}, distributed")
    distributed = mode == "distributed"  # not a core mode: the distributed layer runs it
    if distributed and video is not None:
        raise InputError(f"--video is for --mode {', '.join(MODES)}")
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
    if s["mode"] == "distributed":
        out.print(f"keyframes received: {s['keyframes_received']}, σ {s['std_ms']:.2f} ms, "
                  f"p99 {s['p99_ms']:.2f} ms; server δt {s['delta_t_ms_mean']:.0f} ms, "
                  f"keyframe render {s['render_ms_mean']:.0f} ms")
    if s["mode"] == "adaptive":
        out.print(f"{s['sse']:g} px: first frame {s['first_frame_s']:.2f} s; tiles resident "
                  f"{s['tiles_resident']}, loaded {s['tiles_loaded']}, evicted "
                  f"{s['tiles_evicted']}, unreadable {s['tiles_bad']}")
    if s["mode"] == "sprite":
        out.print(f"keyframes: {s['keyframes']} of {s['frames']}; mean ms keyframe "
                  f"{s['mean_ms_keyframe']:.1f}, first spriteframe "
                  f"{s['mean_ms_first_sprite']:.1f}, spriteframe {s['mean_ms_sprite']:.1f}")
    if "rmse_mean" in s:
        plain = (f", plain {s['lod']}² {s['rmse_lod_mean']:.2f}" if "rmse_lod_mean" in s
                 else "")
        flip = f", FLIP {s['flip_mean']:.4f}" if "flip_mean" in s else ""
        out.print(f"RMSE vs full resolution (untimed replay): {s['rmse_mean']:.2f}{plain} "
                  f"grey levels, PSNR {s['psnr_mean']:.1f} dB, SSIM {s['ssim_mean']:.3f}{flip}")
    out.print(f"GL: {s['gl_renderer']}   wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


_DEF = " (default: the terrain's, lodsprite.techniques.defaults)"
TilesOpt = Annotated[int | None, typer.Option(
    "--tiles", help="sprite: refresh keyframes tile by tile on an N x N grid of screen "
                    "tiles (1: whole keyframes; inline keyframes only)" + _DEF)]
TileBudgetOpt = Annotated[float | None, typer.Option(
    "--tile-budget-ms", help="sprite with --tiles > 1: tile work per frame (ms); a tile "
                             "over 2 epsilon is rendered even beyond it" + _DEF)]
TerrainLodOpt = Annotated[int | None, typer.Option(
    "--lod", help="coarse level: N x N quads over the terrain" + _DEF)]
TerrainMetricOpt = Annotated[str | None, typer.Option(
    "--metric", help="sprite mode: the keyframe error metric: warp (Chen et al. Eq. 1-2) | "
                     "resample (adds the keyframe image's resampling error)" + _DEF)]
TerrainCacheMbOpt = Annotated[float | None, typer.Option(
    "--cache-mb", help="sprite mode: keep keyframes in a GPU cache of this many MB and show "
                       "the one with the lowest error (0: off, the 1999 algorithm)" + _DEF)]


def render(
    terrain: TerrainOpt = "jacksboro",
    texture: TextureOpt = "terrain",
    path: PathOpt = "chen1999",
    mode: Annotated[str, typer.Option(
        "--mode", help="a technique of the registry: full | lod | sprite (adaptive "
                       "keyframes on a store or with --key-sse) | adaptive (view-dependent, "
                       "--sse) | distributed (starts a local LOD server)")] = "full",
    lod: TerrainLodOpt = None,
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
    epsilon: EpsOpt = 1.0,
    ground_truth: GroundTruthOpt = False,
    quality_stride: QualityStrideOpt = 1,
    flip: Annotated[bool, typer.Option(
        "--flip", help="with --ground-truth: FLIP per frame too")] = False,
    visibility: VisOpt = "coarse",
    border: BorderOpt = True,
    guard: GuardOpt = 32,
    metric: TerrainMetricOpt = None,
    pace: PaceOpt = "needed",
    max_error: MaxErrorOpt = None,
    sse: Annotated[float, typer.Option(
        "--sse", help="adaptive: screen-space error tolerance in pixels")] = 1.0,
    key_sse: Annotated[float | None, typer.Option(
        "--key-sse", help="sprite: render keyframes with the adaptive renderer at this "
                          "tolerance in pixels (default: the terrain's, 0.5 on a store, "
                          "none in memory; lodsprite.techniques.defaults)")] = None,
    proxy_sse: Annotated[float | None, typer.Option(
        "--proxy-sse", help="sprite with --key-sse: spriteframes draw the adaptive mesh at "
                            "this tolerance (pixels, e.g. 8-16), selected at each keyframe, "
                            "instead of the uniform --lod level" + _DEF)] = None,
    gpu_mb: Annotated[float, typer.Option(
        "--gpu-mb", help="adaptive: GPU tile cache budget (MB)")] = 256.0,
    host_mb: Annotated[float, typer.Option(
        "--host-mb", help="adaptive: host tile cache budget (MB)")] = 512.0,
    shading: ShadingOpt = "auto",
    tiles: TilesOpt = None,
    tile_budget_ms: TileBudgetOpt = None,
    cache_mb: TerrainCacheMbOpt = None,
    cache_policy: CachePolicyOpt = "lru",
    scene: Annotated[Path | None, typer.Option(
        "--scene", help="a scene file (TOML): its terrain (drawn by --mode), objects and "
                        "light fields composited by depth along its [view] path")] = None,
    target_fps: Annotated[float | None, typer.Option(
        "--target-fps", help="with --scene: one frame budget over the layers "
                             "(the scheduler) at this frame rate")] = None,
) -> None:
    """Render a camera path; write DIR/frames.csv and DIR/summary.json (and PNG frames)."""
    from lodsprite import RenderConfig, render_path
    from lodsprite.run import parse_size

    if scene is not None or target_fps is not None:
        _render_scene(scene, out_dir, None if size is None else parse_size(size), frames,
                      mode, target_fps, ground_truth, flip, epsilon=epsilon, sse=sse, lod=lod)
        return

    distributed = _check_mode(mode, ground_truth, video, metric)
    config = RenderConfig(terrain=terrain, texture=texture, path=path,
                          mode="sprite" if distributed else mode, lod=lod,
                          size=parse_size(size or "512x512"), frames=frames, grid=grid,
                          exaggeration=exaggeration, save_frames=save_frames, epsilon=epsilon,
                          ground_truth=ground_truth, quality_stride=quality_stride,
                          visibility=visibility, border=border,
                          guard_px=guard, sse=sse, gpu_mb=gpu_mb, host_mb=host_mb,
                          key_sse=key_sse, proxy_sse=proxy_sse, flip=flip, shading=shading,
                          tiles=tiles, tile_budget_ms=tile_budget_ms, cache_mb=cache_mb,
                          cache_policy=cache_policy, metric=metric)
    with progress_bar(f"render {mode}") as update:
        if distributed:
            from lodsprite.distributed.run import parse_max_error, render_distributed

            s = render_distributed(config, out_dir, update, pace=pace,
                                   max_error=parse_max_error(max_error))
        else:
            s = render_path(config, out_dir, update, video)
    _print_render(s, out_dir)


def _render_scene(scene: Path | None, out_dir: Path, size: tuple[int, int] | None,
                  frames: int | None, mode: str, target_fps: float | None,
                  ground_truth: bool, flip: bool, **options) -> None:
    """``render --scene``: the layered technique over a scene file's world."""
    from lodsprite.errors import InputError
    from lodsprite.layered.technique import render_scene

    if scene is None:
        raise InputError("--target-fps is for --scene SCENE.toml")
    with progress_bar("render scene") as update:
        s = render_scene(scene, out_dir, size, frames, mode, target_fps, ground_truth,
                         flip, progress=update,
                         **{k: v for k, v in options.items() if v is not None})
    shares = ", ".join(f"{k[6:]} {v:.0%}" for k, v in s.items() if k.startswith("share_"))
    out.print(f"{s['frames']} frames of {scene}: median {s['median_ms']:.1f} ms, p99 "
              f"{s['p99_ms']:.1f} ms; shares: {shares}; wrote {out_dir}")


def view(
    terrain: Annotated[str, typer.Argument(
        help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy) | a lumigraph "
             "folder | crowd[:OBJECTS[:TREES]]")] = "jacksboro",
    texture: TextureOpt = "terrain",
    grid: GridOpt = None,
    mode: Annotated[str | None, typer.Option(
        "--mode", help="terrain: full | lod | sprite (default; on a store "
                       "sprite-adaptive) | adaptive | sprite-adaptive | distributed "
                       "(needs --server); lumigraph: "
                       "critical (default) | full | arbitrary | fixed | line | "
                       "projective | progressive | subsample; crowd: manager (default) | "
                       "independent | discrete; keys 1-9 switch")] = None,
    lod: TerrainLodOpt = None,
    epsilon: EpsOpt = 1.0,
    size: Annotated[str | None, typer.Option(
        "--size", help="window size WxH (default 1024x768; a scene file's [view] size if it "
                       "gives one)")] = None,
    fps: Annotated[float, typer.Option(
        "--fps", help="frame rate cap (0: none); the keyframe worker uses the time left")] = 60,
    inline: Annotated[bool, typer.Option(
        "--inline-keyframes", help="sprite mode: render keyframes in the frame that needs "
                                   "them (the 1999 algorithm) instead of on a worker "
                                   "thread")] = False,
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
    server: Annotated[str | None, typer.Option(
        "--server", help="distributed mode: a LOD server's HOST:PORT")] = None,
    target_fps: Annotated[float | None, typer.Option(
        "--target-fps", help="crowd: bend the LODs to hold this frame rate ([ ] step it)")
    ] = None,
    sse: Annotated[float | None, typer.Option(
        "--sse", help="adaptive: screen-space error tolerance in pixels")] = None,
    key_sse: Annotated[float | None, typer.Option(
        "--key-sse", help="sprite-adaptive: its keyframes' tolerance in pixels" + _DEF)] = None,
    shading: ShadingOpt = "auto",
    tiles: TilesOpt = None,
    tile_budget_ms: TileBudgetOpt = None,
    cache_mb: Annotated[float | None, typer.Option(
        "--cache-mb", help="sprite with --inline-keyframes: keyframe cache budget in MB "
                           "(0: off)" + _DEF)] = None,
    cache_policy: CachePolicyOpt = "lru",
    metric: TerrainMetricOpt = None,
    proxy_sse: Annotated[float | None, typer.Option(
        "--proxy-sse", help="sprite-adaptive: spriteframes draw the adaptive mesh at this "
                            "tolerance (pixels) instead of the uniform --lod level" + _DEF)] = None,
) -> None:
    """Fly through a terrain with live LOD-sprite, or round a lumigraph (WASD/QE, mouse, tab
    orbit)."""
    from lodsprite.run import parse_size
    from lodsprite.viewer.app import ViewOptions
    from lodsprite.viewer.app import view as run_view

    opts = ViewOptions(terrain=terrain, texture=texture, grid=grid, mode=mode, lod=lod,
                       epsilon=epsilon, size=None if size is None else parse_size(size),
                       fps=fps, threaded=not inline,
                       play=play, frames=frames, screenshots=screenshots, every=every,
                       exit=exit_, out=out_dir, record=record, server=server,
                       target_fps=target_fps, sse=sse, key_sse=key_sse,
                       proxy_sse=proxy_sse, shading=shading, tiles=tiles,
                       tile_budget_ms=tile_budget_ms, cache_mb=cache_mb,
                       cache_policy=cache_policy, metric=metric)
    s = run_view(opts)
    if s:
        out.print(f"{s['frames']} frames, {s['mode']}: median {s['median_ms']:.2f} ms, "
                  f"p99 {s['p99_ms']:.2f} ms, mean {s['mean_ms']:.2f} ms; keyframes "
                  f"{s['keyframes']}; GL {s['gl_renderer']}")
    if out_dir is not None and s:
        out.print(f"wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")
    if record is not None:
        out.print(f"wrote {record}")
