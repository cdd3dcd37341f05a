"""The time-critical comparison's outputs: ``results.json``, ``timecritical.csv``, the plot
of time-weighted error against display rate (one curve per technique, error bars the
spread over the repeats) and ``report.md``."""

from __future__ import annotations

from pathlib import Path

from lodsprite.files import atomic_write_bytes, save_figure, write_csv, write_json

COLUMNS = ("path", "technique", "rate", "median_ms", "p99_ms", "rmse_time_weighted",
           "flip_time_weighted", "flicker", "rmse_worst_second", "missed_slots",
           "display_fps", "latency_ms_mean", "cvvdp_jod", "frames", "runs")


def rows(r: dict) -> list[dict]:
    """One row per path, technique and display rate (the median run's figures)."""
    out = []
    for path, techs in r["timecritical"].items():
        for tech, rates in techs.items():
            for rate, f in rates.items():
                out.append({"path": path, "technique": tech, "rate": rate,
                            **{k: f.get(k) for k in COLUMNS[3:]}})
    return out


def plot(r: dict, png: Path) -> Path:
    """Time-weighted RMSE against display rate, a curve per technique (bars: min-max over
    the repeats), per path."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    paths = r["timecritical"]
    fig = Figure(figsize=(6.4, 4.2 * len(paths)), dpi=120)
    axes = fig.subplots(len(paths), 1, squeeze=False)[:, 0]
    for ax, (path, techs) in zip(axes, paths.items(), strict=True):
        for i, (tech, rates) in enumerate(techs.items()):
            xs = [float(k) for k in rates]
            ys = [rates[k]["rmse_time_weighted"] for k in rates]
            lo = [y - rates[k].get("rmse_time_weighted_spread", [y, y])[0]
                  for k, y in zip(rates, ys, strict=True)]
            hi = [rates[k].get("rmse_time_weighted_spread", [y, y])[1] - y
                  for k, y in zip(rates, ys, strict=True)]
            ax.errorbar(xs, ys, yerr=[lo, hi], fmt="o-", color=f"C{i}", label=tech,
                        capsize=3, lw=1.5, ms=4)
        ax.set_xscale("log")
        ax.set_xticks([float(k) for k in next(iter(techs.values()))])
        ax.set_xticklabels([k for k in next(iter(techs.values()))])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("display rate (frames a second)")
        ax.set_ylabel("time-weighted RMSE (grey levels)")
        ax.set_title(f"{r['terrain']}, {path}: what the viewer sees")
        ax.grid(True, alpha=0.3)
        ax.legend()
    return save_figure(fig, png)


def _f(v, digits: int = 2) -> str:
    return "—" if v is None or v != v else f"{v:.{digits}f}"


def _spread(f: dict, key: str, digits: int = 2) -> str:
    s = f.get(f"{key}_spread")
    return "" if not s else f" ({_f(s[0], digits)}–{_f(s[1], digits)})"


def write_outputs(r: dict, out_dir: Path) -> Path:
    """results.json, timecritical.csv, timecritical.png and report.md; the report's path."""
    out_dir = Path(out_dir)
    write_json(out_dir / "results.json", r)
    write_csv(out_dir / "timecritical.csv", rows(r), COLUMNS)
    png = plot(r, out_dir / "timecritical.png")
    cfg = r["config"]
    lines = [f"# Time-critical rendering: {r['terrain']}, {r['path']}", "",
             f"Each technique plays the path in real time at each display rate ({cfg['size']}² "
             f"pixels, {cfg['repeats']} runs each); a display slot it misses keeps the "
             "previous image; every frame is drawn for the viewpoint predicted at its "
             f"display time (one predictor for all: {cfg.get('predictor', 'kalman')}).  "
             "The image on screen is judged "
             f"against the band-limited reference at pairs of display ticks every "
             f"{cfg['judge_every_s']:g} s of path time (RMSE, flicker; FLIP every "
             f"{cfg['flip_every']}th pair), so an image held long counts long.  Figures: "
             "the run of median time-weighted RMSE, (min–max) over the runs.", "",
             f"Reference: {r['reference']}; {r['reference_images']} reference images drawn.",
             "", "| technique | rate | frame ms median / p99 | missed slots | "
             "time-weighted RMSE | FLIP | flicker | worst second RMSE |"
             + (" ColorVideoVDP (JOD) |" if cfg.get("vdp_seconds") else ""),
             "|---|---|---|---|---|---|---|---|" + ("---|" if cfg.get("vdp_seconds") else "")]
    for row_ in rows(r):
        f = r["timecritical"][row_["path"]][row_["technique"]][row_["rate"]]
        lines.append(
            f"| {row_['technique']} | {row_['rate']} | {_f(f['median_ms'], 1)} / "
            f"{_f(f['p99_ms'], 1)} | {_f(f['missed_slots'])} | "
            f"{_f(f['rmse_time_weighted'])}{_spread(f, 'rmse_time_weighted')} | "
            f"{_f(f.get('flip_time_weighted'), 3)} | {_f(f.get('flicker'))} | "
            f"{_f(f.get('rmse_worst_second'))} |"
            + (f" {_f(f.get('cvvdp_jod'))}{_spread(f, 'cvvdp_jod')} |"
               if cfg.get("vdp_seconds") else ""))
    if cfg.get("vdp_seconds"):
        lines += ["", f"ColorVideoVDP: {cfg['vdp_seconds']:g} s of each run, centred, every "
                  "display tick against the reference's, on cvvdp's standard_fhd display "
                  "(JOD: 10 is indistinguishable from the reference)."]
    lines += ["", f"![time-weighted error against display rate]({png.name})", ""]
    report = out_dir / "report.md"
    atomic_write_bytes(report, "\n".join(lines).encode())
    return report


__all__ = ["COLUMNS", "plot", "rows", "write_outputs"]
