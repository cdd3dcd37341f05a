"""What the commands share: the consoles, the shared options, progress bars, the summary
table printer, the one-line error and option parsing helpers."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from lodsprite.progress import Progress as Update
from lodsprite.progress import StageProgress

if TYPE_CHECKING:
    from lodsprite.experiments.base import Summary

out = Console()
err = Console(stderr=True)

TerrainOpt = Annotated[str, typer.Option(
    "--terrain", help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy)")]
TextureOpt = Annotated[str, typer.Option(
    "--texture", help="terrain | checker[:K] | image FILE")]
PathOpt = Annotated[str, typer.Option(
    "--path", help="chen1999 | swan2002 | flyover[:HEIGHT_M[:TRACK_M]] | "
                   "patrol[:HEIGHT_M[:TRACK_M[:PASSES]]] | bank[:HEIGHT_M[:TRACK_M]] | "
                   "weave[:HEIGHT_M[:HALF_M[:TURNS]]] | FILE.json")]
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
QualityStrideOpt = Annotated[int, typer.Option(
    "--quality-stride", help="with --ground-truth: measure every K-th frame")]
GroundTruthOpt = Annotated[bool, typer.Option(
    "--ground-truth", help="replay the run's decisions untimed against the band-limited "
                           "level-0 reference: RMSE/PSNR/SSIM and flicker per frame and "
                           "their means (played: over display time)")]
MaxErrorOpt = Annotated[str | None, typer.Option(
    "--max-error", help="distributed: PX: the client renders its own keyframe when the shown "
                        "one's error reaches PX pixels and no better one has arrived | off: "
                        "never (the paper's client); default 4")]


def _bars() -> Progress:
    cols = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
            TimeRemainingColumn())
    return Progress(*cols, console=err, transient=False)


@contextmanager
def progress_bars() -> Iterator[StageProgress]:
    """Rich progress bars on stderr, one per step name, each shown from its first update
    (so that input errors, raised before any work, print alone); yields a
    ``(name, done, total)`` callback."""
    bar = _bars()
    tasks: dict[str, int] = {}

    def update(name: str, done: int, total: int) -> None:
        if not tasks:
            bar.start()
        if name not in tasks:
            tasks[name] = bar.add_task(name, total=total)
        bar.update(tasks[name], completed=done, total=total)

    try:
        yield update
    finally:
        bar.stop()


@contextmanager
def progress_bar(description: str) -> Iterator[Update]:
    """One progress bar named ``description`` (see :func:`progress_bars`); yields a
    ``(done, total)`` callback."""
    with progress_bars() as update:
        yield lambda done, total: update(description, done, total)


def print_summary(s: Summary) -> None:
    """An experiment's summary: its table, its notes, the report's path."""
    t = Table(title=s.title)
    for i, col in enumerate(s.columns):
        t.add_column(col, justify="left" if i == 0 and not col else "right")
    for row in s.rows:
        t.add_row(*row)
    out.print(t)
    for line in s.notes:
        out.print(line, markup=False, highlight=False)
    if s.report is not None:
        out.print(f"report: {s.report}")


def numbers(text: str | None, kind: type, option: str) -> list | None:
    """``'1,2,4'`` as a list of ``kind``; None for None; InputError naming ``option``."""
    from lodsprite.errors import InputError

    if text is None:
        return None
    try:
        return [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated numbers, got '{text}'") from None


def one_line(message: str, code: int) -> None:
    """Print ``lodsprite: error: MESSAGE`` as one line on stderr and exit with ``code``."""
    err.print(f"lodsprite: error: {message}", markup=False, highlight=False, soft_wrap=True)
    sys.exit(code)
