"""Inline against worker keyframes, the path played in time (issue 32, must-haves 1 and 2):
which of ``--keyframes inline`` and ``--keyframes worker`` pays, on each one's error–time
frontier.

Both play the same path in time (:mod:`lodsprite.playback`: the camera moves at the
path's nominal speed, the display draws as often as it can, or at ``--display-fps``), so
a keyframe drawn inline costs the frame it is drawn in and one from the worker costs the
error of arriving late; in the untimed replay the image on screen is judged at display
ticks against the band-limited reference at each tick's viewpoint (error over display
time, :mod:`lodsprite.display`).  The worker process shares this machine's
cores with the display (Swan et al. 2002's shared set-up, not their second pipe).

For each source, one run per ε of ``--eps``: a point (median and p99 display frame time,
mean RMSE of the judged frames).  The frontier of each source is the lower envelope of its
points, chosen on one half of the judged frames and compared with the other half's RMSE
(:func:`~lodsprite.experiments.base.split_sampled`); printed: every point, then inline's
frontier time over the worker's at each of inline's frontier errors (> 1: the worker is
faster at that error; none where the worker's frontier does not reach it), and the
inline runs some worker run beats in both time and error (a worker frontier wholly below
inline's reaches none of inline's errors).  Each run is
a process of its own, warmed up alike, in turns (inline, worker, inline, ...) so that
drift on a shared machine falls on both.

    python benchmarks/keyframes_played.py [--terrain jacksboro] [--path chen1999]
        [--frames 120] [--size 256x256] [--eps 2 1 0.5 0.25] [--display-fps F]
        [--quality-stride 4] [--tiles 1] [--out DIR] [--json]

``--tiles N`` compares inline tile updates with tiles from the worker; ``--terrain`` a
store: adaptive keyframes (or tiles) at the store's defaults (inline runs also get its
``--proxy-sse`` default, which the worker does not take).
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
from pathlib import Path

import numpy as np

from lodsprite.experiments.base import split_sampled
from lodsprite.experiments.large.child import render_in_child
from lodsprite.report.frontier import frontier, frontier_speedup

SOURCES = ("inline", "worker")


def judged(folder: Path) -> tuple[float, float]:
    """Mean RMSE of the judged display ticks (the image on screen at each, against the
    band-limited reference there: error over display time), ``(reported, chosen)``
    halves."""
    ticks = folder / "ticks.csv"
    if not ticks.exists():  # --quality-stride 0: times only
        return float("nan"), float("nan")
    with open(ticks, newline="") as f:
        e = [float(r["rmse"]) for r in csv.DictReader(f) if r.get("rmse")]
    if not e:  # --quality-stride 0: times only
        return float("nan"), float("nan")
    chosen, reported = split_sampled(e)
    return float(np.mean(reported)), float(np.mean(chosen))


def point(args: argparse.Namespace, source: str, eps: float, out: Path) -> dict:
    """One played run of ``source`` at ``eps`` in a process of its own."""
    w, h = (int(v) for v in args.size.lower().split("x"))
    cfg = {"terrain": args.terrain, "path": args.path, "frames": args.frames,
           "size": [w, h], "mode": "sprite", "epsilon": eps, "keyframes": source,
           "ground_truth": args.quality_stride > 0, "play": True,
           "quality_stride": max(args.quality_stride, 1)}
    if args.display_fps:
        cfg["display_fps"] = args.display_fps
    if args.tiles > 1:
        cfg["tiles"] = args.tiles
    if args.vdp:
        cfg["vdp_seconds"] = args.vdp
    s = render_in_child(cfg, out / f"{source}_eps{eps:g}")
    rmse, chosen = judged(out / f"{source}_eps{eps:g}")
    return {"source": source, "epsilon": eps, "median_ms": s["median_ms"],
            "p99_ms": s["p99_ms"], "rmse": rmse, "rmse_chosen": chosen,
            "keyframes": s.get("keyframes"), "frames": s.get("frames"),
            "display_fps": s.get("display_fps"), "latency_ms_mean": s.get("latency_ms_mean"),
            "cvvdp_jod": s.get("cvvdp_jod")}


def compare(points: list[dict], time: str) -> dict:
    """The worker's speedup over inline at each of inline's frontier errors."""
    curves = {}
    for src in SOURCES:
        ps = [p for p in points if p["source"] == src]
        chosen = set(frontier([(p[time], p["rmse_chosen"]) for p in ps]))
        curves[src] = frontier([(p[time], p["rmse"]) for p in ps
                                if (p[time], p["rmse_chosen"]) in chosen])
    return {f"{e:.3f}": frontier_speedup(curves["inline"], curves["worker"], e)
            for _, e in curves["inline"]}


def dominated(points: list[dict], time: str) -> list[dict]:
    """The inline points some worker point beats or equals in both ``time`` and RMSE
    (reported half), with the worker point that does: where the worker's frontier lies
    wholly below inline's, the speedup at inline's errors is never reached and this says
    why."""
    out = []
    for p in (q for q in points if q["source"] == "inline"):
        better = [w for w in points if w["source"] == "worker" and w[time] <= p[time]
                  and w["rmse"] <= p["rmse"]]
        if better:
            w = min(better, key=lambda q: q[time])
            out.append({"inline_epsilon": p["epsilon"], "worker_epsilon": w["epsilon"],
                        "time_ratio": p[time] / w[time], "rmse": (p["rmse"], w["rmse"])})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--path", default="chen1999")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--eps", type=float, nargs="+", default=[2.0, 1.0, 0.5, 0.25])
    ap.add_argument("--display-fps", type=float, default=None)
    ap.add_argument("--quality-stride", type=int, default=4,
                    help="judge every n-th frame (0: times only, no reference)")
    ap.add_argument("--tiles", type=int, default=1,
                    help="tiles x tiles keyframe tiles, inline or from the worker")
    ap.add_argument("--vdp", type=float, default=None,
                    help="ColorVideoVDP over this many seconds of each run (the vdp extra)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="keyframes_played_"))
    points = [point(args, src, eps, out) for eps in args.eps for src in SOURCES]
    result = {"points": points, "worker_speedup_median": compare(points, "median_ms"),
              "worker_speedup_p99": compare(points, "p99_ms"),
              "inline_dominated_median": dominated(points, "median_ms"),
              "inline_dominated_p99": dominated(points, "p99_ms")}
    if args.json:
        print(json.dumps(result, indent=1))
        return
    for p in points:
        print(f"{p['source']:6s} ε {p['epsilon']:<5g} median {p['median_ms']:7.2f} ms  p99 "
              f"{p['p99_ms']:7.2f} ms (p99/median {p['p99_ms'] / p['median_ms']:.2f})  "
              f"RMSE {p['rmse']:6.2f}  keyframes {p['keyframes']}  "
              f"frames {p['frames']}  latency {p['latency_ms_mean']:.1f} ms"
              + ("" if p["cvvdp_jod"] is None else f"  ColorVideoVDP {p['cvvdp_jod']:.2f} JOD"))
    for key in ("worker_speedup_median", "worker_speedup_p99"):
        cells = ", ".join(f"RMSE {e}: " + ("none" if v is None else f"{v:.2f}x")
                          for e, v in result[key].items())
        print(f"{key}: {cells}")
    for key in ("inline_dominated_median", "inline_dominated_p99"):
        cells = ", ".join(f"inline ε {d['inline_epsilon']:g} by worker ε "
                          f"{d['worker_epsilon']:g} ({d['time_ratio']:.2f}x the time)"
                          for d in result[key]) or "none"
        print(f"{key}: {cells}")


if __name__ == "__main__":
    main()
