"""Plots and a Markdown report for the Chen, Swan & Kaufman (1999) LOD-sprite experiment.

:func:`write_plots` turns the experiment runner's ``results`` dict (JSON-compatible)
into the paper's Figures 8-14 as PNGs; :func:`write_report` writes ``report.md``
comparing our numbers with the paper's (kept once, in :data:`PAPER`).

Every number in the outputs comes from ``results`` or :data:`PAPER`.  Missing
optional sections (``fig10``, ``fig11``, ``fig12``, ``images``) are skipped, and
missing or non-finite values (``None``, NaN, ``"inf"``) are shown as "—".
Figures are drawn on :class:`matplotlib.figure.Figure` objects with the Agg
canvas, never through pyplot's global state.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from itertools import zip_longest
from pathlib import Path
from typing import Any

from lodsprite.experiments.chen1999.plots import write_plots
from lodsprite.experiments.paper_numbers import PAPER, PAPER_KEYFRAME_FRACTION, RMSE_RATIO_TARGET
from lodsprite.files import atomic_write_bytes
from lodsprite.report.values import (
    DASH,
    count_type,
    fmt_fixed,
    fmt_g,
    fmt_int,
    fmt_size,
    fmt_square,
    fmt_text,
    num,
    ratio,
    section,
)

REPORT_NAME = "report.md"

__all__ = ["PAPER", "write_plots", "write_report"]


# --------------------------------------------------------------------------- report


def _cell(s: str) -> str:
    return s.replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines + [""]


def _path_phrase(path: Any) -> str:
    return "the camera path" if fmt_text(path) == DASH else f"the `{fmt_text(path)}` camera path"


def _description(r: dict) -> str:
    return (
        f"Experiment `{fmt_text(r.get('experiment'))}`: the `{fmt_text(r.get('terrain'))}` terrain "
        f"({fmt_square(r.get('grid'))} height field, {fmt_square(r.get('lod'))} LOD mesh for "
        f"spriteframes) rendered along {_path_phrase(r.get('path'))} for "
        f"{fmt_int(r.get('frames'))} frames at {fmt_size(r.get('size'))}, with error threshold "
        f"ε = {fmt_g(r.get('epsilon'))} px and the `{fmt_text(r.get('visibility'))}` visibility "
        f"rule. GL renderer: {fmt_text(r.get('gl_renderer'))}; "
        f"machine: {fmt_text(r.get('machine'))}."
    )


def _of(part: Any, whole: Any) -> str:
    return f"{fmt_int(part)} of {fmt_int(whole)}"


def _sprite_count(r: dict, key: str, frame_type: str) -> Any:
    return r[key] if key in r else count_type(r, frame_type)


def _rmse_verdict(ratio: Any) -> str:
    f = num(ratio)
    if f is None:
        return f"target ≤ {RMSE_RATIO_TARGET:g}"
    return f"target ≤ {RMSE_RATIO_TARGET:g}: {'met' if f <= RMSE_RATIO_TARGET else 'not met'}"


def _timing_rows(r: dict) -> list[list[str]]:
    p = PAPER
    return [
        ["mean time, keyframe (ms)", fmt_fixed(r.get("mean_ms_keyframe"), 1),
         fmt_fixed(p["mean_ms_keyframe"], 1), "paper says 'microseconds'; its totals give ms"],
        ["mean time, first spriteframe (ms)", fmt_fixed(r.get("mean_ms_first_sprite"), 1),
         fmt_fixed(p["mean_ms_first_sprite"], 1), "frame after a keyframe (sprite upload)"],
        ["mean time, spriteframe (ms)", fmt_fixed(r.get("mean_ms_sprite"), 1),
         fmt_fixed(p["mean_ms_sprite"], 1), ""],
        ["keyframe ÷ spriteframe time (×)",
         fmt_fixed(ratio(r.get("mean_ms_keyframe"), r.get("mean_ms_sprite")), 2),
         fmt_fixed(ratio(p["mean_ms_keyframe"], p["mean_ms_sprite"]), 2), "ratio: comparable"],
        ["total, full resolution (s)", fmt_fixed(r.get("total_s_full"), 2),
         fmt_fixed(p["total_s_full"], 2), "sampled and scaled" if r.get("full_sampled") else ""],
        ["total, LOD-sprite (s)", fmt_fixed(r.get("total_s_sprite"), 2),
         fmt_fixed(p["total_s_sprite"], 2), ""],
        ["total, plain LOD (s)", fmt_fixed(r.get("total_s_lod"), 2), DASH, "not in the paper"],
        ["speedup, full ÷ LOD-sprite (×)", fmt_fixed(r.get("speedup"), 2),
         fmt_fixed(p["speedup"], 2), "ratio: comparable"],
    ]


def _quality_rows(r: dict) -> list[list[str]]:
    claim = "much closer to full res (Figs 13–14), no number"
    return [
        ["RMSE, LOD-sprite vs ref (mean)",
         fmt_fixed(r.get("rmse_mean"), 2), DASH, "ref: level 0, 4×4 samples a pixel"],
        ["RMSE, plain LOD vs ref (mean)", fmt_fixed(r.get("rmse_lod_mean"), 2),
         DASH, ""],
        ["flicker, LOD-sprite (mean over consecutive frames)",
         fmt_fixed(r.get("flicker_mean"), 2), DASH,
         "RMS of (I_t − I_t−1) − (R_t − R_t−1)"],
        ["RMSE, plain LOD + border ribbons vs ref (mean)",
         fmt_fixed(r.get("rmse_lod_border_mean"), 2), DASH, "ablation: the ribbons alone"],
        ["RMSE ratio, LOD-sprite ÷ plain LOD", fmt_fixed(r.get("rmse_ratio"), 3), claim,
         _rmse_verdict(r.get("rmse_ratio"))],
        ["PSNR, LOD-sprite vs ref (dB, mean)", fmt_fixed(r.get("psnr_mean"), 2), DASH, ""],
        ["PSNR, plain LOD vs ref (dB, mean)", fmt_fixed(r.get("psnr_lod_mean"), 2), DASH, ""],
        ["SSIM, LOD-sprite vs ref (mean)", fmt_fixed(r.get("ssim_mean"), 4), DASH, ""],
        ["SSIM, plain LOD vs ref (mean)", fmt_fixed(r.get("ssim_lod_mean"), 4), DASH, ""],
    ]


def comparison_rows(r: dict) -> list[list[str]]:
    """The ours-vs-paper rows: ``[quantity, ours, paper, note]`` cell strings."""
    p = PAPER
    counts = [
        ["keyframes", _of(r.get("keyframes"), r.get("frames")),
         _of(p["keyframes"], p["frames"]), ""],
        ["keyframe fraction", fmt_fixed(r.get("keyframe_fraction"), 3),
         fmt_fixed(PAPER_KEYFRAME_FRACTION, 3), ""],
        ["first spriteframes", fmt_int(_sprite_count(r, "first_sprite_frames", "first_sprite")),
         fmt_int(p["first_sprite_frames"]), "paper: one per keyframe"],
        ["spriteframes", fmt_int(_sprite_count(r, "sprite_frames", "sprite")),
         fmt_int(p["sprite_frames"]), ""],
    ]
    return counts + _timing_rows(r) + _quality_rows(r)


def _comparison_notes(r: dict) -> list[str]:
    p = PAPER
    accounted = p["keyframes"] + p["first_sprite_frames"] + p["sprite_frames"]
    notes = [
        f"The paper's times were measured in 1999 on an SGI Power Challenge with "
        f"InfiniteReality graphics; ours were measured in this run on "
        f"{fmt_text(r.get('gl_renderer'))}, so only ratios (fractions, speedup, time ratios) "
        f"compare, not absolute times.",
        f"The paper's frame counts add up to {accounted:.0f} "
        f"({p['keyframes']:.0f} + {p['first_sprite_frames']:.0f} + {p['sprite_frames']:.0f}), "
        f"not {p['frames']:.0f}; its full-resolution total is "
        f"{fmt_fixed(1000 * p['total_s_full'] / p['frames'], 1)} ms per frame, which is why its "
        f"'microseconds' are read as milliseconds.",
    ]
    if num(r.get("quality_frames")) is not None:
        stride = fmt_int(r.get("quality_stride"))
        notes.append(
            f"RMSE, PSNR and SSIM are means over {fmt_int(r.get('quality_frames'))} frames "
            f"(stride {stride}) against the band-limited reference of the same view (level "
            f"0 drawn by its own code at 4×4 samples a pixel, box-filtered in linear light)."
        )
    if r.get("border") is not None:
        notes.append(
            f"LOD-sprite drew the {fmt_int(r.get('lod'))}² level "
            f"{'with' if r.get('border') else 'without'} border ribbons (the full-resolution "
            f"outline of the terrain's edges) and rendered keyframes with a "
            f"{fmt_int(r.get('guard_px'))}-pixel guard band; the plain LOD is the paper's "
            f"{fmt_int(r.get('lod'))}² level alone."
        )
    if r.get("full_sampled"):
        notes.append(
            f"Full-resolution time was measured on {fmt_int(r.get('full_sample_frames'))} evenly "
            f"spaced frames and scaled to all {fmt_int(r.get('frames'))} frames."
        )
    return [f"- {n}" for n in notes] + [""]


def _series_table(sec: dict | None, columns: Sequence[tuple[str, str, Callable]]) -> list[str]:
    if not sec:
        return []
    series = [sec.get(key) or [] for _, key, _ in columns]
    rows = [[fmt(v) for v, (_, _, fmt) in zip(vals, columns, strict=True)]
            for vals in zip_longest(*series)]
    return _table([head for head, _, _ in columns], rows)


def _fig10_table(r: dict) -> list[str]:
    return _series_table(section(r, "fig10"), [
        ("frames", "frames", fmt_int), ("keyframes", "keyframes", fmt_int),
        ("keyframe fraction", "keyframe_fraction", lambda v: fmt_fixed(v, 3))])


def _fig11_table(r: dict) -> list[str]:
    return _series_table(section(r, "fig11"), [
        ("ε (px)", "epsilon", fmt_g), ("keyframes", "keyframes", fmt_int),
        ("keyframe fraction", "keyframe_fraction", lambda v: fmt_fixed(v, 3)),
        ("RMSE LOD-sprite", "rmse", lambda v: fmt_fixed(v, 2)),
        ("RMSE plain LOD", "rmse_lod", lambda v: fmt_fixed(v, 2)),
        ("ratio", "rmse_ratio", lambda v: fmt_fixed(v, 3))])


def _fig12_table(r: dict) -> list[str]:
    return _series_table(section(r, "fig12"), [
        ("ε (px)", "epsilon", fmt_g),
        ("total LOD-sprite (s)", "total_s_sprite", lambda v: fmt_fixed(v, 2)),
        ("speedup (×)", "speedup", lambda v: fmt_fixed(v, 2))])


def _frame_of(r: dict, name: str) -> str:
    spec = (r.get("images") or {}).get(name)
    if not isinstance(spec, dict):
        return DASH
    key, at = num(spec.get("keyframe")), num(spec.get("keyframe_frame"))
    if key is None:
        return fmt_text(spec.get("frame"))
    where = "" if at is None else f", rendered at frame {at:.0f}"
    ahead = " from a viewpoint ahead of the viewer" if spec.get("keyframe_ahead") else ""
    return f"{fmt_text(spec.get('frame'))} (keyframe {key:.0f}{where}{ahead})"


def _captions(r: dict) -> dict[str, tuple[str, str]]:
    """File name -> (section heading, one-line caption)."""
    p, lod, grid = PAPER, fmt_square(r.get("lod")), fmt_square(r.get("grid"))
    return {
        "fig08_error.png": ("Fig. 8 — error per frame",
            f"Error (px) of each frame; red dots mark the {fmt_int(r.get('keyframes'))} keyframes "
            f"(error 0), the dashed line is ε = {fmt_g(r.get('epsilon'))} px."),
        "fig09_time.png": ("Fig. 9 — render time per frame",
            f"Time per frame (ms, log scale) by frame type, full resolution as a faint line; "
            f"the paper's three levels were {p['mean_ms_keyframe']:.0f} / "
            f"{p['mean_ms_first_sprite']:.0f} / {p['mean_ms_sprite']:.0f} ms on its SGI."),
        "fig10_keyframes_vs_frames.png": ("Fig. 10 — keyframe fraction vs frames",
            "Fraction of keyframes as the same path is rendered with more frames; the star is "
            "the paper's 460-frame run."),
        "fig11_keyframes_vs_epsilon.png": ("Fig. 11 — keyframe fraction vs ε",
            "Fraction of keyframes against the error threshold (the paper's caption says "
            "'update rate', its text keyframe fraction); the star is the paper's ε = 1 px run."),
        "fig12_speedup_vs_epsilon.png": ("Fig. 12 — speedup vs ε",
            f"Speedup of LOD-sprite over full resolution against ε; the star is the paper's "
            f"only reported value ({p['speedup']:.2f} at ε = 1 px, SGI IR, 1999)."),
        "fig13.png": ("Fig. 13 — full resolution, plain LOD, LOD-sprite",
            f"Frame {_frame_of(r, 'fig13')}: (a) full {grid} height field, (b) plain {lod} "
            f"LOD, (c) LOD-sprite on the same {lod} mesh, textured from the keyframe (f), "
            f"re-rendered from the viewpoint and projection the run logged for it."),
        "fig14.png": ("Fig. 14 — with difference images",
            f"Frame {_frame_of(r, 'fig14')}: as Fig. 13 plus the differences (d) |a−b| and "
            f"(e) |a−c|, shown on the same 0–255 grey scale."),
    }


FIGURE_TABLES: dict[str, Callable[[dict], list[str]]] = {
    "fig10_keyframes_vs_frames.png": _fig10_table,
    "fig11_keyframes_vs_epsilon.png": _fig11_table,
    "fig12_speedup_vs_epsilon.png": _fig12_table,
}


def _link(path: Path, out_dir: Path) -> str:
    return Path(os.path.relpath(Path(path), out_dir)).as_posix()


def _figure_sections(r: dict, out_dir: Path, plots: Sequence[Path]) -> list[str]:
    by_name = {Path(p).name: Path(p) for p in plots}
    lines: list[str] = []
    skipped = []
    for name, (heading, caption) in _captions(r).items():
        if name not in by_name:
            skipped.append(heading.split(" — ")[0])
            continue
        lines += [f"## {heading}", "", f"![{heading}]({_link(by_name[name], out_dir)})", "",
                  caption, ""]
        lines += FIGURE_TABLES.get(name, lambda _r: [])(r)
    if skipped:
        sweeps = (" The ε sweeps (Figs. 11–12) are run by `lodsprite reproduce chen1999`."
                  if "Fig. 11" in skipped else "")
        lines += [f"Not produced in this run (no data): {', '.join(skipped)}.{sweeps}", ""]
    return lines


def write_report(results: dict, out_dir: Path, plots: list[Path]) -> Path:
    """Write ``out_dir/report.md``: description, ours-vs-paper table, one section per figure.

    ``plots`` are the PNGs from :func:`write_plots`; a figure whose PNG is not among
    them is listed as not produced.  Returns the report's path.
    """
    out_dir = Path(out_dir)
    title = f"# Chen, Swan & Kaufman (1999) LOD-sprite — {fmt_text(results.get('experiment'))}"
    lines = [title, "", _description(results), "", "## Ours vs paper", ""]
    lines += _table(["quantity", "ours", "paper", "note"], comparison_rows(results))
    lines += _comparison_notes(results)
    lines += _figure_sections(results, out_dir, plots)
    path = out_dir / REPORT_NAME
    atomic_write_bytes(path, "\n".join(lines).rstrip("\n").encode() + b"\n")
    return path
