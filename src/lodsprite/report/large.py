"""Plots and a Markdown report for ``reproduce large``
(:func:`lodsprite.terrain.large.reproduce_large`)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from lodsprite.report.io import atomic_write_bytes, save_figure, write_json
from lodsprite.report.values import fmt_fixed


def _plot(r: dict, path: Path) -> Path:
    sizes = sorted(r["sizes"], key=int)
    n = [int(s) for s in sizes]
    fig = Figure(figsize=(10, 3.6), dpi=100)
    ax = fig.add_subplot(1, 2, 1)
    for key, label in (("median_ms_adaptive", "adaptive 1 px"),
                       ("median_ms_sprite", "LOD-sprite, adaptive keyframes")):
        ax.plot(n, [r["sizes"][s][key] for s in sizes], "o-", label=label)
    ax.set(xscale="log", xlabel="terrain side (samples)", ylabel="median ms",
           title="frame cost against terrain size")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(1, 2, 2)
    ax.plot(n, [r["sizes"][s]["peak_rss_mb"] for s in sizes], "o-")
    ax.set(xscale="log", xlabel="terrain side (samples)", ylabel="MB",
           title="peak resident memory (adaptive run)")
    fig.tight_layout()
    return save_figure(fig, path)


def write_outputs(r: dict, out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    write_json(out_dir / "results.json", r)
    plot = _plot(r, out_dir / "large_scaling.png")
    f = fmt_fixed
    c = r["config"]
    lines = ["# Large terrain — large", "",
             f"Fractal stores (tiled, seamless), the chen1999-shaped path, {c['frames']} frames "
             f"at {c['image']}²; adaptive at {c['sse']} px; LOD-sprite with keyframes by the "
             f"adaptive renderer at {c['key_sse']} px; errors (RMSE, grey levels) on frames "
             f"{r['sample_frames']} against the reference named per size.", "",
             "| side | tile s (MB/s) | median ms adaptive | p99 | median ms sprite | total s "
             "adaptive / sprite | RMSE adaptive | RMSE sprite | reference | peak RSS MB | "
             "first frame s | tiles loaded |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in sorted(r["sizes"], key=int):
        v = r["sizes"][s]
        tile = (f"{f(v['tile_s'], 1)} ({f(v['tile_mb_per_s'], 1)})" if v["tile_s"] is not None
                else "reused")
        ref = v["reference"]
        if "reference_vs_full_rmse" in v:
            ref += f" (0.25 px stand-in vs full: {f(v['reference_vs_full_rmse'], 2)})"
        lines.append(f"| {s} | {tile} | {f(v['median_ms_adaptive'], 2)} | "
                     f"{f(v['p99_ms_adaptive'], 2)} | {f(v['median_ms_sprite'], 2)} | "
                     f"{f(v['total_s_adaptive'], 2)} / {f(v['total_s_sprite'], 2)} | "
                     f"{f(v['rmse_adaptive'], 2)} | {f(v['rmse_sprite'], 2)} | {ref} | "
                     f"{f(v['peak_rss_mb'], 0)} | {f(v['first_frame_s'], 2)} | "
                     f"{v['tiles_loaded']} |")
    j = r.get("jacksboro")
    lines += [] if j is None else ["", "## 512² jacksboro, chen1999", "",
              f"LOD-sprite with adaptive keyframes: {f(r['speedup_sprite_vs_full_512'], 2)}× "
              f"faster than full resolution (plain LOD-sprite in the same run: "
              f"{f(j['speedup_plain_sprite'], 2)}×); RMSE against the plain 16² level "
              f"{f(r['rmse_ratio_sprite_vs_lod_512'], 3)} (plain LOD-sprite "
              f"{f(j['rmse_ratio_plain_sprite'], 3)}); {j['keyframes']} keyframes of "
              f"{f(j['mean_ms_keyframe'], 1)} ms, spriteframes {f(j['mean_ms_sprite'], 2)} ms."]
    h = r["huge"]
    lines += ["", f"65536²: needs up to {f(h['need_gb'], 1)} GB of disk (float32, all levels); "
                  f"{f(h['free_gb'], 1)} GB free here; run with `--huge`.", "",
              f"![scaling]({plot.name})", ""]
    report = out_dir / "report.md"
    atomic_write_bytes(report, "\n".join(lines).encode())
    return report
