"""Gumbau, Ripolles & Chover, the LODManager: ``lodsprite reproduce gumbau``.
The run is :mod:`.run`, the report :mod:`.report`."""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.gumbau.run.GumbauConfig` (the paper's scenes, or
    quick); no terrain or size option applies."""
    from lodsprite.experiments.gumbau.run import GumbauConfig

    return GumbauConfig.quick() if o.quick else GumbauConfig()


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """The crowd with and without the manager, at a target rate, the discrete baseline;
    results.json, Figure 5, plots, report.md."""
    from lodsprite.experiments.gumbau.report import write_outputs
    from lodsprite.experiments.gumbau.run import reproduce_gumbau

    r = reproduce_gumbau(cfg, progress)
    return r, write_outputs(r, out_dir)


def summary(r: dict) -> Summary:
    """With the manager against without: extractions, fps, LOD CPU, draw calls."""
    rows = [
        ("extractions", f"{r['extractions_with']:,}", f"{r['extractions_without']:,}"),
        ("fps (mean)", f"{r['fps_mean_with']:.2f}", f"{r['fps_mean_without']:.2f}"),
        ("LOD CPU ms / frame", f"{r['lod_cpu_ms_with']:.2f}", f"{r['lod_cpu_ms_without']:.2f}"),
        ("draw calls", f"{r['draw_calls_mean_with']:.0f}", f"{r['draw_calls_mean_without']:.0f}"),
        ("image difference (grey levels)", f"{r['image_diff_mean']:.3f}", ""),
        (f"target {r['target_fps']:g} fps: median / p99 ms",
         f"{r['frame_ms_median_at_target']:.1f} / {r['frame_ms_p99_at_target']:.1f}", ""),
    ]
    return Summary("Gumbau, Ripolles & Chover (LODManager) reproduced",
                   ("", "with the manager", "without"), rows)


EXPERIMENT = Experiment("gumbau", "Gumbau, Ripolles & Chover (LODManager)", configure, run,
                        summary)
