"""Chen, Swan & Kaufman (1999), LOD-sprite: ``lodsprite reproduce chen1999``.

The run is :mod:`.run` (timed LOD-sprite and full resolution along the paper's path, an
untimed quality replay, the Figs 10-12 sweeps; :data:`DEMO` is its shorter
configuration for ``lodsprite demo``), the report :mod:`.report` and
:mod:`.plots`; the summary table is a selection of the report's own rows.
"""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary, single

#: The report's rows the command line shows after a run.
HEADLINE = ("keyframes", "mean time, keyframe (ms)", "mean time, first spriteframe (ms)",
            "mean time, spriteframe (ms)", "total, full resolution (s)",
            "total, LOD-sprite (s)", "speedup, full ÷ LOD-sprite (×)",
            "RMSE, LOD-sprite vs ref (mean)", "RMSE, plain LOD vs ref (mean)",
            "flicker, LOD-sprite (mean over consecutive frames)",
            "RMSE ratio, LOD-sprite ÷ plain LOD")


def _settings(o: Options) -> dict:
    """The options' terrain and LOD-sprite settings as ``ReproduceConfig`` fields."""
    return {"terrain": o.terrain, "grid": o.grid, "lod": o.lod, "epsilon": o.epsilon,
            "visibility": o.visibility, "border": o.border, "guard_px": o.guard}


def configure(o: Options):
    """The paper's set-up (or the quick one) with the options' terrain and LOD-sprite
    settings: a :class:`~lodsprite.experiments.chen1999.run.ReproduceConfig`."""
    from lodsprite.experiments.chen1999.run import ReproduceConfig

    kw = {**_settings(o), "full_sample": o.full_sample, "sweeps": o.sweeps}
    return ReproduceConfig.quick(**kw) if o.quick else ReproduceConfig(size=o.size, **kw)


def configure_demo(o: Options):
    """``lodsprite demo``'s set-up: :meth:`ReproduceConfig.demo
    <lodsprite.experiments.chen1999.run.ReproduceConfig.demo>` (the whole path, Fig. 10,
    no ε sweeps), or with ``o.quick`` the quick run without the ε sweeps."""
    from lodsprite.experiments.chen1999.run import ReproduceConfig

    if o.quick:
        return ReproduceConfig.quick(**_settings(o), fig11_epsilon=())
    return ReproduceConfig.demo(**_settings(o))


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
#: ``lodsprite demo``: the same experiment in its demo configuration.
DEMO = Experiment("chen1999", EXPERIMENT.title, configure_demo, run, summary)
