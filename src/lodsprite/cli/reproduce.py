"""``lodsprite reproduce NAME`` and ``demo``: one lookup in :mod:`lodsprite.experiments`,
the run, and the table the experiment gives."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import (
    BorderOpt,
    EpsOpt,
    GridOpt,
    GuardOpt,
    LodOpt,
    PaceOpt,
    VisOpt,
    print_summary,
    progress_bars,
)
from lodsprite.experiments import Experiment, Options, get, names


def run_experiment(experiment: Experiment, options: Options, out_dir: Path | None) -> None:
    """Run ``experiment`` under progress bars (into ``out_dir``, default its own
    ``out/NAME``) and print its summary table."""
    with progress_bars() as update:  # (Experiment.reproduce checks out_dir before any work)
        _, summary = experiment.reproduce(options, out_dir, update)
    print_summary(summary)


def reproduce(
    experiment: Annotated[str, typer.Argument(help=" | ".join(names()))],
    out_dir: Annotated[Path | None, typer.Option(
        "--out", help="output folder (default: out/EXPERIMENT)")] = None,
    terrain: Annotated[str | None, typer.Option(
        "--terrain", help="jacksboro | fractal:SIZE[:SEED] | FILE (.tif/.tiff/.png/.npy) | "
                          "a store (default jacksboro; battlefield: fractal:4096:1)")] = None,
    size: Annotated[int | None, typer.Option(
        "--size", help="image size in pixels (square; default 512, battlefield 256)")] = None,
    path: Annotated[str | None, typer.Option(
        "--path", help="timecritical: the camera path (chen1999 | swan2002 | flyover | bank "
                       "| ... | FILE.json; default bank)")] = None,
    vdp: Annotated[float | None, typer.Option(
        "--vdp", help="timecritical, large: ColorVideoVDP (JOD) over this many seconds of "
                      "each played run, centred (needs the vdp extra)")] = None,
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
    full: Annotated[bool, typer.Option(
        "--full", help="large: the long sweep (1k² to 16k², more frames and ε; far "
                       "longer than the default, not timed here)")] = False,
) -> None:
    """Run a paper's experiment; write DIR/results.json, PNG plots and DIR/report.md."""
    options = Options(terrain=terrain or "jacksboro", size=size or 512,
                      terrain_given=terrain is not None, size_given=size is not None,
                      quick=quick, grid=grid, lod=lod,
                      epsilon=epsilon, visibility=visibility, border=border, guard=guard,
                      full_sample=full_sample, sweeps=sweeps, adopt=adopt, pace=pace,
                      max_error=max_error, links=links, huge=huge, full=full, path=path,
                      vdp=vdp)
    run_experiment(get(experiment), options, out_dir)


def demo(
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/demo"),
    quick: Annotated[bool, typer.Option("--quick", help="a short run")] = False,
) -> None:
    """A first look: Chen et al. 1999 on the real Jacksboro DEM at 512², Figs 8-10 and
    13-14 (67-71 s measured on 2 cores; the ε sweeps are in ``reproduce chen1999``)."""
    from lodsprite.experiments.chen1999 import DEMO

    run_experiment(DEMO, Options(quick=quick), out_dir)
