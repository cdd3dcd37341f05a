"""What a viewer sees at a fixed display rate, ``lodsprite reproduce timecritical``: every
technique held to 30, 60 and 120 frames a second on any terrain or store and path, judged
over display time against the band-limited reference.  The run is :mod:`.run`, the report
:mod:`.report`."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary


def configure(o: Options):
    """A :class:`~lodsprite.experiments.timecritical.run.TimeCriticalConfig` from
    ``--terrain``, ``--path``, ``--size`` and ``--vdp`` (``--quick``: 256², the path's
    first 3 s)."""
    from lodsprite.experiments.timecritical.run import TimeCriticalConfig

    cfg = TimeCriticalConfig.quick() if o.quick else TimeCriticalConfig()
    cfg = replace(cfg, terrain=o.terrain, path=o.path or cfg.path, vdp_seconds=o.vdp)
    return replace(cfg, size=o.size) if o.size_given or not o.quick else cfg


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    from lodsprite.experiments.timecritical.report import write_outputs
    from lodsprite.experiments.timecritical.run import reproduce_timecritical

    r = reproduce_timecritical(cfg, out_dir, progress)
    return r, write_outputs(r, out_dir)


def summary(r: dict) -> Summary:
    """One row per technique and rate: frame times, missed slots, what the viewer saw."""
    from lodsprite.experiments.timecritical.report import rows

    out = [(row["technique"], row["rate"], f"{row['median_ms']:.1f} / {row['p99_ms']:.1f}",
            f"{row['missed_slots']:.2f}", f"{row['rmse_time_weighted']:.2f}",
            "—" if row["flicker"] is None else f"{row['flicker']:.2f}")
           for row in rows(r)]
    return Summary(f"Time-critical: {r['terrain']}, {r['path']}",
                   ("technique", "fps", "frame ms median / p99", "missed slots",
                    "time-weighted RMSE", "flicker"), out)


EXPERIMENT = Experiment("timecritical", "Every technique at 30/60/120 fps, judged over "
                        "display time", configure, run, summary)
