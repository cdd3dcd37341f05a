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
PathOpt = Annotated[str, typer.Option("--path", help="chen1999 | swan2002 | FILE.json")]
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
    mode: Annotated[str, typer.Option("--mode", help="full | lod | sprite")] = "full",
    lod: LodOpt = 16,
    size: SizeOpt = "512x512",
    frames: FramesOpt = None,
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out"),
    save_frames: Annotated[bool, typer.Option("--save-frames", help="write PNG frames")] = False,
    grid: GridOpt = None,
    exaggeration: ExagOpt = DEFAULT_EXAGGERATION,
    epsilon: EpsOpt = 1.0,
    ground_truth: Annotated[bool, typer.Option(
        "--ground-truth", help="sprite mode: also render full resolution (untimed) and "
                               "report RMSE/PSNR/SSIM of sprite and plain coarse frames")] = False,
    visibility: VisOpt = "coarse",
) -> None:
    """Render a camera path; write DIR/frames.csv and DIR/summary.json (and PNG frames)."""
    from lodsprite.run import RenderConfig, parse_size, render_path

    config = RenderConfig(terrain=terrain, texture=texture, path=path, mode=mode, lod=lod,
                          size=parse_size(size), frames=frames, grid=grid,
                          exaggeration=exaggeration, save_frames=save_frames, epsilon=epsilon,
                          ground_truth=ground_truth, visibility=visibility)
    with progress_bar(f"render {mode}") as update:
        s = render_path(config, out_dir, update)
    t = Table(title=f"{s['frames']} frames, {s['mode']}, {s['terrain']} ({s['grid']}² grid)")
    for col in ("median ms", "mean ms", "p95 ms", "total s", "triangles"):
        t.add_column(col, justify="right")
    t.add_row(f"{s['median_ms']:.2f}", f"{s['mean_ms']:.2f}", f"{s['p95_ms']:.2f}",
              f"{s['total_s']:.2f}", f"{s['triangles_mean']:.0f}")
    out.print(t)
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
def demo(
    terrain: TerrainOpt = "jacksboro",
    path: PathOpt = "chen1999",
    frames: FramesOpt = None,
    lod: LodOpt = 16,
    size: SizeOpt = "512x512",
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/demo"),
) -> None:
    """Render the default terrain along the default path at full resolution and at 16x16."""
    from lodsprite.run import RenderConfig, compare_full_lod, parse_size

    config = RenderConfig(terrain=terrain, path=path, frames=frames, lod=lod,
                          size=parse_size(size))
    with progress_bar("full vs coarse") as update:
        s = compare_full_lod(config, out_dir, update)
    t = Table(title=f"{s['terrain']} {s['grid']}², path {s['path']}, {s['frames']} frames, "
                    f"{s['size'][0]}x{s['size'][1]} px")
    for col in ("model", "triangles", "median ms", "mean ms", "p95 ms"):
        t.add_column(col, justify="right")
    t.add_row(f"full {s['grid']}²", f"{2 * s['grid'] ** 2}", f"{s['full']['median_ms']:.2f}",
              f"{s['full']['mean_ms']:.2f}", f"{s['full']['p95_ms']:.2f}")
    t.add_row(f"coarse {s['lod']}²", f"{2 * s['lod'] ** 2}", f"{s['lod_level']['median_ms']:.2f}",
              f"{s['lod_level']['mean_ms']:.2f}", f"{s['lod_level']['p95_ms']:.2f}")
    out.print(t)
    out.print(f"coarse vs full image difference: RMSE {s['rmse_mean']:.2f} grey levels, "
              f"PSNR {s['psnr_mean']:.2f} dB (mean over frames); median speedup "
              f"{s['speedup_median']:.1f}x")
    out.print(f"GL: {s['gl_renderer']}   wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")


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
