"""Chen, Swan & Kaufman (1999), LOD-sprite: ``lodsprite reproduce chen1999``.

The run is :mod:`.run` (timed LOD-sprite and full resolution along the paper's path, an
untimed quality replay, the Figs 10-12 sweeps), the report :mod:`.report` and
:mod:`.plots`; the summary table is a selection of the report's own rows.
"""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary, single

#: The report's rows the command line shows after a run.
HEADLINE = ("keyframes", "mean time, keyframe (ms)", "mean time, first spriteframe (ms)",
            "mean time, spriteframe (ms)", "total, full resolution (s)",
            "total, LOD-sprite (s)", "speedup, full ÷ LOD-sprite (×)",
            "RMSE, LOD-sprite vs full (mean)", "RMSE, plain LOD vs full (mean)",
            "RMSE ratio, LOD-sprite ÷ plain LOD")


def configure(o: Options):
    """The paper's set-up (or the quick one) with the options' terrain and LOD-sprite
    settings: a :class:`~lodsprite.experiments.chen1999.run.ReproduceConfig`."""
    from lodsprite.experiments.chen1999.run import ReproduceConfig

    kw = {"terrain": o.terrain, "grid": o.grid, "lod": o.lod, "epsilon": o.epsilon,
          "visibility": o.visibility, "border": o.border, "guard_px": o.guard,
          "full_sample": o.full_sample, "sweeps": o.sweeps}
    return ReproduceConfig.quick(**kw) if o.quick else ReproduceConfig(size=o.size, **kw)


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Measure; write results.json, the figures and report.md; ``(results, report)``."""
    from lodsprite.experiments.chen1999.report import write_plots, write_report
    from lodsprite.experiments.chen1999.run import reproduce_chen1999

    results = reproduce_chen1999(cfg, out_dir, single(progress, "reproduce chen1999"))
    return results, write_report(results, out_dir, write_plots(results, out_dir))


def summary(r: dict) -> Summary:
    """The report's headline rows: this run beside the paper's."""
    from lodsprite.experiments.chen1999.report import comparison_rows

    rows = [tuple(row[:3]) for row in comparison_rows(r) if row[0] in HEADLINE]
    return Summary(f"Chen et al. 1999 reproduced: {r['terrain']} {r['grid']}², {r['lod']}² "
                   f"LOD, {r['frames']} frames, ε = {r['epsilon']} px, {r['size'][0]}² px",
                   ("", "this run", "paper (1999)"), rows, [f"GL: {r['gl_renderer']}"])


EXPERIMENT = Experiment("chen1999", "Chen, Swan & Kaufman 1999 (LOD-sprite)", configure, run,
                        summary)
