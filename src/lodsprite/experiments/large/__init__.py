"""Large terrain: how frame cost, memory and error scale with terrain size,
``lodsprite reproduce large``.  The run is :mod:`.run` (each timed run in a process of its
own, :mod:`.child`), the report :mod:`.report`."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.large.run.LargeConfig`: the default run (4096²,
    14 minutes here), the long sweep with ``--full`` (16k² too), the short one with
    ``--quick``; plus ``--terrain`` when it is not the default, plus 65536² with
    ``--huge``."""
    from lodsprite.errors import InputError
    from lodsprite.experiments.large.run import LargeConfig

    if o.quick and o.full:
        raise InputError("--quick and --full exclude each other")
    cfg = LargeConfig.quick() if o.quick else LargeConfig.full() if o.full else LargeConfig()
    return replace(cfg, huge=o.huge, terrains=() if o.terrain == "jacksboro" else (o.terrain,),
                   vdp_seconds=o.vdp)


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Tile the stores, run adaptive, LOD-sprite and references; results.json, plot,
    report.md."""
    from lodsprite.experiments.large.report import write_outputs
    from lodsprite.experiments.large.run import reproduce_large

    r = reproduce_large(cfg, out_dir, progress)
    return r, write_outputs(r, out_dir)


def _best(e: dict) -> str:
    b = e["best"]
    return "none" if b is None else f"{b['speedup']:.2f}× ({b['variant']} ε {b['epsilon']:g})"


def summary(r: dict) -> Summary:
    """One row a store and path (fractal sizes, then ``--terrain`` ones): adaptive's and
    whole-keyframe LOD-sprite's (first ε) medians and RMSE, memory, the equal-error
    speedup."""
    stores = [*sorted(r["sizes"].items(), key=lambda kv: int(kv[0])), *r["terrains"].items()]
    rows = []
    for side, v in stores:
        for p, e in r["equal_error_speedup"][side].items():
            ad, whole = v[p]["adaptive"], (v[p].get("whole") or [None])[0]
            rows.append((side, p, f"{ad['median_ms']:.1f}",
                         "—" if whole is None else f"{whole['median_ms']:.1f}",
                         f"{ad['rmse']:.2f} / " + ("—" if whole is None
                                                   else f"{whole['rmse']:.2f}"),
                         f"{ad['peak_rss_mb']:.0f}", _ms(ad.get("first_frame_ms")),
                         f"{ad['first_frame_s']:.2f}", _best(e),
                         _speed(r.get("frontier_speedup", {}).get(side, {}).get(p, {}))))
    return Summary("Large terrain reproduced", (
        "store", "path", "adaptive median ms", "sprite median ms", "RMSE adaptive / sprite",
        "peak RSS MB", "adaptive warm-up ms", "first frame s", "at equal error",
        "frontier speedup 1 / 2 / 4 px"), rows)


def _speed(levels: dict) -> str:
    return " / ".join("—" if levels.get(k) is None else f"{levels[k]:.2f}×"
                      for k in ("1px", "2px", "4px"))


def _ms(v: float | None) -> str:
    return "—" if v is None else f"{v:.0f}"


EXPERIMENT = Experiment("large", "Large terrain (adaptive and LOD-sprite over stores)",
                        configure, run, summary)
