"""``lodsprite reproduce timecritical``: every technique held to a display rate, judged by
what the viewer sees over time.

Time-critical rendering is a frame budget (Funkhouser & Séquin 1993; Swan et al. 2002
judge their client so).  Each technique plays the path in real time
(:func:`lodsprite.playback.run_played`) at 30, 60 and 120 frames a second: the display
shows a new image only on its slots, a slot a technique misses keeps the previous image
(the fraction missed is reported), and every frame is drawn for the viewpoint predicted
for its display time, by one predictor for all (``kalman``: the eye and the orientation
extrapolated, :class:`~lodsprite.sprite.predictors.KalmanPredictor`; the 2002 paper's
``decay`` keeps the last orientation, which on a turning path is worse than none:
``benchmarks/predictors_played.py`` on chen1999 over fractal:128 at 256², 30 Hz, 58
slots: a full-resolution frame drawn for the paper's prediction is RMSE 30.2 from the
view at its display time, 10.0 for the viewpoint at its start, 6.45 for Kalman's, 6.22
for the exact one).  The techniques:

* ``adaptive`` - the adaptive renderer with frame-time feedback on its tolerance
  (:class:`~lodsprite.feedback.KnobFeedback`, target 90 % of the display period);
* ``lod`` - one uniform coarse level;
* ``sprite-inline`` - LOD-sprite, keyframes drawn in the frame that needs them;
* ``sprite-worker`` - LOD-sprite, keyframes from the worker process beside the display;
* ``depth-inline``, ``depth-worker`` - the same on the keyframe's own depth
  (:mod:`lodsprite.gl.depth_mesh`), inline keyframes at scale 2, the worker's paired;
  ``depth-worker-estimate`` asks for keyframes by the estimate on their own depth,
  ``depth-worker-fixed-guard`` keeps the worker keyframes' guard band at the slots' (the
  control for the band sized to the predictor's error, :mod:`lodsprite.sprite.guard`).

Every run gets the same untimed warm-up; nothing is read back while it plays.  Then the
image on screen is judged at instants of path time against the band-limited reference
(:mod:`lodsprite.display`: pairs of display ticks every ``judge_every_s``, RMSE and
flicker on each, FLIP every ``flip_every``-th pair), the reference images cached and
shared by every technique and rate.  Each (technique, rate) is played ``repeats`` times;
the median run's figures are reported with their spread (min and max over the runs).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lodsprite.experiments.base import StageProgress

RATES = (30.0, 60.0, 120.0)
#: name -> (registry mode, its options, the knob a frame-time controller turns or None)
TECHNIQUES: dict[str, tuple[str, dict[str, Any], str | None]] = {
    "adaptive": ("adaptive", {}, "sse"),
    "lod": ("lod", {}, None),
    "sprite-inline": ("sprite", {"keyframes": "inline"}, None),
    "sprite-worker": ("sprite", {"keyframes": "worker"}, None),
    # spriteframes on the keyframe's own depth, keyframes at scale 2 (the worker: scale 1,
    # its keyframes crossing the process boundary at 4x the bytes otherwise)
    "depth-inline": ("sprite", {"keyframes": "inline", "proxy": "depth", "key_scale": 2.0,
                                "depth_stride": 8}, None),
    "depth-worker": ("sprite", {"keyframes": "worker", "proxy": "depth", "pair": True,
                                "depth_stride": 8}, None),
    # the same, asking for keyframes by the estimate on each keyframe's own depth
    "depth-worker-estimate": ("sprite", {"keyframes": "worker", "proxy": "depth",
                                         "pair": True, "depth_stride": 8,
                                         "metric": "depth"}, None),
    # depth-worker with its guard band fixed at the slots' (the control for the guard
    # band that follows the predictor's error, lodsprite.sprite.guard)
    "depth-worker-fixed-guard": ("sprite", {"keyframes": "worker", "proxy": "depth",
                                            "pair": True, "depth_stride": 8}, None),
}


def _fixed_guard(technique) -> None:
    technique.engine.sprite.engine.worker.guard = None


#: name -> what is changed on the technique once made (before its warm-up)
ADJUST = {"depth-worker-fixed-guard": _fixed_guard}
FIGURES = ("median_ms", "p99_ms", "rmse_time_weighted", "flip_time_weighted", "flicker",
           "rmse_worst_second", "missed_slots", "display_fps", "latency_ms_mean", "cvvdp_jod")
TARGET_SHARE = 0.9  # the controller's target: this share of the display period


@dataclass(frozen=True)
class TimeCriticalConfig:
    """One terrain (a DEM, a store or a built-in) and path (any ``--path`` spec, its own
    frame count unless ``frames``; its first ``seconds`` only when given, at its own
    speed), images ``size`` pixels square, played at ``rates``, each ``repeats`` times;
    the reference at ``samples`` x ``samples`` a pixel."""

    terrain: str = "jacksboro"
    path: str = "bank"
    size: int = 512
    frames: int | None = None
    seconds: float | None = None
    rates: tuple[float, ...] = RATES
    repeats: int = 3
    techniques: tuple[str, ...] = tuple(TECHNIQUES)
    judge_every_s: float = 0.25
    flip_every: int = 4
    samples: int = 4
    predictor: str = "kalman"
    vdp_seconds: float | None = None  # ColorVideoVDP over this long of each run (vdp extra)

    @classmethod
    def quick(cls) -> TimeCriticalConfig:
        """A short run: 256², the path's first 3 s, every rate, three repeats."""
        return cls(size=256, seconds=3.0)


def _config(cfg: TimeCriticalConfig, name: str):
    from lodsprite.runconfig import RenderConfig

    mode, options, _ = TECHNIQUES[name]
    return RenderConfig(terrain=cfg.terrain, path=cfg.path, mode=mode,
                        size=(cfg.size, cfg.size), frames=cfg.frames, ground_truth=True,
                        play=True, options=dict(options)).resolved()


def _median_run(runs: list[dict]) -> dict:
    """The figures of the run whose time-weighted RMSE is the median, with each figure's
    spread (``min``, ``max`` over the runs) beside it."""
    def error(i: int) -> float:  # a run with no tick judged sorts last
        v = runs[i].get("rmse_time_weighted")
        return float("inf") if v is None else float(v)

    order = sorted(range(len(runs)), key=error)
    mid = dict(runs[order[len(order) // 2]])
    for key in FIGURES:
        vals = [r[key] for r in runs if r.get(key) is not None and r[key] == r[key]]
        if vals:
            mid[f"{key}_spread"] = [float(min(vals)), float(max(vals))]
    mid["runs"] = len(runs)
    return mid


def play_one(technique_name: str, renderer, path, rate: float, cache, cfg) -> tuple[dict, Any]:
    """One played run of ``technique_name`` on ``renderer`` at ``rate``, judged against
    ``cache``; its figures and the run's result."""
    from lodsprite import techniques
    from lodsprite.feedback import KnobFeedback
    from lodsprite.playback import run_played

    config = _config(cfg, technique_name)
    options = techniques.get(config.technique).bind(config.technique_options())
    t = techniques.create(config.technique, renderer, **options)
    try:
        if technique_name in ADJUST:
            ADJUST[technique_name](t)
        knob = TECHNIQUES[technique_name][2]
        control = None if knob is None else KnobFeedback(
            t, knob, TARGET_SHARE * 1e3 / rate)
        r = run_played(t, path, rate=rate, ground_truth=True, reference=cache, flip=True,
                       predict=cfg.predictor, control=None if control is None else control.after,
                       judge_every_s=cfg.judge_every_s, flip_every=cfg.flip_every,
                       vdp_seconds=cfg.vdp_seconds)
    finally:
        t.release()
    s = r.summary
    figures = {k: s.get(k) for k in FIGURES}
    if control is not None and control.values:
        figures[f"{knob}_median"] = float(np.median(control.values))
    figures["frames"] = len(r.frames)
    return figures, r


def reproduce_timecritical(cfg: TimeCriticalConfig, out_dir: Path,
                           progress: StageProgress | None = None) -> dict:
    """Play every technique at every rate ``repeats`` times (module doc); write each run's
    ``frames.csv``, ``ticks.csv`` and ``summary.json`` under ``out_dir/runs``; return the
    results (``timecritical`` -> path -> technique -> rate -> figures)."""
    from lodsprite.api import Renderer
    from lodsprite.display import ReferenceCache
    from lodsprite.harness import level_zero_reference, write_run
    from lodsprite.paths import CameraPath
    from lodsprite.paths.core import NOMINAL_FPS
    from lodsprite.runconfig import field_of_view, prepare

    out_dir = Path(out_dir)
    total = len(cfg.techniques) * len(cfg.rates) * cfg.repeats
    done = 0
    table: dict[str, dict[str, dict]] = {}
    cache = None
    how = ""
    # One path for every technique: a path that follows the terrain's heights is made
    # from the scene loaded, and a coarse level's scene over a store is not the adaptive
    # renderer's (up to 3 m apart along a flyover of a 4k² store)
    path = prepare(_config(cfg, "adaptive"))[1]
    if cfg.seconds is not None:  # the path's first seconds, at its own speed
        n = max(2, min(len(path), int(cfg.seconds * NOMINAL_FPS) + 1))
        path = CameraPath(path.name, path.viewpoints[:n], path.fov_y_deg)
    for name in cfg.techniques:
        config = _config(cfg, name)
        scene = prepare(config)[0]
        fov = field_of_view(config, path)
        with Renderer(scene, (cfg.size, cfg.size), fov) as renderer:
            ref = level_zero_reference(renderer.gl, scene, renderer.size, fov, "auto",
                                       cfg.samples)
            try:
                if cache is None:
                    cache = ReferenceCache(ref.image, key=(cfg.terrain, cfg.path, cfg.size,
                                                            cfg.samples))
                cache.reference = ref.image  # the same images, drawn on this context
                per_rate = {}
                for rate in cfg.rates:
                    runs = []
                    for k in range(cfg.repeats):
                        figures, result = play_one(name, renderer, path, rate, cache, cfg)
                        runs.append(figures)
                        write_run(out_dir / "runs" / f"{name}_{rate:g}_{k}", result)
                        done += 1
                        if progress:
                            progress(f"play {name} at {rate:g} fps", done, total)
                    per_rate[f"{rate:g}"] = _median_run(runs)
                table[name] = per_rate
                how = ref.describe()
            finally:
                ref.release()
    return {"config": {**cfg.__dict__, "rates": list(cfg.rates),
                       "techniques": list(cfg.techniques)},
            "path": cfg.path, "terrain": cfg.terrain, "reference": how,
            "reference_images": 0 if cache is None else cache.misses,
            "timecritical": {cfg.path: table}}


__all__ = ["RATES", "TECHNIQUES", "TimeCriticalConfig", "play_one", "reproduce_timecritical"]
