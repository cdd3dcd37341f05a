"""Renderers needed for N web pages at a target error: a capacity model computed from two
measured figures, the page's error against keyframe latency (``web_predictor.py``'s
``results.json``) and a renderer's time per keyframe under load (``web_load.py``'s).

1. The page's curve: for each latency L the predictor benchmark played (policy ``page``),
   the mean error over its paths and the keyframes a page asked for a second. ``L*`` is
   the largest latency whose error is at most the target (linear between the measured
   latencies), ``r*`` a page's keyframes a second there.
2. A renderer's service time ``S``: the pool's ``job_ms_p50`` under load (dispatch to
   answer: the render and the pool's dispatch overhead), so a renderer serves
   ``mu = 1/S`` keyframes a second.
3. N pages ask ``lambda = N r*`` keyframes a second. Renderers are servers of one queue
   (the hub hands a job to whichever is free): the M/M/R queue's mean response time,
   Erlang C's wait plus ``S``, must stay at most ``L*``; the answer is the smallest R
   for which it does.

It assumes what the figures were measured with (the same scene, keyframe size and ε,
renderers of the same speed) and Poisson requests (a page asks when its error reaches
ε/2: closer to regular, so the queue's wait is an upper bound).

    python benchmarks/web_capacity.py --predictor out/web_predictor/results.json \\
        --load out/web_load_ray/results.json --pages 16 100 1000 --target 4
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def page_curve(predictor: dict, metric: str) -> list[tuple[float, float, float]]:
    """(latency s, mean error px, keyframes a page asks a second), policy ``page``."""
    play_s = predictor["frames"] / predictor["fps"]
    out = []
    for row in predictor["rows"]:
        if row["policy"] != "page" or row[metric] is None:
            continue
        rates = [p["keyframes"] / play_s for p in row["paths"].values()]
        out.append((row["latency_s"], row[metric], sum(rates) / len(rates)))
    return sorted(out)


def latency_for(curve: list[tuple[float, float, float]], target: float
                ) -> tuple[float, float] | None:
    """(L*, r*): the largest latency whose error is at most ``target`` px (linear between
    measured points) and a page's keyframe rate there; None if none meets it."""
    best = None
    for (l0, e0, r0), (l1, e1, r1) in zip(curve, curve[1:], strict=False):
        if e0 <= target < e1:
            f = (target - e0) / (e1 - e0)
            best = (l0 + f * (l1 - l0), r0 + f * (r1 - r0))
    if best is None and curve and curve[-1][1] <= target:
        best = curve[-1][:1] + curve[-1][2:]
    if best is None and curve and curve[0][1] <= target:
        best = (curve[0][0], curve[0][2])
    return best


def erlang_c(servers: int, load: float) -> float:
    """Erlang C: the probability a request waits, ``servers`` servers at ``load`` =
    lambda/mu (< servers); through Erlang B's recursion, which stays finite for
    thousands of servers."""
    b = 1.0
    for k in range(1, servers + 1):
        b = load * b / (k + load * b)
    return servers * b / (servers - load * (1.0 - b))


def renderers_needed(pages: int, rate: float, service_s: float, latency_s: float,
                     limit: int = 100_000) -> int | None:
    """Smallest R whose M/M/R mean response time is at most ``latency_s`` (None: not
    within ``limit``, or a keyframe alone takes longer)."""
    if service_s >= latency_s:
        return None
    lam, mu = pages * rate, 1.0 / service_s
    r = max(1, math.floor(lam / mu) + 1)
    while r <= limit:
        wait = erlang_c(r, lam / mu) / (r * mu - lam)
        if wait + service_s <= latency_s:
            return r
        r += 1
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--predictor", type=Path, required=True)
    ap.add_argument("--load", type=Path, required=True)
    ap.add_argument("--pool", default="ray", help="which run of a --ray load file")
    ap.add_argument("--pages", type=int, nargs="+", default=[16, 100, 1000])
    ap.add_argument("--target", type=float, default=4.0, help="mean error, px")
    args = ap.parse_args()
    predictor = json.loads(args.predictor.read_text())
    load = json.loads(args.load.read_text())
    load = load.get(args.pool, load)
    service_s = load["job_ms_p50"] / 1000.0
    print(f"service time S = {1e3 * service_s:.1f} ms ({load.get('pool', 'local')} pool, "
          f"job_ms_p50 at {load['clients']} pages on {load['renderers']} renderers), "
          f"dispatch overhead p50 {load.get('overhead_ms_p50')} ms")
    for metric in ("estimate_px", "exact_px"):
        curve = page_curve(predictor, metric)
        print(f"{metric}: " + ", ".join(f"L {lat:.3f} s: {err:.2f} px, {rate:.2f} kf/s"
                                        for lat, err, rate in curve))
        found = latency_for(curve, args.target)
        if found is None:
            print(f"  no measured latency gives {args.target} px")
            continue
        lat, rate = found
        need = {n: renderers_needed(n, rate, service_s, lat) for n in args.pages}
        print(f"  L* {lat:.3f} s, r* {rate:.2f} keyframes/s a page: renderers for "
              + ", ".join(f"{n} pages {r}" for n, r in need.items()))


if __name__ == "__main__":
    main()
