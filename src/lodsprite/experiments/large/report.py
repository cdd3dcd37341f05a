"""Plots and a Markdown report for ``reproduce large``
(:func:`lodsprite.experiments.large.run.reproduce_large`)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from lodsprite.files import atomic_write_bytes, save_figure, write_json
from lodsprite.report.values import fmt_fixed


def _series(r: dict, path: str) -> tuple[list[int], list[dict]]:
    first = r["config"]["paths"][0]
    sizes = sorted(r["sizes"], key=int)
    rows = [r["sizes"][s] if path == first else r["sizes"][s][path] for s in sizes]
    return [int(s) for s in sizes], rows


def _plot(r: dict, path: Path) -> Path:
    fig = Figure(figsize=(13, 3.8), dpi=100)
    cost, err, mem = (fig.add_subplot(1, 3, i) for i in (1, 2, 3))
    for p, style in zip(r["config"]["paths"], ("-", "--"), strict=False):
        n, rows = _series(r, p)
        for key, label in (("median_ms_adaptive", "adaptive 1 px"),
                           ("median_ms_sprite", "LOD-sprite, adaptive keys")):
            cost.plot(n, [v[key] for v in rows], "o" + style, label=f"{label} ({p})")
        for key, label in (("rmse_adaptive", "adaptive"), ("rmse_sprite", "LOD-sprite")):
            err.plot(n, [v[key] for v in rows], "o" + style, label=f"{label} ({p})")
        mem.plot(n, [v["peak_rss_mb"] for v in rows], "o" + style, label=p)
    cost.set(xscale="log", xlabel="terrain side (samples)", ylabel="median ms",
             title="frame cost against terrain size")
    err.set(xscale="log", xlabel="terrain side (samples)", ylabel="RMSE (grey levels)",
            title="image error against the reference")
    mem.set(xscale="log", xlabel="terrain side (samples)", ylabel="MB",
            title="peak resident memory (adaptive run)")
    for ax in (cost, err, mem):
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def _row(label: str, v: dict, tile: str) -> str:
    f = fmt_fixed
    ref = v["reference"]
    if "reference_vs_full_rmse" in v:
        ref += (f"; 0.25 px stand-in vs full: RMSE {f(v['reference_vs_full_rmse'], 2)}, "
                f"FLIP {f(v['reference_vs_full_flip'], 3)}")
    full = f(v["median_ms_full"], 0) if "median_ms_full" in v else "—"
    return (f"| {label} | {tile} | {full} | {f(v['median_ms_adaptive'], 2)} / "
            f"{f(v['p99_ms_adaptive'], 2)} | {f(v['median_ms_sprite'], 2)} / "
            f"{f(v['p99_ms_sprite'], 2)} | {f(v['speedup_sprite_vs_adaptive'], 2)}× | "
            f"{f(v['rmse_adaptive'], 2)} / {f(v['flip_adaptive'], 3)} | "
            f"{f(v['rmse_sprite'], 2)} / {f(v['flip_sprite'], 3)} | {v['keyframes_sprite']} | "
            f"{_equal(v)} | {ref} | {f(v['peak_rss_mb'], 0)} | {f(v['first_frame_s'], 2)} | "
            f"{v['tiles_loaded']} |")


def _equal(v: dict) -> str:
    """LOD-sprite at adaptive's RMSE or lower: ε, speedup, RMSE; or why none."""
    f = fmt_fixed
    e = v.get("equal_error")
    if e is None:
        best = min(v.get("sprite_sweep", [{"rmse": v["rmse_sprite"]}]), key=lambda s: s["rmse"])
        return f"none (lowest sprite RMSE {f(best['rmse'], 2)})"
    return f"ε {e['epsilon']:g}: {f(e['speedup'], 2)}× (RMSE {f(e['rmse'], 2)})"


HEADER = ["| side | tile s (MB/s) | median ms full | adaptive median / p99 ms | sprite median "
          "/ p99 ms | sprite speedup (total) | adaptive RMSE / FLIP | sprite RMSE / FLIP | "
          "keyframes | sprite at equal RMSE | reference | peak RSS MB | first frame s | "
          "tiles loaded |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]


def _table(r: dict, path: str) -> list[str]:
    f = fmt_fixed
    first = r["config"]["paths"][0]
    lines = list(HEADER)
    groups = [(s, r["sizes"][s]) for s in sorted(r["sizes"], key=int)]
    groups += sorted(r.get("terrains", {}).items())
    for key, res in groups:
        v = res if path == first else res[path]
        tile = (f"{f(res['tile_s'], 1)} ({f(res['tile_mb_per_s'], 1)})"
                if res.get("tile_s") and res.get("tile_mb_per_s") else "reused")
        label = f"{key}²" if key.isdigit() else f"{key} ({res['side']} a side)"
        lines.append(_row(label, v, tile))
    return lines


def write_outputs(r: dict, out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    write_json(out_dir / "results.json", r)
    plot = _plot(r, out_dir / "large_scaling.png")
    f = fmt_fixed
    c = r["config"]
    lines = ["# Large terrain — large", "",
             f"Fractal stores (tiled, seamless), {c['frames']} frames at {c['image']}² along "
             "each path; adaptive at "
             f"{c['sse']} px; LOD-sprite with keyframes by the adaptive renderer at "
             f"{c['key_sse']} px (proxy, ribbons and error metric from the store's level 0; "
             "coarse level of 16² up to 2k², then squares of 128 samples, at most 128²); "
             f"errors (RMSE in grey levels / mean FLIP) on frames {r['sample_frames']} "
             "against the reference named per row.  Sprite speedup: adaptive's total time "
             "over LOD-sprite's at ε = 1 px; at equal RMSE: the fastest LOD-sprite run of "
             f"ε in {[1.0, *c['sweep_eps']]} whose RMSE is at most adaptive's.  Full "
             "resolution's median is timed on the sampled frames."]
    for p in c["paths"]:
        lines += ["", f"## Path {p}", "", *_table(r, p)]
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
              "GPU memory in use: the adaptive renderer's GPU cache is a fixed atlas of the "
              "budget (`--gpu-mb`, 256 MB by default), allocated at start; llvmpipe has no "
              "query for the memory a driver holds.", "",
              f"![scaling]({plot.name})", ""]
    report = out_dir / "report.md"
    atomic_write_bytes(report, "\n".join(lines).encode())
    return report
