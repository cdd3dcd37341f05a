"""The battlefield: terrain, a walking crowd, trees and light fields under one frame
budget (issue 23, after Chen, Swan & Kaufman 1999's battlefield and Funkhouser & Séquin
1993's scheduler): ``lodsprite reproduce battlefield``.  The scene is :mod:`.scene`, the
runs :mod:`.run`, the report :mod:`.report`."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.battlefield.run.BattlefieldConfig`: the default run
    (about 14 minutes here) or the short one with ``--quick``; ``--terrain`` replaces the
    4k² fractal store (a ``fractal:`` spec is tiled into a store first), ``--size`` the
    image side."""
    from lodsprite.experiments.battlefield.run import BattlefieldConfig

    cfg = BattlefieldConfig.quick() if o.quick else BattlefieldConfig()
    if o.terrain_given:
        cfg = replace(cfg, terrain=o.terrain)
    if o.size_given:
        cfg = replace(cfg, image=o.size)
    return cfg


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Build the scene, run every path; results.json, plots, report.md."""
    from lodsprite.experiments.battlefield.report import write_outputs
    from lodsprite.experiments.battlefield.run import reproduce_battlefield

    r = reproduce_battlefield(cfg, out_dir, progress)
    return r, write_outputs(r, out_dir)


def _f(v, digits: int) -> str:
    return "—" if v is None else f"{v:.{digits}f}"


def summary(r: dict) -> Summary:
    """Scheduler against independent feedback; profile against linear; extractions."""
    rows = []
    for name in ("scheduler", "reuse", "independent"):
        x = r[name]
        rows.append((name, f"{x['target_ms']:.1f}", f"{x['median_ms']:.1f}",
                     f"{x['p99_ms']:.1f}", f"{x['std_ms']:.1f}", _f(x["rmse"], 2),
                     _f(x["flip"], 4)))
    v = r["profile_vs_linear"]
    notes = [f"profile vs linear at equal triangles ({_f(v['triangles_profile'], 0)} / "
             f"{_f(v['triangles_linear'], 0)}): RMSE {_f(v['rmse_profile'], 2)} / "
             f"{_f(v['rmse_linear'], 2)}, FLIP {_f(v['flip_profile'], 4)} / "
             f"{_f(v['flip_linear'], 4)}",
             f"LOD extractions with the manager {r['extractions_with_manager']:,}, without "
             f"{r['extractions_without_manager']:,}"]
    return Summary("The battlefield reproduced", ("", "target ms", "median ms", "p99 ms",
                                                  "σ ms", "RMSE", "FLIP"), rows, notes)


EXPERIMENT = Experiment("battlefield", "The battlefield (a scene under one frame budget)",
                        configure, run, summary)
