"""Error–time frontiers of ``reproduce large`` (issue 32, must-have 1): adaptive along
its tolerance, LOD-sprite along all of its knobs (ε, keyframe tolerance, whole or tiled
keyframes and the other variants the run has), each a lower envelope
(:func:`lodsprite.report.frontier.frontier`), compared at adaptive's own errors.

A point is one timed run: its median and p99 frame time and its RMSE and FLIP (the
untimed replay's sampled frames against level 0).  The choice and the report are on
different frames, as in the comparison at equal error
(:func:`~lodsprite.experiments.base.split_sampled`):

* which runs are on a technique's frontier is decided on the *chosen* half of the sampled
  frames (``rmse_chosen`` against the time);
* the curve compared is the lower envelope of those runs with the errors of the
  *reported* half (``rmse``), and the error levels are adaptive's own errors on the
  reported half at ``LEVELS`` (its 1, 2 and 4 px runs).

``frontier_speedup`` at a level is adaptive's frontier time over LOD-sprite's there
(:func:`~lodsprite.report.frontier.frontier_speedup`: interpolated in log time between
two measured points, never extrapolated, so None where LOD-sprite's frontier does not
reach that error); one block for the median frame time and one for the p99.  Where
LOD-sprite's fastest run is already below a level, the block's ``speedup_at_least``
gives the lower bound from that run (:func:`~lodsprite.report.frontier.
speedup_lower_bound`).
"""

from __future__ import annotations

from pathlib import Path

from lodsprite.report.frontier import (
    frontier,
    frontier_speedup,
    plot_frontiers,
    speedup_lower_bound,
)

#: The error levels compared: adaptive's run at this tolerance (px) gives the level.
LEVELS = {"1px": 1.0, "2px": 2.0, "4px": 4.0}
TIMES = ("median_ms", "p99_ms")
SPRITE = "lod-sprite"
POINT_KEYS = ("median_ms", "p99_ms", "total_s", "rmse", "flip", "rmse_chosen",
              "flip_chosen", "keyframes", "tiles_rendered")


def _point(r: dict, **knobs) -> dict:
    return {**knobs, **{k: r.get(k) for k in POINT_KEYS}}


def points(per_path: dict, variants: list[str]) -> dict[str, list[dict]]:
    """The frontier's points of one side and path: ``adaptive`` (a point a tolerance of
    ``adaptive_sweep``, ``sse``) and ``lod-sprite`` (a point a run of every variant in
    ``variants``: ``variant, key_sse, epsilon``)."""
    ad = [_point(r, sse=r["sse"]) for r in per_path.get("adaptive_sweep", [])]
    sp = [_point(r, variant=name, key_sse=r.get("key_sse"), epsilon=r["epsilon"])
          for name in variants for r in per_path.get(name, [])]
    return {"adaptive": ad, SPRITE: sp}


def _usable(p: dict, time: str) -> bool:
    vals = (p.get(time), p.get("rmse"), p.get("rmse_chosen"))
    return all(v is not None and v == v for v in vals) and p[time] > 0


def curve(pts: list[dict], time: str) -> tuple[list[tuple[float, float]], list[int]]:
    """The compared curve of one technique for ``time`` and the indices (into ``pts``) of
    the runs on its frontier: membership from the chosen half, the curve from the
    reported half (module docstring)."""
    ok = [i for i, p in enumerate(pts) if _usable(p, time)]
    chosen = frontier([(pts[i][time], pts[i]["rmse_chosen"]) for i in ok])
    members = [i for i in ok if (pts[i][time], pts[i]["rmse_chosen"]) in set(chosen)]
    return frontier([(pts[i][time], pts[i]["rmse"]) for i in members]), members


def levels(per_path: dict) -> dict[str, float | None]:
    """Each level's error: adaptive's reported RMSE at that tolerance, None if not run."""
    by_sse = {r["sse"]: r["rmse"] for r in per_path.get("adaptive_sweep", [])}
    return {name: by_sse.get(sse) for name, sse in LEVELS.items()}


def frontier_block(per_path: dict, variants: list[str]) -> tuple[dict, dict]:
    """``(frontier, speedups)`` of one side and path: every point of both techniques with
    ``on_frontier`` (by the median) and ``on_frontier_p99``; and per time key
    (``median_ms``, ``p99_ms``) the speedup at each level (None: not reached)."""
    pts = points(per_path, variants)
    curves: dict[str, dict] = {}
    for tech, ps in pts.items():
        curves[tech] = {}
        for time in TIMES:
            curves[tech][time], members = curve(ps, time)
            flag = "on_frontier" if time == "median_ms" else "on_frontier_p99"
            for i, p in enumerate(ps):
                p[flag] = i in members
    lv = levels(per_path)
    speed = {time: {name: (None if e is None else frontier_speedup(
        curves["adaptive"][time], curves[SPRITE][time], e)) for name, e in lv.items()}
        for time in TIMES}
    bound = {time: {name: (None if e is None or speed[time][name] is not None
                           else speedup_lower_bound(curves["adaptive"][time],
                                                    curves[SPRITE][time], e))
                    for name, e in lv.items()} for time in TIMES}
    return {**pts, "levels": lv, "speedup_at_least": bound}, speed


def plot(block: dict, path: Path, title: str) -> Path:
    """Error (reported RMSE) against median frame time: each technique's runs and its
    compared curve; adaptive's levels as horizontal lines."""
    curves = {name: [(p["median_ms"], p["rmse"]) for p in block[tech]
                     if _usable(p, "median_ms")]
              for tech, name in (("adaptive", "adaptive"), (SPRITE, "LOD-sprite"))}
    fronts = {name: curve(block[tech], "median_ms")[0]
              for tech, name in (("adaptive", "adaptive"), (SPRITE, "LOD-sprite"))}
    return plot_frontiers(curves, path, title=title, fronts=fronts,
                          levels=[e for e in block["levels"].values() if e is not None])
