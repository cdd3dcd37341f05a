"""A camera path played in time: the path advances at its nominal speed in seconds, the
display draws as often as it can (or on the slots of a display rate), and the image on
screen is judged over display time, so that latency costs error where it should.

A timed run of the harness (:func:`lodsprite.harness.run_path`) draws every frame of a
path, one after another, however long each takes: it measures frame times, not what a
viewer sees.  Here (Swan et al. 2002 measure their client so: the camera moves while a
keyframe is on its way) frame ``k`` starts at ``start_s[k]`` seconds after the first
and draws the path's viewpoint at that time (:meth:`~lodsprite.paths.CameraPath.at_time`,
frame ``i`` of the path at ``i / fps``), or the one a predictor gives for its display
time; it is displayed when its ``ctx.finish()`` returns, or at a display rate on the
next slot after that, ``shown_s[k]``.  A frame that took long shows a viewpoint the
camera has left; a keyframe from a worker shows a view placed ahead by prediction.
Quality, in the untimed replay (:func:`lodsprite.display.judge_display`), compares the
image on screen at each display tick with the band-limited reference at that instant's
viewpoint, so an image counts for as long as it was shown.

Every technique runs the same: the same untimed warm-up at the path's first viewpoint,
the same clock (``ctx.finish()`` before it stops), nothing read back inside the played
loop.  A frame's ``ms`` is the technique's alone; the rows get ``start_s`` (the path's time
it drew), ``shown_s`` and ``latency_ms`` (``shown_s - start_s``), and judged, ``ticks``
and ``rmse``; the summary ``played_s``, ``path_fps``, ``display_rate``, ``display_fps``
(frames shown a second), ``missed_slots`` (at a display rate), ``latency_ms_mean``,
``predictor``, ``truncated`` (stopped by the frame cap before the path's end) and the
display-time figures (:func:`lodsprite.display.display_summary`).  Every frame up to the
cap is planned for replay (:meth:`~lodsprite.techniques.Technique.plan_replay`): which
ones will be on screen at a tick is known only after the run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lodsprite import vdp
from lodsprite.display import judge_display, tick_hz
from lodsprite.errors import InputError
from lodsprite.harness import (
    Reference,
    RunResult,
    quality_summary,
    technique_reference,
    warm_up,
)
from lodsprite.paths.core import NOMINAL_FPS
from lodsprite.record import Frame, frame_rows, frames_summary
from lodsprite.sprite.predictors import DecayLinearPredictor, KalmanPredictor

#: Viewpoint predictors a played run may draw for the display time with.
PREDICTORS = {"kalman": KalmanPredictor, "decay": DecayLinearPredictor}

#: The default cap on a played run's frames, per frame of the path (a display 16 times
#: faster than the path's frame rate: 480 frames a second at 30).
FRAMES_PER_PATH_FRAME = 16

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.paths import CameraPath
    from lodsprite.progress import Progress
    from lodsprite.techniques.base import Technique


def _played(technique: Technique, path: CameraPath, finish: Callable[[], None], fps: float,
            rate: float | None, progress: Progress | None, max_frames: int,
            predict: str | None = None, control: Callable[[float], None] | None = None
            ) -> tuple[list[Frame], list[dict], list[Viewpoint], np.ndarray, np.ndarray]:
    """The played loop: frames, decisions, the viewpoints drawn, their times (the path's
    time each frame started) and display times (seconds from the first frame's start); at
    most ``max_frames`` frames.  A frame's ``ms`` is the technique's alone (its
    ``frame()`` and ``ctx.finish()``), not the viewpoint's interpolation.

    With a display ``rate`` the display shows a new image only on its slots (every
    ``1 / rate`` seconds): a frame finished is shown at the next slot, and the next frame
    starts there; a slot with no new frame keeps the previous image (a missed slot).
    With ``predict`` each frame draws the viewpoint predicted for its display time (the
    next slot, or the last frame's duration ahead without a rate) from the viewpoints
    sampled at the frames' starts by the predictor it names (:data:`PREDICTORS`:
    ``kalman``, the eye and the orientation extrapolated; ``decay``, the 2002 paper's,
    the eye only); else the viewpoint at its start.
    ``control(ms)`` (a :class:`~lodsprite.feedback.KnobFeedback`'s ``after``) is told each
    frame's time once the frame is done, outside its clock."""
    duration = path.duration_s(fps)
    at = path.sampler()
    frames, decisions, drawn, starts, shown = [], [], [], [], []
    period = None if rate is None else 1.0 / rate
    predictor = None if predict is None else PREDICTORS[predict]()
    ahead = 0.0
    t0 = time.perf_counter()
    while True:
        start = time.perf_counter() - t0
        if start > duration or len(frames) == max_frames:
            break
        vp = at(start * fps)[0]
        if predictor is not None:
            predictor.observe(start, vp)
            vp = predictor.predict(period if period is not None else ahead)
        begin = time.perf_counter()
        f = technique.frame(vp)
        finish()
        done = time.perf_counter()
        frames.append(replace(f, ms=(done - begin) * 1e3))
        decisions.append(technique.decision())
        drawn.append(vp)
        starts.append(start)
        ahead = done - begin
        if control is not None:
            control(ahead * 1e3)
        if progress:
            progress(min(round((done - t0) / duration * len(path)), len(path)), len(path))
        if period is None:
            shown.append(done - t0)
            continue
        slot = math.ceil((done - t0) / period - 1e-9) * period  # shown on the next slot
        shown.append(slot)
        wait = slot - (time.perf_counter() - t0)
        if wait > 0:
            time.sleep(wait)
    return frames, decisions, drawn, np.array(starts), np.array(shown)


def missed_slots(shown_s: np.ndarray, rate: float) -> float:
    """The fraction of display slots from the first frame shown to the last that showed
    no new frame (``shown_s`` on slots of ``1 / rate`` seconds)."""
    slots = np.rint(np.asarray(shown_s) * rate)
    total = slots[-1] - slots[0]
    return float((total - (len(np.unique(slots)) - 1)) / total) if total > 0 else 0.0


def run_played(technique: Technique, path: CameraPath, *, fps: float = NOMINAL_FPS,
               rate: float | None = None, finish: Callable[[], None] | None = None,
               gl_renderer: str = "", progress: Progress | None = None,
               ground_truth: bool = False, reference: Reference | None = None,
               quality_stride: int = 1, flip: bool = False,
               max_frames: int | None = None, predict: str | None = None,
               control: Callable[[float], None] | None = None,
               judge_every_s: float | None = None, flip_every: int = 1,
               vdp_seconds: float | None = None) -> RunResult:
    """Play ``path`` in time with ``technique`` (module doc): its frames at ``fps`` frames
    a second of path, drawn as often as the technique can, or on the slots of ``rate``
    frames a second; with ``ground_truth`` the image on screen judged in the untimed
    replay at ticks of max(rate, 60) Hz (``quality_stride``, or ``judge_every_s``
    seconds: pairs of ticks that far apart; FLIP on every ``flip_every``-th) against
    ``reference`` (default: the technique's own, else the band-limited level 0), and with
    ``vdp_seconds`` ColorVideoVDP over that much of the run, centred
    (:func:`lodsprite.vdp.window`; the vdp extra).
    ``predict``: a :data:`PREDICTORS` name, each frame drawn for the viewpoint it predicts
    at the frame's display time; ``control(ms)``: told each frame's time after it (a
    frame-time controller).  ``max_frames`` (default :data:`FRAMES_PER_PATH_FRAME` a path
    frame) caps the frames drawn, because the replay's plan is made before the run for
    every frame that may come; a run stopped by it before the path's end says
    ``truncated`` in its summary.  A technique whose frames follow the frame count rather
    than the time (:attr:`~lodsprite.techniques.Technique.plays_in_time` False) is
    refused.  Returns the frames, rows, ticks and summary (not written)."""
    if not fps > 0:
        raise InputError(f"a path's frame rate must be > 0, got {fps}")
    if rate is not None and not rate > 0:
        raise InputError(f"a display rate must be > 0, got {rate}")
    if predict is not None and predict not in PREDICTORS:
        raise InputError(f"a predictor is one of {', '.join(PREDICTORS)}, not {predict!r}")
    if quality_stride < 1:
        raise InputError(f"quality stride must be >= 1, got {quality_stride}")
    if len(path.viewpoints) < 2:
        raise InputError("a played run needs a path of at least two viewpoints")
    if not technique.plays_in_time:
        raise InputError(f"{technique.name} cannot be played in time: its frames follow "
                         "the frame count, not the clock")
    if vdp_seconds is not None:
        if not ground_truth:
            raise InputError("ColorVideoVDP judges against the reference: it needs "
                             "ground truth")
        vdp.window(0.0, 1.0, vdp_seconds)  # a bad length fails before the run
        vdp.require()
    if ground_truth and not technique.replays:
        raise InputError(f"{technique.name} cannot replay its frames: no ground truth")
    with ExitStack() as stack:
        if ground_truth and reference is None:
            reference = stack.enter_context(technique_reference(technique, path))
        return _run(technique, path, fps, rate, finish, gl_renderer, progress,
                    reference if ground_truth else None, quality_stride, flip,
                    FRAMES_PER_PATH_FRAME * len(path) if max_frames is None
                    else int(max_frames), predict, control, judge_every_s, flip_every,
                    vdp_seconds)


def _run(technique, path, fps, rate, finish, gl_renderer, progress, reference,
         quality_stride, flip, cap, predict, control, judge_every_s, flip_every,
         vdp_seconds=None) -> RunResult:
    renderer = technique.renderer
    finish = finish or renderer.gl.finish
    technique.plan_replay(set(range(cap)) if reference else set())
    first_ms = warm_up(technique, path.viewpoints[0], finish)
    frames, decisions, drawn, starts, shown = _played(technique, path, finish, fps, rate,
                                                      progress, cap, predict, control)
    own = technique.summary(frames)
    rows, columns = frame_rows(frames)
    for row, a, b in zip(rows, starts, shown, strict=True):
        row.update(start_s=float(a), shown_s=float(b), latency_ms=float(b - a) * 1e3)
    at = columns.index("ms") + 1
    columns[at:at] = ["start_s", "shown_s", "latency_ms"]
    shown_summary: dict = {}
    ticks: list[dict] = []
    truncated = bool(len(frames) == cap and shown[-1] < path.duration_s(fps))
    if reference is not None:
        sampler = path.sampler()
        end = float(shown[-1]) if truncated else path.duration_s(fps)
        hz = tick_hz(rate)
        stride = quality_stride if judge_every_s is None else max(1, round(judge_every_s * hz))
        ticks, shown_summary = judge_display(
            technique, drawn, decisions, shown, lambda t: sampler(t * fps), reference,
            hz, end, stride, flip, flip_every,
            None if vdp_seconds is None else vdp.window(float(shown[0]), end, vdp_seconds))
        per_frame: dict[int, list[float]] = {}
        for t in ticks:
            per_frame.setdefault(t["frame"], []).append(t["rmse"])
        for k, v in per_frame.items():  # each frame: its ticks on screen, their mean error
            rows[k].update(ticks=len(v), rmse=float(np.mean(v)))
        columns += ["ticks", "rmse"]
    summary = {**frames_summary(frames, technique.name, gl_renderer or (
        renderer.info.renderer if renderer else ""), first_ms), **own,
        **quality_summary(rows), **shown_summary,
        "played_s": float(shown[-1]), "path_fps": float(fps),
        "display_rate": rate, "display_fps": len(frames) / float(shown[-1]),
        "latency_ms_mean": float(np.mean(shown - starts) * 1e3),
        "predictor": predict, "truncated": truncated}
    if rate is not None:
        summary["missed_slots"] = missed_slots(shown, rate)
    return RunResult(frames, decisions, rows, columns, summary, ticks=ticks)


__all__ = ["FRAMES_PER_PATH_FRAME", "PREDICTORS", "missed_slots", "run_played"]
