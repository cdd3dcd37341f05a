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

import io
import math
import os
from collections.abc import Callable, Sequence
from itertools import zip_longest
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter
from PIL import Image

from lodsprite.report.io import _atomic_write_bytes

#: The paper's headline numbers (§4; 460 frames, ε = 1 px, SGI Power Challenge with
#: InfiniteReality graphics).  Times in ms: the paper's "microseconds" is a typo,
#: as its totals show (383.2 s / 460 frames ≈ 833 ms per full-resolution frame).
PAPER: dict[str, float] = {
    "keyframes": 28,
    "frames": 460,
    "epsilon": 1.0,
    "mean_ms_keyframe": 830,
    "mean_ms_first_sprite": 36,
    "mean_ms_sprite": 15,
    "total_s_full": 383.2,
    "total_s_sprite": 31.1,
    "speedup": 12.32,
    "sprite_frames": 403,
    "first_sprite_frames": 28,
}

#: Target for (mean RMSE of LOD-sprite) / (mean RMSE of plain LOD): our reading of the
#: paper's qualitative claim (Figs 13-14) that LOD-sprite is "much closer" to full res.
RMSE_RATIO_TARGET = 0.5

DPI = 110
DASH = "—"
REPORT_NAME = "report.md"

FRAME_STYLES = (  # (type, legend label, results key of its mean, colour, marker)
    ("keyframe", "keyframe", "mean_ms_keyframe", "tab:red", "o"),
    ("first_sprite", "first spriteframe", "mean_ms_first_sprite", "tab:orange", "s"),
    ("sprite", "spriteframe", "mean_ms_sprite", "tab:blue", "."),
)

PlotFn = Callable[[dict, Path], "Path | None"]


# --------------------------------------------------------------------------- values


def _num(v: Any) -> float | None:
    """``v`` as a finite float; None for None, NaN, ±inf, "inf"/"nan" strings, non-numbers."""
    if v is None or isinstance(v, bool):
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _fixed(v: Any, decimals: int) -> str:
    """Fixed-point with ``decimals``; values too small to show that way get 2 significant digits."""
    f = _num(v)
    if f is None:
        return DASH
    if f != 0 and abs(f) < 10.0 ** (1 - decimals):
        return f"{f:#.2g}"
    return f"{f:.{decimals}f}"


def _int(v: Any) -> str:
    f = _num(v)
    return DASH if f is None else f"{f:.0f}"


def _g(v: Any) -> str:
    f = _num(v)
    return DASH if f is None else f"{f:g}"


def _text(v: Any) -> str:
    """A free-text field (renderer, machine, path...) as one line; missing -> "—"."""
    if v is None or v == "":
        return DASH
    if isinstance(v, dict):
        return ", ".join(f"{k}: {_text(x)}" for k, x in v.items())
    if isinstance(v, list | tuple):
        return ", ".join(_text(x) for x in v)
    return " ".join(str(v).split())


def _square(v: Any) -> str:
    """Grid size as ``512²`` (an int, or ``[n, n]``) or ``w×h``."""
    if isinstance(v, list | tuple):
        if len(v) == 2 and v[0] == v[1]:
            return f"{v[0]}²"
        return "×".join(str(x) for x in v) if v else DASH
    return DASH if v is None else f"{v}²"


def _size(v: Any) -> str:
    if isinstance(v, list | tuple) and len(v) == 2:
        return f"{v[0]}×{v[1]} px"
    return _text(v)


def _ratio(a: Any, b: Any) -> float | None:
    fa, fb = _num(a), _num(b)
    return None if fa is None or not fb else fa / fb


def _arr(values: Any) -> np.ndarray:
    """A list of numbers as a float array, NaN where a value is missing or not finite."""
    vals = [] if values is None else list(values)
    return np.array([np.nan if _num(x) is None else float(x) for x in vals], dtype=float)


def _per_frame(results: dict) -> dict:
    pf = results.get("per_frame")
    return pf if isinstance(pf, dict) else {}


def _type_mask(results: dict, frame_type: str, n: int) -> np.ndarray:
    types = list(_per_frame(results).get("type") or [])[:n]
    return np.array([t == frame_type for t in types] + [False] * (n - len(types)), dtype=bool)


def _count_type(results: dict, frame_type: str) -> int | None:
    types = _per_frame(results).get("type")
    return None if types is None else sum(t == frame_type for t in types)


def _section(results: dict, key: str) -> dict | None:
    sec = results.get(key)
    return sec if isinstance(sec, dict) and sec else None


# --------------------------------------------------------------------------- figures


def _figure(width: float = 7.0, height: float = 4.2) -> tuple[Figure, Axes]:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _save(fig: Figure, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    _atomic_write_bytes(path, buf.getvalue())
    return path


def _paper_fraction() -> float:
    return PAPER["keyframes"] / PAPER["frames"]


def _plot_fig08(results: dict, out_dir: Path) -> Path | None:
    err = _arr(_per_frame(results).get("error_px"))
    if err.size == 0:
        return None
    x = np.arange(err.size)
    fig, ax = _figure()
    ax.plot(x, err, "-", color="tab:blue", lw=0.9, marker=".", ms=3, label="error per frame")
    kf = _type_mask(results, "keyframe", err.size)
    if kf.any():
        for xk in x[kf]:
            ax.axvline(xk, color="tab:red", lw=0.5, alpha=0.25)
        ax.plot(x[kf], np.nan_to_num(err[kf]), "o", color="tab:red", ms=4,
                label=f"keyframe ({int(kf.sum())})")
    eps = _num(results.get("epsilon"))
    if eps is not None:
        ax.axhline(eps, color="black", ls="--", lw=1, label=f"ε = {eps:g} px")
    ax.set(xlabel="frame number", ylabel="error (px)", title="Fig. 8 — error per frame")
    ax.set_ylim(bottom=0)
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir / "fig08_error.png")


def _full_mean_ms(results: dict, ms_full: np.ndarray) -> float | None:
    given = _num(results.get("mean_ms_full"))
    if given is not None:
        return given
    ok = np.isfinite(ms_full)
    return float(ms_full[ok].mean()) if ok.any() else None


def _plot_frame_types(ax: Axes, results: dict, x: np.ndarray, ms: np.ndarray) -> bool:
    drawn = False
    for ftype, label, mean_key, colour, marker in FRAME_STYLES:
        sel = _type_mask(results, ftype, ms.size) & np.isfinite(ms) & (ms > 0)
        if not sel.any():
            continue
        text = f"{label} (n={int(sel.sum())}, mean {_fixed(results.get(mean_key), 1)} ms)"
        ax.plot(x[sel], ms[sel], marker, color=colour, ms=4, ls="none", label=text)
        drawn = True
    return drawn


def _plot_full_line(ax: Axes, results: dict, ms_full: np.ndarray) -> bool:
    ok = np.isfinite(ms_full) & (ms_full > 0)
    if not ok.any():
        return False
    sampled = " sampled" if results.get("full_sampled") else ""
    mean = _fixed(_full_mean_ms(results, ms_full), 1)
    ax.plot(np.flatnonzero(ok), ms_full[ok], "-", color="grey", alpha=0.45, lw=1,
            marker=".", ms=2, label=f"full resolution{sampled} (mean {mean} ms)")
    return True


def _plot_fig09(results: dict, out_dir: Path) -> Path | None:
    pf = _per_frame(results)
    ms = _arr(pf.get("ms_sprite"))
    if ms.size == 0:
        return None
    fig, ax = _figure()
    drawn = _plot_full_line(ax, results, _arr(pf.get("ms_full")))
    drawn = _plot_frame_types(ax, results, np.arange(ms.size), ms) or drawn
    if drawn:
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(LogFormatter(labelOnlyBase=False))
        ax.yaxis.set_minor_formatter(LogFormatter(labelOnlyBase=False))
        ax.legend(loc="best", fontsize=8)
    ax.set(xlabel="frame number", ylabel="render time per frame (ms, log scale)",
           title="Fig. 9 — render time per frame")
    ax.grid(alpha=0.3, which="both")
    return _save(fig, out_dir / "fig09_time.png")


def _xy(sec: dict, xkey: str, ykey: str, positive_x: bool = False) -> tuple[np.ndarray, ...]:
    x, y = _arr(sec.get(xkey)), _arr(sec.get(ykey))
    n = min(x.size, y.size)
    x, y = x[:n], y[:n]
    ok = np.isfinite(x) & np.isfinite(y) & ((x > 0) if positive_x else True)
    order = np.argsort(x[ok])
    return x[ok][order], y[ok][order]


def _paper_point(ax: Axes, x: float, y: float, label: str) -> None:
    ax.plot([x], [y], "*", color="tab:red", ms=13, ls="none", label=label, zorder=5)


def _plot_fig10(results: dict, out_dir: Path) -> Path | None:
    sec = _section(results, "fig10")
    x, y = _xy(sec, "frames", "keyframe_fraction", positive_x=True) if sec else ((), ())
    if len(x) == 0:
        return None
    fig, ax = _figure()
    ax.plot(x, y, "o-", color="tab:blue", label="this run")
    _paper_point(ax, PAPER["frames"], _paper_fraction(),
                 f"paper ({PAPER['keyframes']:.0f} of {PAPER['frames']:.0f}, ε = 1 px)")
    ax.set_xscale("log")
    ax.set_xticks(x, [f"{v:g}" for v in x])
    ax.minorticks_off()
    ax.set(xlabel="total frames rendered over the path (log scale)",
           ylabel="keyframe fraction (keyframes / frames)",
           title="Fig. 10 — keyframe fraction vs frames")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir / "fig10_keyframes_vs_frames.png")


def _plot_fig11(results: dict, out_dir: Path) -> Path | None:
    sec = _section(results, "fig11")
    x, y = _xy(sec, "epsilon", "keyframe_fraction") if sec else ((), ())
    if len(x) == 0:
        return None
    fig, ax = _figure()
    ax.plot(x, y, "o-", color="tab:blue", label="this run")
    _paper_point(ax, PAPER["epsilon"], _paper_fraction(),
                 f"paper ({PAPER['keyframes']:.0f} of {PAPER['frames']:.0f} frames)")
    ax.set(xlabel="error threshold ε (px)", ylabel="keyframe fraction (keyframes / frames)",
           title="Fig. 11 — keyframe fraction vs error threshold")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir / "fig11_keyframes_vs_epsilon.png")


def _plot_fig12(results: dict, out_dir: Path) -> Path | None:
    sec = _section(results, "fig12")
    x, y = _xy(sec, "epsilon", "speedup") if sec else ((), ())
    if len(x) == 0:
        return None
    fig, ax = _figure()
    ax.plot(x, y, "o-", color="tab:blue", label="this run")
    _paper_point(ax, PAPER["epsilon"], PAPER["speedup"], "paper (SGI IR, 1999)")
    ax.annotate(f"paper (SGI IR, 1999): {PAPER['speedup']:.2f}",
                (PAPER["epsilon"], PAPER["speedup"]), textcoords="offset points",
                xytext=(8, -4), fontsize=8, color="tab:red")
    ax.axhline(1.0, color="grey", ls=":", lw=1)
    ax.set(xlabel="error threshold ε (px)",
           ylabel="speedup (full-res time / LOD-sprite time, ×)",
           title="Fig. 12 — speedup vs error threshold")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir / "fig12_speedup_vs_epsilon.png")


# --------------------------------------------------------------------------- image panels


def _panel_titles(results: dict) -> dict[str, str]:
    grid, lod = _square(results.get("grid")), _square(results.get("lod"))
    return {
        "full": f"(a) full {grid} height field",
        "lod": f"(b) {lod} LOD",
        "sprite": f"(c) LOD-sprite on {lod}",
        "diff_lod": "(d) |a−b|",
        "diff_sprite": "(e) |a−c|",
    }


def _load_image(path: Path) -> tuple[np.ndarray, bool] | None:
    """Pixels of a PNG and whether it is greyscale; None if it is missing or unreadable."""
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("L", "LA", "1"):
                return np.asarray(im.convert("L")), True
            if im.mode in ("I", "I;16", "F"):
                return np.asarray(im, dtype=float), True
            return np.asarray(im.convert("RGB")), False
    except (OSError, ValueError):
        return None


def _draw_panel(ax: Axes, image: tuple[np.ndarray, bool] | None, title: str) -> None:
    ax.set_axis_off()
    if image is None:
        return
    pixels, grey = image
    if grey and pixels.dtype == np.uint8:
        ax.imshow(pixels, cmap="gray", vmin=0, vmax=255)
    elif grey:
        ax.imshow(pixels, cmap="gray")
    else:
        ax.imshow(pixels)
    ax.set_title(title, fontsize=9)


def _panel_layout(images: dict[str, Any]) -> list[list[str | None]]:
    rows: list[list[str | None]] = [["full", "lod", "sprite"]]
    if images.get("diff_lod") is not None or images.get("diff_sprite") is not None:
        rows.append([None, "diff_lod", "diff_sprite"])  # (d) under (b), (e) under (c)
    return rows


def _plot_panels(results: dict, out_dir: Path, name: str) -> Path | None:
    spec = (results.get("images") or {}).get(name)
    if not isinstance(spec, dict):
        return None
    titles = _panel_titles(results)
    images = {k: _load_image(out_dir / str(spec[k])) for k in titles if spec.get(k)}
    if not any(v is not None for v in images.values()):
        return None
    layout = _panel_layout(images)
    fig = Figure(figsize=(9.6, 3.4 * len(layout)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(layout), 3, squeeze=False)
    for r, row in enumerate(layout):
        for c, key in enumerate(row):
            _draw_panel(axes[r][c], images.get(key) if key else None, titles.get(key or "", ""))
    number = name.removeprefix("fig")
    fig.suptitle(f"Fig. {number} — frame {_text(spec.get('frame'))}", fontsize=11)
    return _save(fig, out_dir / f"{name}.png")


def _plot_fig13(results: dict, out_dir: Path) -> Path | None:
    return _plot_panels(results, out_dir, "fig13")


def _plot_fig14(results: dict, out_dir: Path) -> Path | None:
    return _plot_panels(results, out_dir, "fig14")


PLOTS: tuple[PlotFn, ...] = (
    _plot_fig08, _plot_fig09, _plot_fig10, _plot_fig11, _plot_fig12, _plot_fig13, _plot_fig14,
)


def write_plots(results: dict, out_dir: Path) -> list[Path]:
    """Write the PNGs of Figs 8-14 that ``results`` has data for; return their paths.

    Files (in ``out_dir``): ``fig08_error.png``, ``fig09_time.png``,
    ``fig10_keyframes_vs_frames.png``, ``fig11_keyframes_vs_epsilon.png``,
    ``fig12_speedup_vs_epsilon.png``, ``fig13.png``, ``fig14.png``.  Figs 13 and 14
    are composed from the PNGs that ``results["images"]`` names inside ``out_dir``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [p for fn in PLOTS if (p := fn(results, out_dir)) is not None]


# --------------------------------------------------------------------------- report


def _cell(s: str) -> str:
    return s.replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines + [""]


def _path_phrase(path: Any) -> str:
    return "the camera path" if _text(path) == DASH else f"the `{_text(path)}` camera path"


def _description(r: dict) -> str:
    return (
        f"Experiment `{_text(r.get('experiment'))}`: the `{_text(r.get('terrain'))}` terrain "
        f"({_square(r.get('grid'))} height field, {_square(r.get('lod'))} LOD mesh for "
        f"spriteframes) rendered along {_path_phrase(r.get('path'))} for "
        f"{_int(r.get('frames'))} frames at {_size(r.get('size'))}, with error threshold "
        f"ε = {_g(r.get('epsilon'))} px and the `{_text(r.get('visibility'))}` visibility "
        f"rule. GL renderer: {_text(r.get('gl_renderer'))}; machine: {_text(r.get('machine'))}."
    )


def _of(part: Any, whole: Any) -> str:
    return f"{_int(part)} of {_int(whole)}"


def _sprite_count(r: dict, key: str, frame_type: str) -> Any:
    return r[key] if key in r else _count_type(r, frame_type)


def _rmse_verdict(ratio: Any) -> str:
    f = _num(ratio)
    if f is None:
        return f"target ≤ {RMSE_RATIO_TARGET:g}"
    return f"target ≤ {RMSE_RATIO_TARGET:g}: {'met' if f <= RMSE_RATIO_TARGET else 'not met'}"


def _timing_rows(r: dict) -> list[list[str]]:
    p = PAPER
    return [
        ["mean time, keyframe (ms)", _fixed(r.get("mean_ms_keyframe"), 1),
         _fixed(p["mean_ms_keyframe"], 1), "paper says 'microseconds'; its totals give ms"],
        ["mean time, first spriteframe (ms)", _fixed(r.get("mean_ms_first_sprite"), 1),
         _fixed(p["mean_ms_first_sprite"], 1), "frame after a keyframe (sprite upload)"],
        ["mean time, spriteframe (ms)", _fixed(r.get("mean_ms_sprite"), 1),
         _fixed(p["mean_ms_sprite"], 1), ""],
        ["keyframe ÷ spriteframe time (×)",
         _fixed(_ratio(r.get("mean_ms_keyframe"), r.get("mean_ms_sprite")), 2),
         _fixed(_ratio(p["mean_ms_keyframe"], p["mean_ms_sprite"]), 2), "ratio: comparable"],
        ["total, full resolution (s)", _fixed(r.get("total_s_full"), 2),
         _fixed(p["total_s_full"], 2), "sampled and scaled" if r.get("full_sampled") else ""],
        ["total, LOD-sprite (s)", _fixed(r.get("total_s_sprite"), 2),
         _fixed(p["total_s_sprite"], 2), ""],
        ["total, plain LOD (s)", _fixed(r.get("total_s_lod"), 2), DASH, "not in the paper"],
        ["speedup, full ÷ LOD-sprite (×)", _fixed(r.get("speedup"), 2),
         _fixed(p["speedup"], 2), "ratio: comparable"],
    ]


def _quality_rows(r: dict) -> list[list[str]]:
    claim = "much closer to full res (Figs 13–14), no number"
    return [
        ["RMSE, LOD-sprite vs full (mean)", _fixed(r.get("rmse_sprite_mean"), 2), DASH, ""],
        ["RMSE, plain LOD vs full (mean)", _fixed(r.get("rmse_lod_mean"), 2), DASH, ""],
        ["RMSE ratio, LOD-sprite ÷ plain LOD", _fixed(r.get("rmse_ratio"), 3), claim,
         _rmse_verdict(r.get("rmse_ratio"))],
        ["PSNR, LOD-sprite vs full (dB, mean)", _fixed(r.get("psnr_sprite_mean"), 2), DASH, ""],
        ["PSNR, plain LOD vs full (dB, mean)", _fixed(r.get("psnr_lod_mean"), 2), DASH, ""],
        ["SSIM, LOD-sprite vs full (mean)", _fixed(r.get("ssim_sprite_mean"), 4), DASH, ""],
        ["SSIM, plain LOD vs full (mean)", _fixed(r.get("ssim_lod_mean"), 4), DASH, ""],
    ]


def _comparison_rows(r: dict) -> list[list[str]]:
    p = PAPER
    counts = [
        ["keyframes", _of(r.get("keyframes"), r.get("frames")),
         _of(p["keyframes"], p["frames"]), ""],
        ["keyframe fraction", _fixed(r.get("keyframe_fraction"), 3),
         _fixed(_paper_fraction(), 3), ""],
        ["first spriteframes", _int(_sprite_count(r, "first_sprite_frames", "first_sprite")),
         _int(p["first_sprite_frames"]), "paper: one per keyframe"],
        ["spriteframes", _int(_sprite_count(r, "sprite_frames", "sprite")),
         _int(p["sprite_frames"]), ""],
    ]
    return counts + _timing_rows(r) + _quality_rows(r)


def _comparison_notes(r: dict) -> list[str]:
    p = PAPER
    accounted = p["keyframes"] + p["first_sprite_frames"] + p["sprite_frames"]
    notes = [
        f"The paper's times were measured in 1999 on an SGI Power Challenge with "
        f"InfiniteReality graphics; ours were measured in this run on "
        f"{_text(r.get('gl_renderer'))}, so only ratios (fractions, speedup, time ratios) "
        f"compare, not absolute times.",
        f"The paper's frame counts add up to {accounted:.0f} "
        f"({p['keyframes']:.0f} + {p['first_sprite_frames']:.0f} + {p['sprite_frames']:.0f}), "
        f"not {p['frames']:.0f}; its full-resolution total is "
        f"{_fixed(1000 * p['total_s_full'] / p['frames'], 1)} ms per frame, which is why its "
        f"'microseconds' are read as milliseconds.",
    ]
    if _num(r.get("quality_frames")) is not None:
        stride = _int(r.get("quality_stride"))
        notes.append(
            f"RMSE, PSNR and SSIM are means over {_int(r.get('quality_frames'))} frames "
            f"(stride {stride}) against the full-resolution rendering of the same view."
        )
    if r.get("full_sampled"):
        notes.append(
            f"Full-resolution time was measured on {_int(r.get('full_sample_frames'))} evenly "
            f"spaced frames and scaled to all {_int(r.get('frames'))} frames."
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
    return _series_table(_section(r, "fig10"), [
        ("frames", "frames", _int), ("keyframes", "keyframes", _int),
        ("keyframe fraction", "keyframe_fraction", lambda v: _fixed(v, 3))])


def _fig11_table(r: dict) -> list[str]:
    return _series_table(_section(r, "fig11"), [
        ("ε (px)", "epsilon", _g), ("keyframes", "keyframes", _int),
        ("keyframe fraction", "keyframe_fraction", lambda v: _fixed(v, 3)),
        ("RMSE LOD-sprite", "rmse_sprite", lambda v: _fixed(v, 2)),
        ("RMSE plain LOD", "rmse_lod", lambda v: _fixed(v, 2)),
        ("ratio", "rmse_ratio", lambda v: _fixed(v, 3))])


def _fig12_table(r: dict) -> list[str]:
    return _series_table(_section(r, "fig12"), [
        ("ε (px)", "epsilon", _g),
        ("total LOD-sprite (s)", "total_s_sprite", lambda v: _fixed(v, 2)),
        ("speedup (×)", "speedup", lambda v: _fixed(v, 2))])


def _frame_of(r: dict, name: str) -> str:
    spec = (r.get("images") or {}).get(name)
    if not isinstance(spec, dict):
        return DASH
    key = _num(spec.get("keyframe"))
    return _text(spec.get("frame")) + ("" if key is None else f" (keyframe {key:.0f})")


def _captions(r: dict) -> dict[str, tuple[str, str]]:
    """File name -> (section heading, one-line caption)."""
    p, lod, grid = PAPER, _square(r.get("lod")), _square(r.get("grid"))
    return {
        "fig08_error.png": ("Fig. 8 — error per frame",
            f"Error (px) of each frame; red dots mark the {_int(r.get('keyframes'))} keyframes "
            f"(error 0), the dashed line is ε = {_g(r.get('epsilon'))} px."),
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
            f"LOD, (c) LOD-sprite on the same {lod} mesh, textured from the keyframe."),
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
        lines += [f"Not produced in this run (no data): {', '.join(skipped)}.", ""]
    return lines


def write_report(results: dict, out_dir: Path, plots: list[Path]) -> Path:
    """Write ``out_dir/report.md``: description, ours-vs-paper table, one section per figure.

    ``plots`` are the PNGs from :func:`write_plots`; a figure whose PNG is not among
    them is listed as not produced.  Returns the report's path.
    """
    out_dir = Path(out_dir)
    title = f"# Chen, Swan & Kaufman (1999) LOD-sprite — {_text(results.get('experiment'))}"
    lines = [title, "", _description(results), "", "## Ours vs paper", ""]
    lines += _table(["quantity", "ours", "paper", "note"], _comparison_rows(results))
    lines += _comparison_notes(results)
    lines += _figure_sections(results, out_dir, plots)
    path = out_dir / REPORT_NAME
    _atomic_write_bytes(path, "\n".join(lines).rstrip("\n").encode() + b"\n")
    return path
