"""Swan, Arango & Nakshatrala (2002), distributed LOD-sprite: ``reproduce swan2002``.

The run is :mod:`.run` (the client and LOD servers in their set-ups, as processes; it
drives the distributed layer, so it is imported only when the experiment runs), the
report :mod:`.report`.
"""

from __future__ import annotations

from pathlib import Path

from lodsprite.experiments.base import Experiment, Options, StageProgress, Summary, single


def configure(o: Options):
    """A :class:`~lodsprite.experiments.swan2002.run.SwanConfig` from the options; checks
    ε and the client's options first."""
    from lodsprite.distributed.run import check_client_options, parse_max_error
    from lodsprite.errors import InputError
    from lodsprite.experiments.swan2002.run import SwanConfig

    if not o.epsilon > 0:
        raise InputError(f"--epsilon must be > 0 pixels, got {o.epsilon}")
    max_error = parse_max_error(None) if o.max_error is None else o.max_error
    check_client_options(o.pace, o.adopt, max_error)
    kw = {"terrain": o.terrain, "lod": o.lod, "adopt": o.adopt, "pace": o.pace,
          "epsilon": o.epsilon, "max_error": max_error, "links": o.links}
    if o.quick:  # its own 256² unless --size is given
        return SwanConfig.quick(**kw, **({"size": o.size} if o.size_given else {}))
    return SwanConfig(size=o.size, **kw)


def run(cfg, out_dir: Path, progress: StageProgress | None = None) -> tuple[dict, Path]:
    """Run the set-ups; write results.json, the figures and report.md."""
    from lodsprite.experiments.swan2002.report import write_plots, write_report
    from lodsprite.experiments.swan2002.run import reproduce_swan2002

    r = reproduce_swan2002(cfg, out_dir, single(progress, "reproduce swan2002 (set-ups)"))
    return r, write_report(r, out_dir, write_plots(r, out_dir))


def _ms(v: float | None, digits: int) -> str:
    return "—" if v is None else f"{v:.{digits}f}"


def summary(r: dict) -> Summary:
    """Client frame times by set-up beside the paper's, then the two client policies."""
    from lodsprite.experiments.paper_numbers import PAPER_2002
    from lodsprite.experiments.swan2002.report import policy_lines, setups_in

    rows = []
    for s in setups_in(r):
        x = r[s]
        if "skipped" in x:
            rows.append((s, "skipped", "", "", "", ""))
            continue
        rows.append((s, f"{x['client_ms_mean']:.2f}", f"{x['client_ms_std']:.2f}",
                     f"{x['client_ms_p99']:.2f}", _ms(x.get("sprites_per_keyframe"), 1),
                     _ms(x.get("delta_t_ms_mean"), 0)))
    d, n = PAPER_2002["separate"], PAPER_2002["same_cores"]
    rows.append(("paper distributed", f"{d['client_ms_mean']:g}", f"{d['client_ms_std']:g}",
                 "", f"{d['sprites_per_keyframe']:g}", f"{d['delta_t_ms_mean']:g}"))
    rows.append(("paper non-distributed", f"{n['client_ms_mean']:g}",
                 f"{n['client_ms_std']:g}", "", "", ""))
    cfg = r.get("config") or {}
    return Summary(f"Swan et al. 2002 reproduced: {cfg.get('terrain')}, {cfg.get('frames')} "
                   "frames", ("set-up", "client mean ms", "σ ms", "p99 ms",
                              "sprites/keyframe", "δt ms"), rows, policy_lines(r))


EXPERIMENT = Experiment("swan2002", "Swan, Arango & Nakshatrala 2002 (distributed)",
                        configure, run, summary)
