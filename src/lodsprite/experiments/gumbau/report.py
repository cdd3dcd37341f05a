"""Plots, Figure 5's images and a Markdown report for the LODManager reproduction
(:func:`lodsprite.experiments.gumbau.run.reproduce_gumbau`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lodsprite.experiments.paper_numbers import PAPER_GUMBAU
from lodsprite.files import atomic_write_bytes, save_figure, write_json, write_png
from lodsprite.report.values import fmt_fixed


def scenes(r: dict) -> dict[str, str]:
    c = r["config"]
    return {"crowd": f"{c['objects']} objects",
            "crowd_trees": f"{c['objects']} objects + {c['trees']} trees"}


def _fig6(r: dict, path: Path) -> Path:
    fig = Figure(figsize=(11, 6.5), dpi=100)
    for col, (scene, title) in enumerate(scenes(r).items()):
        ax = fig.add_subplot(2, 2, col + 1)
        ax2 = fig.add_subplot(2, 2, col + 3)
        for mode, label in (("manager", "with LODManager"), ("independent", "without")):
            f = r["runs"][f"{scene}_{mode}"]["frames"]
            ax.plot(f["fps"], lw=0.8, label=label)
            ax2.plot(np.array(f["triangles"]) / 1e3, lw=0.8, label=label)
        ax.set(xlabel="frame", ylabel="fps", title=f"Fig. 6 — fps, {title}")
        ax2.set(xlabel="frame", ylabel="triangles (thousands)", title="triangles per frame")
        ax.legend(fontsize=8)
        ax2.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def _target(r: dict, path: Path) -> Path:
    f = r["runs"]["crowd_target"]["frames"]
    fig = Figure(figsize=(10, 3.4), dpi=100)
    ax = fig.add_subplot(1, 2, 1)
    ax.plot(f["ms"], lw=0.8)
    ax.axhline(1e3 / r["target_fps"], color="k", ls="--", lw=0.8, label="target")
    ax.set(xlabel="frame", ylabel="ms", title=f"frame time at a {r['target_fps']:g} fps target")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(1, 2, 2)
    ax.plot(f["exponent"], lw=0.8)
    ax.set(xlabel="frame", ylabel="p in dlof = lod^p", title="the feedback's exponent")
    fig.tight_layout()
    return save_figure(fig, path)


def figure5(with_img: np.ndarray, without_img: np.ndarray) -> np.ndarray:
    """Figure 5: the two frames above their per-pixel difference (red where they differ),
    ``(3h, w, 3) uint8``."""
    diff = np.abs(with_img.astype(np.int16) - without_img.astype(np.int16)).max(axis=2) > 0
    red = np.full_like(with_img, 255)
    red[diff] = (220, 0, 0)
    return np.concatenate([with_img, without_img, red], axis=0)


def write_outputs(r: dict, out_dir: Path) -> Path:
    """results.json, the plots, Figure 5 and report.md; returns the report's path."""
    out_dir = Path(out_dir)
    with_img, without_img, frame = r.pop("_figure5")
    r["figure5_frame"] = frame
    write_json(out_dir / "results.json", r)
    write_png(out_dir / "fig05_with_without_diff.png", figure5(with_img, without_img))
    plots = [_fig6(r, out_dir / "fig06_fps_triangles.png"),
             _target(r, out_dir / "target_fps.png")]
    report = out_dir / "report.md"
    atomic_write_bytes(report, "\n".join(_lines(r, plots)).encode())
    return report


def _lines(r: dict, plots: list[Path]) -> list[str]:
    f = fmt_fixed
    c, p = r["config"], PAPER_GUMBAU
    runs = r["runs"]
    lines = [
        "# Gumbau, Ripolles & Chover — LODManager — gumbau", "",
        f"{c['objects']} ogres (2,240 triangles, to 10 %) and {c['trees']} trees (94,656 "
        f"triangles, to 10 %) on a ground, a {c['frames']}-frame walkthrough, "
        f"{c['size'][0]}×{c['size'][1]}, N_T = {c['slots']}, N_a = {c['active']}; GL "
        f"`{r['gl_renderer']}`. Paper: {p['objects']} ogres of {p['ogre_triangles']:,} "
        f"triangles, {p['trees']} trees of {p['tree_triangles']:,}; it shows fps only in "
        "plots (Figure 6).", "",
        "## With and without the manager (Figure 6)", "",
        "| scene | mode | fps (mean) | median ms | p99 ms | extractions | LOD CPU ms/frame | "
        "draw calls | triangles |", "|---|---|---|---|---|---|---|---|---|"]
    for scene, title in scenes(r).items():
        for mode in ("manager", "independent"):
            s = runs[f"{scene}_{mode}"]["summary"]
            lines.append(f"| {title} | {'with' if mode == 'manager' else 'without'} | "
                         f"{f(s['fps_mean'], 2)} | {f(s['median_ms'], 1)} | "
                         f"{f(s['p99_ms'], 1)} | {s['extractions_total']:,} | "
                         f"{f(s['lod_cpu_ms_mean'], 2)} | {f(s['draw_calls_mean'], 0)} | "
                         f"{s['triangles_mean']:,.0f} |")
    ratio_ext = r["extractions_without"] / max(1, r["extractions_with"])
    lines += ["", f"{c['objects']} objects: {ratio_ext:,.0f}× fewer extractions with the manager "
                  f"(target ≥ 10×), fps {f(r['fps_mean_with'] / r['fps_mean_without'], 2)}× "
                  f"(target ≥ 1.5×), image difference {f(r['image_diff_mean'], 3)} grey "
                  f"levels on average over frames {r['image_diff_frames']} (target ≤ 2).", "",
              "## Figure 5", "",
              f"Frame {r['figure5_frame']}: with the manager (top), without (middle), pixels "
              "that differ in red (bottom).", "", "![fig05](fig05_with_without_diff.png)", "",
              "## Holding a frame rate", ""]
    t = runs["crowd_target"]["summary"]
    target_ms = 1e3 / r["target_fps"]
    lines += [f"Target {r['target_fps']:g} fps ({f(target_ms, 1)} ms): median "
              f"{f(t['median_ms'], 1)} ms ({f(t['median_ms'] / target_ms, 3)}× "
              f"the target, within 10 % wanted), p99 {f(t['p99_ms'], 1)} ms "
              f"({f(t['p99_ms'] / target_ms, 2)}×, ≤ 1.5 wanted), "
              f"{t['triangles_mean']:,.0f} triangles a frame, final exponent "
              f"{f(t['exponent_final'], 2)}.", "",
              "## Baseline (b): discrete LODs by screen size, with hysteresis", "",
              "| mode | fps | median ms | triangles | draw calls | LOD switches/s |",
              "|---|---|---|---|---|---|"]
    for name, label in (("crowd_manager", "LODManager"), ("crowd_independent", "without"),
                        ("crowd_discrete", "discrete chain")):
        s = runs[name]["summary"]
        lines.append(f"| {label} | {f(s['fps_mean'], 2)} | {f(s['median_ms'], 1)} | "
                     f"{s['triangles_mean']:,.0f} | {f(s['draw_calls_mean'], 0)} | "
                     f"{f(s['switches_per_s'], 0)} |")
    lines += ["", "## Plots", ""] + [f"![{pl.stem}]({pl.name})" for pl in plots] + [""]
    return lines
