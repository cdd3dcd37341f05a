"""Error–time frontiers: every technique judged along its own knobs, not one setting
against another.

Each run of a technique at one setting (adaptive's tolerance, LOD-sprite's ε, keyframe
tolerance, keyframe source...) is a point: its frame time (median, or p99) and its error
(RMSE or FLIP from the untimed replay against the reference).  A technique's frontier
(:func:`frontier`) is the lower envelope of its points: the points no other point of the
same technique beats in both time and error, in order of time.  The time a frontier needs
for an error level (:func:`time_at_error`) is interpolated between its two measured points
that bracket the level, linearly in error against log time, and never extrapolated: a
level below the frontier's best error or above its worst has no time (None).
:func:`frontier_speedup` is one frontier's time over another's at the same level (None
where either has none); where the faster frontier's fastest run is already below the
level, :func:`speedup_lower_bound` gives "at least" that run's speedup.
:func:`plot_frontiers` draws error against time, one curve per technique.

Points are ``(time_ms, error)`` pairs, ``time_ms > 0`` (milliseconds) and ``error >= 0``
(grey levels for RMSE, 0..1 for FLIP); non-finite points are left out.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import save_figure

Point = tuple[float, float]


def _finite(points: Iterable[Sequence[float]]) -> np.ndarray:
    """``points`` as an ``(n, 2) float64`` array of finite ``(time_ms, error)`` rows."""
    a = np.asarray([tuple(p) for p in points], dtype=np.float64).reshape(-1, 2)
    a = a[np.isfinite(a).all(axis=1)]
    if (a[:, 0] <= 0).any() or (a[:, 1] < 0).any():
        raise InputError("frontier points need time_ms > 0 and error >= 0")
    return a


def frontier(points: Iterable[Sequence[float]]) -> list[Point]:
    """The lower envelope of ``points`` (``(time_ms, error)``): in order of time, each
    point of strictly lower error than every faster one; of points with equal time the
    lowest error.  Dominated points (slower and no better) are left out."""
    a = _finite(points)
    order = np.lexsort((a[:, 1], a[:, 0]))  # by time, then by error
    out: list[Point] = []
    best = math.inf
    for t, e in a[order]:
        if e < best:
            out.append((float(t), float(e)))
            best = e
    return out


def time_at_error(front: Sequence[Point], error: float) -> float | None:
    """The time (ms) ``front`` (a :func:`frontier`, time ascending, error descending)
    needs for ``error``: interpolated linearly in error against ``log(time)`` between the
    two points that bracket it; a measured point's own time at its error; None outside the
    frontier's measured errors (never extrapolated)."""
    if not front or not math.isfinite(error):
        return None
    t = np.log([p[0] for p in front])
    e = np.array([p[1] for p in front])
    if error > e[0] or error < e[-1]:
        return None
    hit = np.flatnonzero(e == error)
    if hit.size:
        return float(np.exp(t[hit[0]]))
    i = int(np.flatnonzero(e > error)[-1])  # e[i] > error > e[i + 1]
    f = (e[i] - error) / (e[i] - e[i + 1])
    return float(np.exp(t[i] + f * (t[i + 1] - t[i])))


def frontier_speedup(slower: Sequence[Point], faster: Sequence[Point],
                     error: float) -> float | None:
    """``slower``'s time over ``faster``'s at ``error`` (> 1: ``faster`` is faster there);
    None where either frontier has no time for that error."""
    a, b = time_at_error(slower, error), time_at_error(faster, error)
    return None if a is None or b is None else a / b


def speedup_lower_bound(slower: Sequence[Point], faster: Sequence[Point],
                        error: float) -> float | None:
    """Where ``faster``'s fastest run is already at or below ``error`` (its frontier starts
    under the level, so no interpolation reaches it), the speedup is at least ``slower``'s
    time at ``error`` over that run's time: this bound; None where ``faster``'s fastest
    run is above ``error`` (the exact :func:`frontier_speedup` applies, or nothing) or
    ``slower`` has no time there."""
    if not faster or not math.isfinite(error) or faster[0][1] > error:
        return None
    a = time_at_error(slower, error)
    return None if a is None else a / faster[0][0]


def plot_frontiers(curves: Mapping[str, Iterable[Sequence[float]]], path: Path,
                   title: str = "", error_label: str = "RMSE (grey levels)",
                   time_label: str = "median frame time (ms)",
                   levels: Sequence[float] = (),
                   fronts: Mapping[str, Sequence[Point]] | None = None) -> Path:
    """Error against time (log), one curve per technique: its measured points (light) and
    its frontier (a line through the envelope; ``fronts[name]`` where given, e.g. a
    frontier chosen on other frames, else :func:`frontier` of the points); ``levels``:
    error levels marked as horizontal lines.  Written to ``path`` (PNG); returns it."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    fig = Figure(figsize=(6.4, 4.4), dpi=120)
    ax = fig.subplots()
    for i, (name, points) in enumerate(curves.items()):
        a = _finite(points)
        colour = f"C{i}"
        ax.scatter(a[:, 0], a[:, 1], s=14, color=colour, alpha=0.35)
        given = None if fronts is None else fronts.get(name)
        front = np.array(frontier(a) if given is None else given).reshape(-1, 2)
        ax.plot(front[:, 0], front[:, 1], "o-", color=colour, label=name, lw=1.6, ms=4)
    for level in levels:
        ax.axhline(level, color="0.6", lw=0.8, ls=":")
    ax.set_xscale("log")
    plain = FuncFormatter(lambda v, _: f"{v:g}")  # 3, 20, 300: not 3×10^0
    ax.xaxis.set_major_formatter(plain)
    ax.xaxis.set_minor_formatter(FuncFormatter(
        lambda v, _: f"{v:g}" if f"{v:g}"[0] in "25" else ""))
    ax.set_xlabel(time_label)
    ax.set_ylabel(error_label)
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, Path(path))


__all__ = ["frontier", "frontier_speedup", "plot_frontiers", "speedup_lower_bound",
           "time_at_error"]
