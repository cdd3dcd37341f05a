"""Figures 8-14 of Chen, Swan & Kaufman (1999) drawn from a reproduction's ``results``.

Figures are drawn on :class:`matplotlib.figure.Figure` objects with the Agg canvas, never
through pyplot's global state; a figure whose data is missing is skipped.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter
from PIL import Image

from lodsprite.experiments.paper_numbers import PAPER, PAPER_KEYFRAME_FRACTION
from lodsprite.files import atomic_write_bytes
from lodsprite.report.values import (
    arr,
    fmt_fixed,
    fmt_square,
    fmt_text,
    num,
    per_frame,
    section,
    type_mask,
)

DPI = 110

FRAME_STYLES = (  # (type, legend label, results key of its mean, colour, marker)
    ("keyframe", "keyframe", "mean_ms_keyframe", "tab:red", "o"),
    ("first_sprite", "first spriteframe", "mean_ms_first_sprite", "tab:orange", "s"),
    ("sprite", "spriteframe", "mean_ms_sprite", "tab:blue", "."),
)

PlotFn = Callable[[dict, Path], "Path | None"]


# --------------------------------------------------------------------------- figures


def _figure(width: float = 7.0, height: float = 4.2) -> tuple[Figure, Axes]:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _save(fig: Figure, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _plot_fig08(results: dict, out_dir: Path) -> Path | None:
    err = arr(per_frame(results).get("error_px"))
    if err.size == 0:
        return None
    x = np.arange(err.size)
    fig, ax = _figure()
    ax.plot(x, err, "-", color="tab:blue", lw=0.9, marker=".", ms=3, label="error per frame")
    kf = type_mask(results, "keyframe", err.size)
    if kf.any():
        for xk in x[kf]:
            ax.axvline(xk, color="tab:red", lw=0.5, alpha=0.25)
        ax.plot(x[kf], np.nan_to_num(err[kf]), "o", color="tab:red", ms=4,
                label=f"keyframe ({int(kf.sum())})")
    eps = num(results.get("epsilon"))
    if eps is not None:
        ax.axhline(eps, color="black", ls="--", lw=1, label=f"ε = {eps:g} px")
    ax.set(xlabel="frame number", ylabel="error (px)", title="Fig. 8 — error per frame")
    ax.set_ylim(bottom=0)
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, out_dir / "fig08_error.png")


def _full_mean_ms(results: dict, ms_full: np.ndarray) -> float | None:
    given = num(results.get("mean_ms_full"))
    if given is not None:
        return given
    ok = np.isfinite(ms_full)
    return float(ms_full[ok].mean()) if ok.any() else None


def _plot_frame_types(ax: Axes, results: dict, x: np.ndarray, ms: np.ndarray) -> bool:
    drawn = False
    for ftype, label, mean_key, colour, marker in FRAME_STYLES:
        sel = type_mask(results, ftype, ms.size) & np.isfinite(ms) & (ms > 0)
        if not sel.any():
            continue
        text = f"{label} (n={int(sel.sum())}, mean {fmt_fixed(results.get(mean_key), 1)} ms)"
        ax.plot(x[sel], ms[sel], marker, color=colour, ms=4, ls="none", label=text)
        drawn = True
    return drawn


def _plot_full_line(ax: Axes, results: dict, ms_full: np.ndarray) -> bool:
    ok = np.isfinite(ms_full) & (ms_full > 0)
    if not ok.any():
        return False
    sampled = " sampled" if results.get("full_sampled") else ""
    mean = fmt_fixed(_full_mean_ms(results, ms_full), 1)
    ax.plot(np.flatnonzero(ok), ms_full[ok], "-", color="grey", alpha=0.45, lw=1,
            marker=".", ms=2, label=f"full resolution{sampled} (mean {mean} ms)")
    return True


def _plot_fig09(results: dict, out_dir: Path) -> Path | None:
    pf = per_frame(results)
    ms = arr(pf.get("ms_sprite"))
    if ms.size == 0:
        return None
    fig, ax = _figure()
    drawn = _plot_full_line(ax, results, arr(pf.get("ms_full")))
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
    x, y = arr(sec.get(xkey)), arr(sec.get(ykey))
    n = min(x.size, y.size)
    x, y = x[:n], y[:n]
    ok = np.isfinite(x) & np.isfinite(y) & ((x > 0) if positive_x else True)
    order = np.argsort(x[ok])
    return x[ok][order], y[ok][order]


def _paper_point(ax: Axes, x: float, y: float, label: str) -> None:
    ax.plot([x], [y], "*", color="tab:red", ms=13, ls="none", label=label, zorder=5)


def _curve(results: dict, key: str, xkey: str, ykey: str) -> tuple[Figure, Axes] | None:
    """A figure with this run's ``ykey`` over ``xkey`` from section ``key``; None if empty."""
    sec = section(results, key)
    x, y = _xy(sec, xkey, ykey) if sec else ((), ())
    if len(x) == 0:
        return None
    fig, ax = _figure()
    ax.plot(x, y, "o-", color="tab:blue", label="this run")
    return fig, ax


def _finish_curve(fig: Figure, ax: Axes, path: Path, xlabel: str, ylabel: str,
                  title: str) -> Path:
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def _plot_fig10(results: dict, out_dir: Path) -> Path | None:
    made = _curve(results, "fig10", "frames", "keyframe_fraction")
    if made is None:
        return None
    fig, ax = made
    _paper_point(ax, PAPER["frames"], PAPER_KEYFRAME_FRACTION,
                 f"paper ({PAPER['keyframes']:.0f} of {PAPER['frames']:.0f}, ε = 1 px)")
    x = _xy(section(results, "fig10"), "frames", "keyframe_fraction")[0]
    ax.set_xscale("log")
    ax.set_xticks(x, [f"{v:g}" for v in x])
    ax.minorticks_off()
    return _finish_curve(fig, ax, out_dir / "fig10_keyframes_vs_frames.png",
                         "total frames rendered over the path (log scale)",
                         "keyframe fraction (keyframes / frames)",
                         "Fig. 10 — keyframe fraction vs frames")


def _plot_fig11(results: dict, out_dir: Path) -> Path | None:
    made = _curve(results, "fig11", "epsilon", "keyframe_fraction")
    if made is None:
        return None
    fig, ax = made
    _paper_point(ax, PAPER["epsilon"], PAPER_KEYFRAME_FRACTION,
                 f"paper ({PAPER['keyframes']:.0f} of {PAPER['frames']:.0f} frames)")
    return _finish_curve(fig, ax, out_dir / "fig11_keyframes_vs_epsilon.png",
                         "error threshold ε (px)", "keyframe fraction (keyframes / frames)",
                         "Fig. 11 — keyframe fraction vs error threshold")


def _plot_fig12(results: dict, out_dir: Path) -> Path | None:
    made = _curve(results, "fig12", "epsilon", "speedup")
    if made is None:
        return None
    fig, ax = made
    _paper_point(ax, PAPER["epsilon"], PAPER["speedup"], "paper (SGI IR, 1999)")
    ax.annotate(f"paper (SGI IR, 1999): {PAPER['speedup']:.2f}",
                (PAPER["epsilon"], PAPER["speedup"]), textcoords="offset points",
                xytext=(8, -4), fontsize=8, color="tab:red")
    ax.axhline(1.0, color="grey", ls=":", lw=1)
    return _finish_curve(fig, ax, out_dir / "fig12_speedup_vs_epsilon.png",
                         "error threshold ε (px)",
                         "speedup (full-res time / LOD-sprite time, ×)",
                         "Fig. 12 — speedup vs error threshold")


# --------------------------------------------------------------------------- image panels


def _panel_titles(results: dict) -> dict[str, str]:
    grid, lod = fmt_square(results.get("grid")), fmt_square(results.get("lod"))
    return {
        "full": f"(a) full {grid} height field",
        "lod": f"(b) {lod} LOD",
        "sprite": f"(c) LOD-sprite on {lod}",
        "diff_lod": "(d) |a−b|",
        "diff_sprite": "(e) |a−c|",
        "keyframe_image": "(f) the keyframe (c) is drawn from",
    }


def _keyframe_title(spec: dict) -> str:
    """Panel (f)'s title: which keyframe, rendered when, and whether ahead of the viewer."""
    key, at = num(spec.get("keyframe")), num(spec.get("keyframe_frame"))
    if key is None:
        return _panel_titles({})["keyframe_image"]
    where = "" if at is None else f" of frame {at:.0f}"
    ahead = ", placed ahead" if spec.get("keyframe_ahead") else ""
    return f"(f) keyframe {key:.0f}{where}{ahead}"


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
    key = "keyframe_image" if images.get("keyframe_image") is not None else None
    if images.get("diff_lod") is not None or images.get("diff_sprite") is not None:
        rows.append([key, "diff_lod", "diff_sprite"])  # (d) under (b), (e) under (c)
    elif key:
        rows.append([key, None, None])
    return rows


def _plot_panels(results: dict, out_dir: Path, name: str) -> Path | None:
    spec = (results.get("images") or {}).get(name)
    if not isinstance(spec, dict):
        return None
    titles = {**_panel_titles(results), "keyframe_image": _keyframe_title(spec)}
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
    fig.suptitle(f"Fig. {number} — frame {fmt_text(spec.get('frame'))}", fontsize=11)
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
