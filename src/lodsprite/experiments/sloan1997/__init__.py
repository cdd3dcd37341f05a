"""Sloan, Cohen & Gortler (1997), the time-critical lumigraph:
``lodsprite reproduce sloan1997``.  The run is :mod:`.run`, the report :mod:`.report`."""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.sloan1997.run.SloanConfig` (the paper's, or quick);
    the built-in still life, so no terrain or size option applies."""
    from lodsprite.experiments.sloan1997.run import SloanConfig

    return SloanConfig.quick() if o.quick else SloanConfig()


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Capture, Table 1, the critical-time runs; results.json, plots, report.md."""
    from lodsprite.experiments.sloan1997.report import write_outputs
    from lodsprite.experiments.sloan1997.run import reproduce_sloan1997

    r = reproduce_sloan1997(cfg, out_dir, progress)
    return r, write_outputs(r, out_dir)


def summary(r: dict) -> Summary:
    """Capture, depth correction, Table 1's fill rates beside the paper's, critical time."""
    from lodsprite.experiments.paper_numbers import PAPER_1997

    rows = [("capture s", f"{r['capture_s']:.1f}", ""),
            ("PSNR full / no depth correction",
             f"{r['psnr_full']:.2f} / {r['psnr_no_depth_correction']:.2f} dB", "")]
    rows += [(f"fill rate {name}", f"{v['fill_rate']:.2f}", str(PAPER_1997["fill_rate"][name]))
             for name, v in r["table1"].items()]
    rows += [(f"{name}: mean / p99 ms (target {q['target_ms']:.1f})",
              f"{q['mean_ms']:.1f} / {q['p99_ms']:.1f}", "") for name, q in r["critical"].items()]
    return Summary("Sloan, Cohen & Gortler 1997 reproduced", ("", "this run", "paper"), rows)


EXPERIMENT = Experiment("sloan1997", "Sloan, Cohen & Gortler 1997 (time-critical lumigraph)",
                        configure, run, summary)
