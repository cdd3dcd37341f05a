"""The ``lodsprite`` command line: parses, calls the library, prints.

User errors (bad files, bad options) print one line on stderr and exit with
code 2; an interrupted run exits with 130.  No traceback reaches the user for
either.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from lodsprite.errors import GLUnavailableError, LodspriteError
from lodsprite.terrain import DEFAULT_EXAGGERATION

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Time-critical rendering of large terrains with LOD geometry and "
                       "image reuse (LOD-sprite).")
out = Console()
err = Console(stderr=True)

TerrainOpt = Annotated[str, typer.Option(
    "--terrain", help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy)")]
TextureOpt = Annotated[str, typer.Option(
    "--texture", help="terrain | checker[:K] | image FILE")]
PathOpt = Annotated[str, typer.Option(
    "--path", help="chen1999 | swan2002 | flyover[:HEIGHT_M[:TRACK_M]] | FILE.json")]
FramesOpt = Annotated[int | None, typer.Option(
    "--frames", help="frames along the path (default: the paper's 460 / 600, or the file's)")]
SizeOpt = Annotated[str, typer.Option("--size", help="image size WxH in pixels")]
GridOpt = Annotated[int | None, typer.Option(
    "--grid", help="working grid in quads per side, a power of two "
                   "(default 512; SIZE for fractal:SIZE)")]
ExagOpt = Annotated[float, typer.Option("--exaggeration", help="vertical exaggeration")]
LodOpt = Annotated[int, typer.Option("--lod", help="coarse level: N x N quads over the terrain")]
EpsOpt = Annotated[float, typer.Option("--epsilon", help="sprite mode: error threshold (pixels)")]
VisOpt = Annotated[str, typer.Option(
    "--visibility", help="sprite mode: where the sprite is used: coarse | triangle | fragment")]
BorderOpt = Annotated[bool, typer.Option(
    "--border/--no-border", help="sprite mode: draw the terrain's full-resolution outline "
                                 "(border ribbons) with the coarse level")]
GuardOpt = Annotated[int, typer.Option(
    "--guard", help="sprite mode: keyframe guard band in pixels on every side")]
PaceOpt = Annotated[str, typer.Option(
    "--pace", help="distributed: needed (the server renders a keyframe when the shown one "
                   "nears ε) | continuous (back to back, the paper)")]
MaxErrorOpt = Annotated[str | None, typer.Option(
    "--max-error", help="distributed: PX: the client renders its own keyframe when the shown "
                        "one's error reaches PX pixels and no better one has arrived | off: "
                        "never (the paper's client); default 4")]


@contextmanager
def progress_bar(description: str):
    """A rich progress bar on stderr, shown from the first update (so that input errors,
    raised before any frame, print alone); yields a ``(done, total)`` callback."""
    cols = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
            TimeRemainingColumn())
    bar = Progress(*cols, console=err, transient=False)
    task = None

    def update(done: int, total: int) -> None:
        nonlocal task
        if task is None:
            bar.start()
            task = bar.add_task(description, total=total)
        bar.update(task, completed=done, total=total)

    try:
        yield update
    finally:
        bar.stop()


@app.command()
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


@app.command()
def render(
    terrain: TerrainOpt = "jacksboro",
    texture: TextureOpt = "terrain",
    path: PathOpt = "chen1999",
    mode: Annotated[str, typer.Option(
        "--mode", help="full | lod | sprite | adaptive (view-dependent, --sse) | distributed "
                       "(starts a local LOD server)")] = "full",
    lod: LodOpt = 16,
    size: SizeOpt = "512x512",
    frames: FramesOpt = None,
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out"),
    save_frames: Annotated[bool, typer.Option("--save-frames", help="write PNG frames")] = False,
    video: Annotated[Path | None, typer.Option(
        "--video", help="write the frames to an MP4 file (with --ground-truth: full | "
                        "LOD-sprite | difference side by side)")] = None,
    grid: GridOpt = None,
    exaggeration: ExagOpt = DEFAULT_EXAGGERATION,
    epsilon: EpsOpt = 1.0,
    ground_truth: Annotated[bool, typer.Option(
        "--ground-truth", help="sprite mode: also render full resolution (untimed) and "
                               "report RMSE/PSNR/SSIM of sprite and plain coarse frames")] = False,
    visibility: VisOpt = "coarse",
    border: BorderOpt = True,
    guard: GuardOpt = 32,
    pace: PaceOpt = "needed",
    max_error: MaxErrorOpt = None,
    sse: Annotated[float, typer.Option(
        "--sse", help="adaptive: screen-space error tolerance in pixels")] = 1.0,
    key_sse: Annotated[float | None, typer.Option(
        "--key-sse", help="sprite: render keyframes with the adaptive renderer at this "
                          "tolerance (pixels; 0.5 is a good start)")] = None,
    gpu_mb: Annotated[float, typer.Option(
        "--gpu-mb", help="adaptive: GPU tile cache budget (MB)")] = 256.0,
    host_mb: Annotated[float, typer.Option(
        "--host-mb", help="adaptive: host tile cache budget (MB)")] = 512.0,
) -> None:
    """Render a camera path; write DIR/frames.csv and DIR/summary.json (and PNG frames)."""
    from lodsprite import InputError, RenderConfig, render_path
    from lodsprite.run import MODES, parse_size

    if mode not in (*MODES, "distributed"):
        raise InputError(f"unknown mode '{mode}': use one of {', '.join(MODES)}, distributed")
    distributed = mode == "distributed"  # not a core mode: the distributed layer runs it
    if distributed and ground_truth:
        raise InputError("--ground-truth needs --mode sprite")
    if distributed and video is not None:
        raise InputError("--video is for --mode full, lod and sprite")
    config = RenderConfig(terrain=terrain, texture=texture, path=path,
                          mode="sprite" if distributed else mode, lod=lod,
                          size=parse_size(size), frames=frames, grid=grid,
                          exaggeration=exaggeration, save_frames=save_frames, epsilon=epsilon,
                          ground_truth=ground_truth, visibility=visibility, border=border,
                          guard_px=guard, sse=sse, gpu_mb=gpu_mb, host_mb=host_mb,
                          key_sse=key_sse)
    with progress_bar(f"render {mode}") as update:
        if distributed:
            from lodsprite.distributed.run import parse_max_error, render_distributed

            s = render_distributed(config, out_dir, update, pace=pace,
                                   max_error=parse_max_error(max_error))
        else:
            s = render_path(config, out_dir, update, video)
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
        if "rmse_sprite_mean" in s:
            out.print(f"RMSE vs full resolution: LOD-sprite {s['rmse_sprite_mean']:.2f}, "
                      f"plain {s['lod']}² {s['rmse_lod_mean']:.2f} grey levels")
    out.print(f"GL: {s['gl_renderer']}   wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


@app.command()
def view(
    terrain: Annotated[str, typer.Argument(
        help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy) | a lumigraph "
             "folder | crowd[:OBJECTS[:TREES]]")] = "jacksboro",
    texture: TextureOpt = "terrain",
    grid: GridOpt = None,
    mode: Annotated[str | None, typer.Option(
        "--mode", help="terrain: full | lod | sprite (default) | distributed (needs "
                       "--server), keys 1-4; lumigraph: critical (default) | full | "
                       "arbitrary | fixed | line | projective | progressive | subsample, "
                       "keys 1-8; crowd: manager (default) | independent | discrete, "
                       "keys 1-3")] = None,
    lod: LodOpt = 16,
    epsilon: EpsOpt = 1.0,
    size: Annotated[str, typer.Option("--size", help="window size WxH")] = "1024x768",
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
) -> None:
    """Fly through a terrain with live LOD-sprite, or round a lumigraph (WASD/QE, mouse, tab
    orbit)."""
    from lodsprite.run import parse_size
    from lodsprite.viewer.app import ViewOptions
    from lodsprite.viewer.app import view as run_view

    opts = ViewOptions(terrain=terrain, texture=texture, grid=grid, mode=mode, lod=lod,
                       epsilon=epsilon, size=parse_size(size), fps=fps, threaded=not inline,
                       play=play, frames=frames, screenshots=screenshots, every=every,
                       exit=exit_, out=out_dir, record=record, server=server,
                       target_fps=target_fps)
    s = run_view(opts)
    if s:
        out.print(f"{s['frames']} frames, {s['mode']}: median {s['median_ms']:.2f} ms, "
                  f"p99 {s['p99_ms']:.2f} ms, mean {s['mean_ms']:.2f} ms; keyframes "
                  f"{s['keyframes']}; GL {s['gl_renderer']}")
    if out_dir is not None and s:
        out.print(f"wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")
    if record is not None:
        out.print(f"wrote {record}")


lumigraph_app = typer.Typer(no_args_is_help=True,
                             help="Time-critical lumigraph (Sloan et al. 1997): capture, render.")
app.add_typer(lumigraph_app, name="lumigraph")


@lumigraph_app.command("capture")
def lumigraph_capture(
    model: Annotated[str, typer.Argument(
        help="still-life (built in) | a mesh FILE (.obj .ply .off .stl .glb .gltf)")
    ] = "still-life",
    out_dir: Annotated[Path, typer.Option("--out", help="lumigraph folder to write")] = Path(
        "out/lumigraph"),
    st: Annotated[int, typer.Option("--st", help="st nodes per side")] = 32,
    uv: Annotated[int, typer.Option("--uv", help="uv image size in pixels")] = 256,
    codec: Annotated[str, typer.Option("--codec", help="jpeg | png (lossless)")] = "jpeg",
    quality: Annotated[int, typer.Option("--quality", help="JPEG quality 1-100")] = 90,
    slabs: Annotated[int, typer.Option(
        "--slabs", help="1 (in front, as in the paper) or 6 (round the object: orbit it)")
    ] = 1,
) -> None:
    """Render a two-plane lumigraph of an object: one uv image per st node, compressed."""
    from lodsprite.lumigraph.run import capture_lumigraph

    with progress_bar("capture") as update:
        s = capture_lumigraph(model, out_dir, st, uv, codec, quality, slabs=slabs,
                              progress=update)
    out.print(f"{s['nodes']} nodes of {s['uv']}² ({s['codec']}) of {s['object']} "
              f"({s['faces']:,} triangles) in {s['capture_s']:.1f} s; wrote {out_dir}")


@lumigraph_app.command("import")
def lumigraph_import(
    folder: Annotated[Path, typer.Argument(
        help="a Stanford Light Field Archive rectified/ folder (out_RR_CC_Y_X_.png)")],
    out_dir: Annotated[Path, typer.Option("--out", help="lumigraph folder to write")] = Path(
        "out/lumigraph"),
    uv: Annotated[int, typer.Option("--uv", help="uv image size in pixels")] = 256,
    codec: Annotated[str, typer.Option("--codec", help="jpeg | png (lossless)")] = "jpeg",
    st_scale: Annotated[float, typer.Option(
        "--st-scale", help="scale of the camera grid against the image plane")] = 1.0,
) -> None:
    """Import a rectified light field of the Stanford archive as a lumigraph."""
    from lodsprite.lumigraph.importer import import_stanford

    s = import_stanford(folder, out_dir, uv, codec, st_scale=st_scale)
    out.print(f"{s['nodes']} nodes ({s['grid']}x{s['grid']} cameras) of {s['uv']}²; "
              f"wrote {out_dir}")


@lumigraph_app.command("render")
def lumigraph_render(
    folder: Annotated[Path, typer.Argument(help="a lumigraph folder (lumigraph capture)")],
    frames: Annotated[int, typer.Option("--frames", help="frames along the arc")] = 120,
    path: Annotated[str | None, typer.Option(
        "--path", help="a JSON path file (default: an arc in front of the object, or an "
                       "orbit round it for six slabs)")] = None,
    size: SizeOpt = "512x512",
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path(
        "out/lumigraph-render"),
    ground_truth: Annotated[bool, typer.Option(
        "--ground-truth", help="compare every frame with the object drawn directly "
                               "(PSNR, SSIM)")] = False,
    depth_correction: Annotated[bool, typer.Option(
        "--depth-correction/--no-depth-correction",
        help="correct uv coordinates with the approximate geometry")] = True,
    method: Annotated[str, typer.Option(
        "--method", help="full | subsample | fixed | arbitrary | line | projective | "
                         "progressive | critical")] = "full",
    target_fps: Annotated[float, typer.Option(
        "--target-fps", help="critical: the frame rate to hold")] = 30.0,
    texture_mb: Annotated[float, typer.Option(
        "--texture-mb", help="critical: texture memory for node images (MB)")] = 4.0,
    nodes: Annotated[int, typer.Option(
        "--nodes", help="arbitrary, projective, progressive: nodes round the eye")] = 16,
    level: Annotated[int, typer.Option(
        "--level", help="subsample: mipmap level (st and uv halved per level)")] = 1,
    reuse: Annotated[int, typer.Option(
        "--reuse", help="projective: frames each reconstructed image is reused")] = 6,
    fade: Annotated[int, typer.Option(
        "--fade", help="progressive: frames to blend a node in or out")] = 8,
    every: Annotated[int, typer.Option(
        "--every", help="with --ground-truth: compare every K-th frame")] = 1,
    flip: Annotated[bool, typer.Option(
        "--flip", help="with --ground-truth: FLIP too (about 0.4 s a 512² frame)")] = False,
) -> None:
    """Reconstruct a lumigraph along a path with one of the paper's methods."""
    from lodsprite.lumigraph.run import render_lumigraph
    from lodsprite.paths import load_path_json
    from lodsprite.run import parse_size

    cam = load_path_json(path) if path is not None else None
    opts = dict(nodes=nodes, level=level, reuse=reuse, fade=fade, target_fps=target_fps,
                texture_mb=texture_mb)
    with progress_bar(f"lumigraph {method}") as update:
        s = render_lumigraph(folder, out_dir, frames, parse_size(size), cam, ground_truth,
                             depth_correction, method, every, update, flip, **opts)
    line = (f"{s['frames']} frames ({method}, {s['images_per_frame_mean']:.1f} images a "
            f"frame): median {s['median_ms']:.2f} ms, mean {s['mean_ms']:.2f} ms, "
            f"p99 {s['p99_ms']:.2f} ms")
    if "psnr_mean" in s:
        line += f"; PSNR {s['psnr_mean']:.2f} dB, SSIM {s['ssim_mean']:.3f}"
    if "flip_mean" in s:
        line += f", FLIP {s['flip_mean']:.4f}"
    out.print(line + f"; wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")


def _run_reproduction(cfg, out_dir: Path) -> dict:
    from lodsprite.report.chen1999 import write_plots, write_report
    from lodsprite.sprite.reproduce import reproduce_chen1999

    with progress_bar("reproduce chen1999") as update:
        results = reproduce_chen1999(cfg, out_dir, update)
    report = write_report(results, out_dir, write_plots(results, out_dir))
    _print_reproduction(results, report)
    return results


def _print_reproduction(r: dict, report: Path) -> None:
    t = Table(title=f"Chen et al. 1999 reproduced: {r['terrain']} {r['grid']}², "
                    f"{r['lod']}² LOD, {r['frames']} frames, ε = {r['epsilon']} px, "
                    f"{r['size'][0]}² px")
    t.add_column("")
    t.add_column("this run", justify="right")
    t.add_column("paper (1999)", justify="right")
    from lodsprite.report.paper_numbers import PAPER as P

    rows = [
        ("keyframes", f"{r['keyframes']} ({100 * r['keyframe_fraction']:.1f} %)",
         f"{P['keyframes']:.0f} ({100 * P['keyframes'] / P['frames']:.1f} %)"),
        ("keyframe ms", f"{r['mean_ms_keyframe']:.1f}", f"{P['mean_ms_keyframe']:g}"),
        ("first spriteframe ms", f"{r['mean_ms_first_sprite']:.1f}",
         f"{P['mean_ms_first_sprite']:g}"),
        ("spriteframe ms", f"{r['mean_ms_sprite']:.1f}", f"{P['mean_ms_sprite']:g}"),
        ("full resolution total s", f"{r['total_s_full']:.2f}", f"{P['total_s_full']:g}"),
        ("LOD-sprite total s", f"{r['total_s_sprite']:.2f}", f"{P['total_s_sprite']:g}"),
        ("speedup", f"{r['speedup']:.2f}x", f"{P['speedup']:g}x"),
        ("RMSE LOD-sprite / plain LOD", f"{r['rmse_sprite_mean']:.2f} / {r['rmse_lod_mean']:.2f}",
         "(Figs 13-14)"),
    ]
    for row in rows:
        t.add_row(*row)
    out.print(t)
    out.print(f"GL: {r['gl_renderer']}   report: {report}")


def _run_swan2002(out_dir: Path, terrain: str, quick: bool, size: int, lod: int,
                  adopt: str, pace: str, epsilon: float, max_error: float | None,
                  links: bool = True) -> None:
    from lodsprite.distributed.reproduce import SwanConfig, reproduce_swan2002
    from lodsprite.distributed.run import check_client_options, parse_max_error
    from lodsprite.errors import InputError
    from lodsprite.report.swan2002 import policy_lines, setups_in, write_plots, write_report

    if out_dir == Path("out/chen1999"):
        out_dir = Path("out/swan2002")
    if not epsilon > 0:
        raise InputError(f"--epsilon must be > 0 pixels, got {epsilon}")
    max_error = parse_max_error(None) if max_error is None else max_error
    check_client_options(pace, adopt, max_error)
    kw = {"terrain": terrain, "lod": lod, "adopt": adopt, "pace": pace, "epsilon": epsilon,
          "max_error": max_error, "links": links}
    cfg = SwanConfig.quick(**kw) if quick else SwanConfig(size=size, **kw)
    with progress_bar("reproduce swan2002 (set-ups)") as update:
        r = reproduce_swan2002(cfg, out_dir, update)
    report = write_report(r, out_dir, write_plots(r, out_dir))
    t = Table(title=f"Swan et al. 2002 reproduced: {cfg.terrain}, {cfg.frames} frames")
    for col in ("set-up", "client mean ms", "σ ms", "p99 ms", "sprites/keyframe", "δt ms"):
        t.add_column(col, justify="right")
    for s in setups_in(r):
        x = r[s]
        if "skipped" in x:
            t.add_row(s, "skipped", "", "", "", "")
            continue
        spk, dt = x.get("sprites_per_keyframe"), x.get("delta_t_ms_mean")
        t.add_row(s, f"{x['client_ms_mean']:.2f}", f"{x['client_ms_std']:.2f}",
                  f"{x['client_ms_p99']:.2f}", "—" if spk is None else f"{spk:.1f}",
                  "—" if dt is None else f"{dt:.0f}")
    from lodsprite.report.paper_numbers import PAPER_2002

    d, n = PAPER_2002["separate"], PAPER_2002["same_cores"]
    t.add_row("paper distributed", f"{d['client_ms_mean']:g}", f"{d['client_ms_std']:g}", "",
              f"{d['sprites_per_keyframe']:g}", f"{d['delta_t_ms_mean']:g}")
    t.add_row("paper non-distributed", f"{n['client_ms_mean']:g}", f"{n['client_ms_std']:g}",
              "", "", "")
    out.print(t)
    for line in policy_lines(r):
        out.print(line, markup=False, highlight=False)
    out.print(f"report: {report}")


def _multi_progress():
    """A rich progress display with one bar per named task; yields ``(name, done, total)``."""
    cols = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
            TimeRemainingColumn())
    bar = Progress(*cols, console=err, transient=False)
    tasks: dict[str, int] = {}

    def update(name: str, done: int, total: int) -> None:
        if not tasks:
            bar.start()
        if name not in tasks:
            tasks[name] = bar.add_task(name, total=total)
        bar.update(tasks[name], completed=done, total=total)

    return bar, update


def _run_scoggins2000(out_dir: Path, terrain: str, quick: bool, size: int) -> None:
    from lodsprite.profiles.reproduce import ScogginsConfig, reproduce_scoggins2000
    from lodsprite.report.paper_numbers import PAPER_2000
    from lodsprite.report.scoggins2000 import write_outputs

    if out_dir == Path("out/chen1999"):
        out_dir = Path("out/scoggins2000")
    cfg = ScogginsConfig.quick(terrain=terrain) if quick else ScogginsConfig(terrain=terrain,
                                                                             size=size)
    bar, update = _multi_progress()
    try:
        r = reproduce_scoggins2000(cfg, update)
    finally:
        bar.stop()
    report, _ = write_outputs(r, out_dir)
    t = Table(title="Scoggins et al. 2000 reproduced")
    for col in ("", "this run", "paper"):
        t.add_column(col, justify="right")
    t.add_row("profile s, sphere family", f"{r['profile_s_sphere']:.1f}",
              f"{PAPER_2000['profile_min_sphere'] * 60}")
    t.add_row("profile s, mountain", f"{r['profile_s_mountain']:.1f}",
              f"{PAPER_2000['profile_min_mountain'] * 60}")
    t.add_row("sphereflake triangles, full", f"{r['snowflake_triangles_full']:,}",
              f"{PAPER_2000['snowflake_triangles_full']:,}")
    t.add_row("far sphereflake, CSF / no CSF", f"{r['snowflake_triangles_far_csf']:,} / "
              f"{r['snowflake_triangles_far_nocsf']:,}", "")
    t.add_row("RMSE profile / SSE (equal triangles)",
              f"{r['rmse_profile']:.3f} / {r['rmse_sse']:.3f}", "")
    t.add_row("FLIP profile / SSE", f"{r['flip_profile']:.4f} / {r['flip_sse']:.4f}", "")
    out.print(t)
    out.print(f"report: {report}")


def _with_bars(run, *args):
    """``run(*args, update)`` under one progress bar per step."""
    bar, update = _multi_progress()
    try:
        return run(*args, update)
    finally:
        bar.stop()


def _run_large(out_dir: Path, quick: bool, huge: bool = False,
               terrains: tuple[str, ...] = ()) -> None:
    from dataclasses import replace

    from lodsprite.report.large import write_outputs
    from lodsprite.terrain.large import LargeConfig, reproduce_large

    if out_dir == Path("out/chen1999"):
        out_dir = Path("out/large")
    cfg = LargeConfig.quick() if quick else LargeConfig()
    r = _with_bars(reproduce_large, replace(cfg, huge=huge, terrains=terrains), out_dir)
    report = write_outputs(r, out_dir)
    for side, v in [*sorted(r["sizes"].items(), key=lambda kv: int(kv[0])),
                    *r["terrains"].items()]:
        out.print(f"{side}: adaptive median {v['median_ms_adaptive']:.1f} ms, sprite "
                  f"{v['median_ms_sprite']:.1f} ms, RMSE {v['rmse_adaptive']:.2f} / "
                  f"{v['rmse_sprite']:.2f}, peak RSS {v['peak_rss_mb']:.0f} MB, first frame "
                  f"{v['first_frame_s']:.2f} s")
    out.print(f"report: {report}")


def _run_gumbau(out_dir: Path, quick: bool) -> None:
    from lodsprite.manager.reproduce import GumbauConfig, reproduce_gumbau
    from lodsprite.report.gumbau import write_outputs

    if out_dir == Path("out/chen1999"):
        out_dir = Path("out/gumbau")
    r = _with_bars(reproduce_gumbau, GumbauConfig.quick() if quick else GumbauConfig())
    report = write_outputs(r, out_dir)
    t = Table(title="Gumbau, Ripolles & Chover (LODManager) reproduced")
    for col in ("", "with the manager", "without"):
        t.add_column(col, justify="right")
    t.add_row("extractions", f"{r['extractions_with']:,}", f"{r['extractions_without']:,}")
    t.add_row("fps (mean)", f"{r['fps_mean_with']:.2f}", f"{r['fps_mean_without']:.2f}")
    t.add_row("LOD CPU ms / frame", f"{r['lod_cpu_ms_with']:.2f}",
              f"{r['lod_cpu_ms_without']:.2f}")
    t.add_row("draw calls", f"{r['draw_calls_mean_with']:.0f}",
              f"{r['draw_calls_mean_without']:.0f}")
    t.add_row("image difference (grey levels)", f"{r['image_diff_mean']:.3f}", "")
    t.add_row(f"target {r['target_fps']:g} fps: median / p99 ms",
              f"{r['frame_ms_median_at_target']:.1f} / {r['frame_ms_p99_at_target']:.1f}", "")
    out.print(t)
    out.print(f"report: {report}")


def _run_sloan1997(out_dir: Path, quick: bool) -> None:
    from lodsprite.lumigraph.reproduce import SloanConfig, reproduce_sloan1997
    from lodsprite.report.paper_numbers import PAPER_1997
    from lodsprite.report.sloan1997 import write_outputs

    if out_dir == Path("out/chen1999"):
        out_dir = Path("out/sloan1997")
    r = _with_bars(reproduce_sloan1997, SloanConfig.quick() if quick else SloanConfig(),
                   out_dir)
    report = write_outputs(r, out_dir)
    t = Table(title="Sloan, Cohen & Gortler 1997 reproduced")
    for col in ("", "this run", "paper"):
        t.add_column(col, justify="right")
    t.add_row("capture s", f"{r['capture_s']:.1f}", "")
    t.add_row("PSNR full / no depth correction",
              f"{r['psnr_full']:.2f} / {r['psnr_no_depth_correction']:.2f} dB", "")
    for name, v in r["table1"].items():
        t.add_row(f"fill rate {name}", f"{v['fill_rate']:.2f}",
                  str(PAPER_1997["fill_rate"][name]))
    for name, q in r["critical"].items():
        t.add_row(f"{name}: mean / p99 ms (target {q['target_ms']:.1f})",
                  f"{q['mean_ms']:.1f} / {q['p99_ms']:.1f}", "")
    out.print(t)
    out.print(f"report: {report}")


@app.command()
def tile(
    source: Annotated[str, typer.Argument(
        help="a GeoTIFF/COG file (read window by window) | fractal:SIZE[:SEED] | "
             "fractal:ROWSxCOLS[:SEED] (generated tile by tile)")],
    out_dir: Annotated[Path, typer.Option("--out", help="the store to write (STORE.zarr)")],
    tile_size: Annotated[int, typer.Option("--tile", help="tile (and shard) side")] = 1024,
    chunk: Annotated[int, typer.Option("--chunk", help="inner chunk side")] = 256,
    encoding: Annotated[str, typer.Option(
        "--encoding", help="float32 | int16 (heights = value · scale + offset)")] = "float32",
    scale: Annotated[float, typer.Option("--scale", help="int16: metres per step")] = 0.25,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing store")] = False,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="a Dask scheduler address (tcp://HOST:PORT) to spread the tiles "
                            "over (pip install 'lodsprite[cluster]')")] = None,
) -> None:
    """Build a Zarr v3 terrain pyramid from a DEM larger than memory (resumable)."""
    from lodsprite.terrain.store import build_store

    with progress_bar("tiles") as update:
        s = build_store(source, out_dir, tile_size, chunk, encoding, scale, overwrite, update,
                        scheduler=scheduler)
    if s.get("already"):
        out.print(f"{out_dir} is already built ({s['rows']}x{s['cols']}, {s['levels']} levels)")
        return
    out.print(f"{s['rows']}x{s['cols']} samples, {s['levels']} levels: {s['tiles_written']} "
              f"tiles in {s['seconds']:.1f} s ({s['mb_per_s']:.1f} MB/s of float32 heights)"
              f"{' (resumed)' if s['resumed'] else ''}; wrote {out_dir}")


@app.command()
def crowd(
    objects: Annotated[int, typer.Option("--objects", help="crowd members")] = 3000,
    trees: Annotated[int, typer.Option("--trees", help="trees among them (about 97k "
                                                      "triangles each)")] = 0,
    mesh: Annotated[str | None, typer.Option(
        "--mesh", help="a mesh FILE for the crowd members (default: the built-in ogre)")
    ] = None,
    manager: Annotated[bool, typer.Option(
        "--manager/--no-manager", help="share LODs (LODManager) or extract each object's "
                                       "own (baseline a)")] = True,
    discrete: Annotated[bool, typer.Option(
        "--discrete", help="baseline b: a discrete LOD chain by screen size with "
                           "hysteresis, instead of continuous LOD")] = False,
    slots: Annotated[int, typer.Option("--slots", help="N_T: LOD snapshots a type")] = 16,
    snapshots: Annotated[str, typer.Option(
        "--snapshots", help="their distribution: linear | finer-near (narrower slots for "
                            "close objects, §4.3)")] = "linear",
    active: Annotated[int, typer.Option("--active", help="N_a: active-list size")] = 300,
    target_fps: Annotated[float | None, typer.Option(
        "--target-fps", help="bend the LODs to hold this frame rate")] = None,
    path: Annotated[str | None, typer.Option(
        "--path", help="a JSON path file (default: a walkthrough loop)")] = None,
    frames: Annotated[int, typer.Option("--frames", help="frames of the walkthrough")] = 600,
    size: SizeOpt = "640x480",
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/crowd"),
) -> None:
    """Walk through a crowd of continuous-LOD objects with the LODManager (Gumbau et al.)."""
    from lodsprite.manager.run import CrowdConfig, run_crowd
    from lodsprite.paths import load_path_json
    from lodsprite.run import parse_size

    mode = "discrete" if discrete else ("manager" if manager else "independent")
    cfg = CrowdConfig(objects, trees, mesh, mode, slots, active, target_fps, frames,
                      parse_size(size), snapshots=snapshots)
    cfg.validate()
    cam = load_path_json(path) if path is not None else None
    with progress_bar(f"crowd ({mode})") as update:
        _, s, _ = run_crowd(cfg, out_dir, cam, update)
    out.print(f"{s['frames']} frames, {s['objects']} objects ({mode}): {s['fps_mean']:.1f} fps "
              f"mean, median {s['frame_ms_median']:.1f} ms, p99 {s['frame_ms_p99']:.1f} ms; "
              f"{s['extractions_total']} extractions, {s['draw_calls_mean']:.0f} draw calls, "
              f"{s['triangles_mean']:,.0f} triangles a frame; wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


@app.command()
def profile(
    model: Annotated[str, typer.Argument(
        help="sphere | mountain[:TERRAIN] | a mesh file (.obj .ply .off .stl .glb)")],
    out_path: Annotated[Path | None, typer.Option(
        "--out", help="table file to write (default: MODEL-profile.npz here)")] = None,
    faces: Annotated[str | None, typer.Option(
        "--faces", help="mesh files: LOD face counts, e.g. 1000,2000,4000")] = None,
    ratios: Annotated[str | None, typer.Option(
        "--ratios", help="mesh files: LOD face ratios, e.g. 0.05,0.2,0.5 "
                         "(default 0.01,0.02,0.05,0.1,0.2,0.5)")] = None,
    image: Annotated[int, typer.Option("--image", help="profile image size M (pixels)")] = 512,
    phi_step: Annotated[float, typer.Option("--phi-step", help="azimuth step, degrees")] = 30.0,
    theta_step: Annotated[float, typer.Option(
        "--theta-step", help="elevation step, degrees (0..90)")] = 15.0,
    workers: Annotated[int | None, typer.Option(
        "--workers", help="local worker processes (default: one per core)")] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Dask scheduler address (tcp://HOST:PORT): run views there "
                             "(needs the cluster extra: pip install 'lodsprite[cluster]')")
    ] = None,
) -> None:
    """Compute a model's LOD error profile (Scoggins et al. 2000) and write its table."""
    from lodsprite.errors import InputError
    from lodsprite.profiles.generate import ProfileSettings, generate_profile, require_dask
    from lodsprite.profiles.models import get_model

    if scheduler is not None:
        require_dask()  # one line naming the extra, before any model is built
    settings = ProfileSettings(image_size=image, phi_step_deg=phi_step,
                               theta_step_deg=theta_step)
    chain = get_model(model, faces=_numbers(faces, int, "--faces"),
                      ratios=_numbers(ratios, float, "--ratios"))
    if out_path is None:
        stem = Path(model).stem if Path(model).suffix else model.replace(":", "-")
        out_path = Path(f"{stem}-profile.npz")
    if out_path.is_dir():
        raise InputError(f"--out {out_path} is a folder; give a table file name")
    with progress_bar(f"profile {chain.name} (views)") as update:
        table = generate_profile(chain, settings, workers=workers, scheduler=scheduler,
                                 progress=update)
    table.save(out_path)
    out.print(f"{chain.name}: {len(chain.levels)} LODs {chain.faces}, {table.error.shape[1]}x"
              f"{table.error.shape[2]} views, {len(table.z)} distances, "
              f"{table.meta['seconds']:.1f} s; wrote {out_path}")


def _numbers(text: str | None, kind: type, option: str) -> list | None:
    from lodsprite.errors import InputError

    if text is None:
        return None
    try:
        return [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated numbers, got '{text}'") from None


@app.command()
def reproduce(
    experiment: Annotated[str, typer.Argument(
        help="chen1999 | swan2002 | scoggins2000 | sloan1997 | gumbau | large")],
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/chen1999"),
    terrain: TerrainOpt = "jacksboro",
    size: Annotated[int, typer.Option("--size", help="image size in pixels (square)")] = 512,
    quick: Annotated[bool, typer.Option("--quick", help="a short run: 256², 115 frames, "
                                                        "fewer sweep points, quality on "
                                                        "every third frame")] = False,
    grid: GridOpt = None,
    lod: LodOpt = 16,
    epsilon: EpsOpt = 1.0,
    visibility: VisOpt = "coarse",
    border: BorderOpt = True,
    guard: GuardOpt = 32,
    full_sample: Annotated[int | None, typer.Option(
        "--full-sample", help="time full resolution on this many evenly spaced frames "
                              "(>= 46) and scale; default all frames up to 1024², else 46")] = None,
    sweeps: Annotated[bool, typer.Option(
        "--sweeps/--no-sweeps", help="run the Fig. 10-12 sweeps")] = True,
    adopt: Annotated[str, typer.Option(
        "--adopt", help="swan2002: when the client takes a newer keyframe: "
                        "newest | better | needed")
    ] = "newest",
    pace: PaceOpt = "needed",
    max_error: Annotated[float | None, typer.Option(
        "--max-error", help="swan2002: the bounded client's --max-error in pixels, run beside "
                            "the paper's client (default: the client's default, 4)")] = None,
    links: Annotated[bool, typer.Option(
        "--links/--no-links", help="swan2002: run the set-ups over emulated network links "
                                   "(network namespaces, root)")] = True,
    huge: Annotated[bool, typer.Option(
        "--huge", help="large: also a 65536² store (see report.md for the disk it needs)")
    ] = False,
) -> None:
    """Run a paper's experiment; write DIR/results.json, PNG plots and DIR/report.md."""
    from lodsprite.errors import InputError
    from lodsprite.sprite.reproduce import ReproduceConfig

    if experiment == "swan2002":
        _run_swan2002(out_dir, terrain, quick, size, lod, adopt, pace, epsilon, max_error,
                      links)
        return
    if experiment == "scoggins2000":
        _run_scoggins2000(out_dir, terrain, quick, size)
        return
    if experiment == "sloan1997":
        _run_sloan1997(out_dir, quick)
        return
    if experiment == "gumbau":
        _run_gumbau(out_dir, quick)
        return
    if experiment == "large":
        _run_large(out_dir, quick, huge, () if terrain == "jacksboro" else (terrain,))
        return
    if experiment != "chen1999":
        raise InputError(f"unknown experiment '{experiment}': available: chen1999, swan2002, "
                         "scoggins2000, sloan1997, gumbau, large")
    kw = {"terrain": terrain, "grid": grid, "lod": lod, "epsilon": epsilon,
          "visibility": visibility, "border": border, "guard_px": guard,
          "full_sample": full_sample, "sweeps": sweeps}
    cfg = ReproduceConfig.quick(**kw) if quick else ReproduceConfig(size=size, **kw)
    _run_reproduction(cfg, out_dir)


@app.command()
def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/demo"),
    quick: Annotated[bool, typer.Option("--quick", help="a short run")] = False,
) -> None:
    """Reproduce Chen et al. 1999 on the real Jacksboro DEM at 512² (a few minutes)."""
    from lodsprite.sprite.reproduce import ReproduceConfig

    _run_reproduction(ReproduceConfig.quick() if quick else ReproduceConfig(), out_dir)


@app.command()
def serve(
    bind: Annotated[str, typer.Option("--bind", help="HOST:PORT; the three connections use "
                                                     "PORT, PORT+1, PORT+2")] = "127.0.0.1:5555",
    predictor: Annotated[str, typer.Option("--predictor", help="linear | kalman")] = "linear",
    codec: Annotated[str, typer.Option("--codec", help="raw | zlib (keyframe images)")] = "raw",
    allow_remote: Annotated[bool, typer.Option(
        "--allow-remote", help="allow binding an address other than loopback")] = False,
    keys: Annotated[Path | None, typer.Option(
        "--keys", help="folder from `lodsprite keys`: encrypt with CURVE and accept only "
                       "clients whose public key is there")] = None,
    data: Annotated[Path | None, typer.Option(
        "--data", help="folder whose terrain and texture files clients may name (relative "
                       "to it); without it only built-ins (jacksboro, fractal:SIZE:SEED, "
                       "terrain, checker) are served")] = None,
    allow_shutdown: Annotated[bool, typer.Option(
        "--allow-shutdown", help="carry out a `shutdown` message from the client holding "
                                 "the server (refused otherwise)")] = False,
) -> None:
    """The LOD server: renders keyframes for LOD clients; driven entirely by messages."""
    import logging

    from lodsprite.distributed.keys import ServerKeys
    from lodsprite.distributed.server import LodServer

    server_keys = ServerKeys.load(keys) if keys is not None else None
    server = LodServer(bind, predictor, codec, server_keys, data_dir=data,
                       allow_remote=allow_remote, allow_shutdown=allow_shutdown)
    logging.basicConfig(level=logging.INFO, format="lodsprite serve: %(message)s")
    if server_keys is None and allow_remote:
        logging.warning("serving beyond loopback without --keys: anyone who can reach "
                        "the port can drive this server")
    server.run()


@app.command(name="keys")
def keys_command(
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("keys"),
) -> None:
    """Make CURVE key pairs for a LOD server and a client (server.key*, client.key*)."""
    from lodsprite.distributed.keys import make_keys

    for path in make_keys(out_dir):
        out.print(str(path))


@app.command()
def client(
    server: Annotated[list[str] | None, typer.Option(
        "--server", help="HOST:PORT of a LOD server (default 127.0.0.1:5555); repeat for "
                         "several")] = None,
    terrain: TerrainOpt = "jacksboro",
    texture: TextureOpt = "terrain",
    path: PathOpt = "swan2002",
    frames: FramesOpt = None,
    size: SizeOpt = "512x512",
    lod: LodOpt = 16,
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/client"),
    grid: GridOpt = None,
    exaggeration: ExagOpt = DEFAULT_EXAGGERATION,
    visibility: VisOpt = "coarse",
    epsilon: EpsOpt = 1.0,
    border: BorderOpt = True,
    pace: PaceOpt = "needed",
    adopt: Annotated[str, typer.Option(
        "--adopt", help="newest: take every newer keyframe (the paper); better: once its "
                        "error metric here is lower than the shown one's; needed: when the "
                        "shown one's reaches ε/2")] = "newest",
    max_error: MaxErrorOpt = None,
    keys: Annotated[Path | None, typer.Option(
        "--keys", help="folder holding client.key_secret and server.key (CURVE)")] = None,
) -> None:
    """The LOD client: draws a scripted path with keyframes from LOD servers."""
    import logging

    from lodsprite.distributed.keys import ClientKeys
    from lodsprite.distributed.run import check_client_options, parse_max_error, run_client
    from lodsprite.run import RenderConfig, parse_size

    logging.basicConfig(level=logging.WARNING, format="lodsprite client: %(message)s")
    bound = check_client_options(pace, adopt, parse_max_error(max_error))
    config = RenderConfig(terrain=terrain, texture=texture, path=path, mode="sprite",
                          lod=lod, size=parse_size(size), frames=frames, grid=grid,
                          exaggeration=exaggeration, visibility=visibility, epsilon=epsilon,
                          border=border)
    with progress_bar("client") as update:
        s = run_client(config, list(server or ["127.0.0.1:5555"]), out_dir, update,
                       adopt=adopt, keys=ClientKeys.load(keys) if keys is not None else None,
                       pace=pace, max_error=bound)
    out.print(f"{s['frames']} frames: median {s['median_ms']:.2f} ms, mean {s['mean_ms']:.2f}, "
              f"σ {s['std_ms']:.2f}, p99 {s['p99_ms']:.2f}; {s['keyframes_received']} keyframes "
              f"received, {s['local_keyframes']} own keyframes, {s['rejected_keyframes']} "
              f"rejected; δt {s['delta_t_ms_mean']:.0f} ms")
    out.print(f"wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")


def _one_line(message: str, code: int) -> None:
    err.print(f"lodsprite: error: {message}", markup=False, highlight=False, soft_wrap=True)
    sys.exit(code)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app, turning user errors into one line and exit code 2."""
    try:
        code = app(args=argv, standalone_mode=False, prog_name="lodsprite")
    except GLUnavailableError as exc:
        err.print(str(exc), markup=False, highlight=False, soft_wrap=True)
        sys.exit(2)
    except LodspriteError as exc:
        _one_line(str(exc), 2)
    except KeyboardInterrupt:
        err.print("lodsprite: interrupted", markup=False)
        sys.exit(130)
    except Exception as exc:
        # Click's exceptions (vendored by recent typer releases, hence matched by name).
        name = type(exc).__name__
        if name == "NoArgsIsHelpError":
            out.print(exc.ctx.get_help(), markup=False, highlight=False)
            sys.exit(0)
        if name == "Abort":
            err.print("lodsprite: interrupted", markup=False)
            sys.exit(130)
        if hasattr(exc, "format_message") and hasattr(exc, "exit_code"):
            _one_line(exc.format_message(), 2)
        raise
    sys.exit(code if isinstance(code, int) else 0)
