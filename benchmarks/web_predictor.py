"""The web page's request logic against a server model that answers every request
exactly L seconds later (no capacity limit, no jitter): how much of the shown error is
the client logic at a given keyframe latency, apart from the renderers' capacity
(``docs/web.md``, the load benchmark).

For each latency and each built-in path the page's logic
(:mod:`lodsprite.distributed.web.estimate`: the linear predictor one measured latency
ahead, a request when the shown keyframe's estimated error there reaches ε/2, one in
flight) plays the path at ``fps``; a request made at ``t`` brings a keyframe at the
requested viewpoint at ``t + L``.  Three request policies: ``page`` (the page's),
``hold`` (looking ahead by the latency and half the measured interval between keyframes,
so that a keyframe stands in the middle of the time it is shown; measured, not kept) and
``oracle`` (the page's timing, but the true viewpoint one lead ahead instead of the
linear prediction).  Per policy, latency and path: the mean of the page's estimate and
of lodsprite's exact metric (:mod:`lodsprite.sprite.metric`) over the frames shown, and
the keyframes.  Writes ``DIR/results.json``; GL-free (a few minutes on 2 cores).

    python benchmarks/web_predictor.py --latency 0.09 0.25 0.5 --out out/web_predictor
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from web_load import PATHS, scene_options  # this folder's: the load benchmark's set-up

from lodsprite.camera import Viewpoint
from lodsprite.distributed.protocol import LoadArgs
from lodsprite.distributed.web.estimate import MAX_AHEAD_S, ErrorMetric, Predictor
from lodsprite.distributed.web.scene import build_scene_field, decode_scene
from lodsprite.paths import get_path
from lodsprite.sprite.metric import ErrorMetric as ExactMetric

POLICIES = ("page", "hold", "oracle")


class HoldPredictor(Predictor):
    """The page's predictor looking ahead by the latency and half the measured interval
    between keyframes (an exponential mean, as the latency's)."""

    def __init__(self, scene) -> None:
        super().__init__(scene)
        self.interval: float | None = None
        self.last: float | None = None

    def lead(self) -> float:
        half = 0.0 if self.interval is None else 0.5 * self.interval
        return min(self.latency + half, MAX_AHEAD_S)

    def arrived(self, t0: float, now: float) -> None:
        if t0 in self.inflight and self.last is not None:
            gap = now - self.last
            self.interval = gap if self.interval is None else (
                self.interval + 0.3 * (gap - self.interval))
        if t0 in self.inflight:
            self.last = now
        super().arrived(t0, now)


def play(scene, exact: ExactMetric, path: list[Viewpoint], latency: float, fps: float,
         policy: str) -> dict:
    """One path against the fixed-latency server: mean estimate, mean exact error (px,
    over the frames whose value is finite) and keyframes."""
    metric = ErrorMetric(scene)
    pred = HoldPredictor(scene) if policy == "hold" else Predictor(scene)
    key, pending, keyframes = path[0].o, None, 0
    est, ref, rep, rep_eye = [], [], None, None
    for k, vp in enumerate(path):
        t = k / fps
        if pending is not None and pending[0] <= t + 1e-9:
            key = pending[1]
            pred.arrived(pending[2], t)
            pending, keyframes = None, keyframes + 1
        pred.sample(t, vp)
        est.append(pred.error_px(metric, key, vp))
        if rep_eye is None or not np.array_equal(key, rep_eye):
            rep, rep_eye = exact.reproject(key), key
        ref.append(exact.error_px(rep, vp.o, pred.proj @ vp.view_matrix(), pred.beta))
        want = pred.want(metric, key, t)
        if want is not None:
            pred.sent(t)
            if policy == "oracle":
                want = path[min(len(path) - 1, k + round(pred.lead() * fps))]
            pending = (t + latency, np.array(want.o), t)
    return {"estimate_px": _mean(est), "exact_px": _mean(ref), "keyframes": keyframes}


def _mean(values: list[float]) -> float | None:
    a = np.asarray(values, np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if len(a) else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--latency", type=float, nargs="+", default=[0.09, 0.25, 0.5],
                    help="keyframe latencies, s")
    ap.add_argument("--policies", nargs="+", choices=POLICIES, default=list(POLICIES),
                    help="request policies to play (web_capacity.py reads page)")
    scene_options(ap)
    ap.add_argument("--out", type=Path, default=Path("out/web_predictor"))
    args = ap.parse_args()
    if not all(0.0 <= x <= 60.0 for x in args.latency) or args.fps <= 0:
        ap.error("latencies must lie in 0..60 s and fps be positive")
    load = LoadArgs(terrain=args.terrain, size=(args.size, args.size), lod=args.lod,
                    epsilon=args.epsilon)
    parts, hf = build_scene_field(load)
    scene = decode_scene(parts)
    exact = ExactMetric.for_level(hf, args.lod)
    paths = {spec: list(get_path(spec, hf, args.frames).viewpoints) for spec in PATHS}
    rows = []
    for latency in args.latency:
        for policy in args.policies:
            per = {spec: play(scene, exact, p, latency, args.fps, policy)
                   for spec, p in paths.items()}
            means = {k: _mean([v[k] for v in per.values() if v[k] is not None])
                     for k in ("estimate_px", "exact_px")}
            rows.append({"latency_s": latency, "policy": policy, **means, "paths": per})
            print(json.dumps({"latency_s": latency, "policy": policy, **means}))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(
        {"terrain": args.terrain, "size": args.size, "lod": args.lod,
         "epsilon": args.epsilon, "frames": args.frames, "fps": args.fps, "rows": rows},
        indent=2) + "\n")


if __name__ == "__main__":
    main()
