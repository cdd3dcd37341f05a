"""Scoggins, Machiraju & Moorhead (2000), LOD matching by error profiles:
``lodsprite reproduce scoggins2000``.  The run is :mod:`.run`, the report :mod:`.report`."""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.scoggins2000.run.ScogginsConfig`: the options'
    terrain (the mountain) and image size."""
    from lodsprite.experiments.scoggins2000.run import ScogginsConfig

    if o.quick:
        return ScogginsConfig.quick(terrain=o.terrain)
    return ScogginsConfig(terrain=o.terrain, size=o.size)


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Profiles, the sphereflake spiral, the comparison; results.json, tables, figures,
    report.md."""
    from lodsprite.experiments.scoggins2000.report import write_outputs
    from lodsprite.experiments.scoggins2000.run import reproduce_scoggins2000

    r = reproduce_scoggins2000(cfg, progress)
    report, _ = write_outputs(r, out_dir)
    return r, report


def summary(r: dict) -> Summary:
    """Profile times and sphereflake triangles beside the paper's; profile against SSE."""
    from lodsprite.experiments.paper_numbers import PAPER_2000 as P

    rows = [
        ("profile s, sphere family", f"{r['profile_s_sphere']:.1f}",
         f"{P['profile_min_sphere'] * 60}"),
        ("profile s, mountain", f"{r['profile_s_mountain']:.1f}",
         f"{P['profile_min_mountain'] * 60}"),
        ("sphereflake triangles, full", f"{r['snowflake_triangles_full']:,}",
         f"{P['snowflake_triangles_full']:,}"),
        ("far sphereflake, CSF / no CSF", f"{r['snowflake_triangles_far_csf']:,} / "
         f"{r['snowflake_triangles_far_nocsf']:,}", ""),
        ("RMSE profile / SSE (equal triangles)",
         f"{r['rmse_profile']:.3f} / {r['rmse_sse']:.3f}", ""),
        ("FLIP profile / SSE", f"{r['flip_profile']:.4f} / {r['flip_sse']:.4f}", ""),
    ]
    return Summary("Scoggins et al. 2000 reproduced", ("", "this run", "paper"), rows)


EXPERIMENT = Experiment("scoggins2000", "Scoggins, Machiraju & Moorhead 2000 (LOD matching)",
                        configure, run, summary)
