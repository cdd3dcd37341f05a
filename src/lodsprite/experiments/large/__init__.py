"""Large terrain: how frame cost, memory and error scale with terrain size,
``lodsprite reproduce large``.  The run is :mod:`.run` (each timed run in a process of its
own, :mod:`.child`), the report :mod:`.report`."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.large.run.LargeConfig`: the fractal sizes, plus
    ``--terrain`` when it is not the default, plus 65536² with ``--huge``."""
    from lodsprite.experiments.large.run import LargeConfig

    cfg = LargeConfig.quick() if o.quick else LargeConfig()
    return replace(cfg, huge=o.huge, terrains=() if o.terrain == "jacksboro" else (o.terrain,))


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Tile the stores, run adaptive, LOD-sprite and references; results.json, plot,
    report.md."""
    from lodsprite.experiments.large.report import write_outputs
    from lodsprite.experiments.large.run import reproduce_large

    r = reproduce_large(cfg, out_dir, progress)
    return r, write_outputs(r, out_dir)


def summary(r: dict) -> Summary:
    """One row a store (fractal sizes, then ``--terrain`` ones): medians, RMSE, memory."""
    stores = [*sorted(r["sizes"].items(), key=lambda kv: int(kv[0])), *r["terrains"].items()]
    rows = [(side, f"{v['median_ms_adaptive']:.1f}", f"{v['median_ms_sprite']:.1f}",
             f"{v['rmse_adaptive']:.2f} / {v['rmse_sprite']:.2f}", f"{v['peak_rss_mb']:.0f}",
             f"{v['first_frame_s']:.2f}") for side, v in stores]
    return Summary("Large terrain reproduced", (
        "store", "adaptive median ms", "sprite median ms", "RMSE adaptive / sprite",
        "peak RSS MB", "first frame s"), rows)


EXPERIMENT = Experiment("large", "Large terrain (adaptive and LOD-sprite over stores)",
                        configure, run, summary)
