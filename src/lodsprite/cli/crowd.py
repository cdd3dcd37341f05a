"""``lodsprite crowd``: a walk through a crowd of continuous-LOD objects (the LODManager)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import SizeOpt, out, progress_bar


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
    snapshots: Annotated[str, typer.Option(
        "--snapshots", help="their distribution: linear | finer-near (narrower slots for "
                            "close objects, §4.3)")] = "linear",
    path: Annotated[str | None, typer.Option(
        "--path", help="a JSON path file (default: a walkthrough loop)")] = None,
    frames: Annotated[int, typer.Option("--frames", help="frames of the walkthrough")] = 600,
    size: SizeOpt = "640x480",
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/crowd"),
    options: dict | None = None,
) -> None:
    """Walk through a crowd of continuous-LOD objects with the LODManager (Gumbau et al.);
    its options (--slots, --active, --target-fps, ...): the crowd techniques'
    declarations, under "Technique options"."""
    from lodsprite import techniques
    from lodsprite.files import writable_folder
    from lodsprite.manager.run import CrowdConfig, run_crowd
    from lodsprite.paths import load_path_json
    from lodsprite.run import parse_size

    writable_folder(out_dir)  # before any work: one line if it cannot be

    mode = "discrete" if discrete else ("manager" if manager else "independent")
    o = techniques.get(mode).bind(options or {})
    cfg = CrowdConfig(objects, trees, mesh, mode, o["slots"], o["active"], o["target_fps"],
                      frames, parse_size(size), snapshots=snapshots,
                      range_near=o["range_near"], range_far=o["range_far"])
    cfg.validate()
    cam = load_path_json(path) if path is not None else None
    with progress_bar(f"crowd ({mode})") as update:
        _, s, _ = run_crowd(cfg, out_dir, cam, update)
    out.print(f"{s['frames']} frames, {s['objects']} objects ({mode}): {s['fps_mean']:.1f} fps "
              f"mean, median {s['median_ms']:.1f} ms, p99 {s['p99_ms']:.1f} ms; "
              f"{s['extractions_total']} extractions, {s['draw_calls_mean']:.0f} draw calls, "
              f"{s['triangles_mean']:,.0f} triangles a frame; wrote {out_dir / 'frames.csv'}, "
              f"{out_dir / 'summary.json'}")
