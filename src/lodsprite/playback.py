"""A camera path played in time: the path advances at its nominal speed in seconds, the
display draws as often as it can (or at a target rate), and each displayed frame is judged
at the viewpoint of its display time, so that latency costs error where it should.

A timed run of the harness (:func:`lodsprite.harness.run_path`) draws every frame of a
path, one after another, however long each takes: it measures frame times, not what a
viewer sees.  Here (Swan et al. 2002 measure their client so: the camera moves while a
keyframe is on its way) frame ``k`` starts at ``start_s[k]`` seconds after the first
and draws the path's viewpoint at that time (:meth:`~lodsprite.paths.CameraPath.at_time`,
frame ``i`` of the path at ``i / fps``); it is displayed when its ``ctx.finish()`` returns,
``shown_s[k]``.  A frame that took long shows a viewpoint the camera has left; a keyframe
from a worker shows a view placed ahead by prediction.  Quality, in the untimed replay
(:func:`lodsprite.harness.replay_frames`), compares the frame as drawn with the reference
at the viewpoint of ``shown_s[k]``.

Every technique runs the same: the same untimed warm-up at the path's first viewpoint,
the same clock (``ctx.finish()`` before it stops), nothing read back inside the played
loop.  The rows get ``start_s``, ``shown_s`` and ``latency_ms`` (``shown_s - start_s``);
the summary ``played_s``, ``path_fps``, ``display_rate``, ``display_fps`` (frames shown a
second) and ``latency_ms_mean``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.errors import InputError
from lodsprite.harness import (
    Reference,
    RunResult,
    full_resolution,
    quality_columns,
    quality_summary,
    replay_frames,
    warm_up,
)
from lodsprite.paths.core import NOMINAL_FPS
from lodsprite.record import Frame, frame_rows, frames_summary

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.paths import CameraPath
    from lodsprite.progress import Progress
    from lodsprite.techniques.base import Technique


def _played(technique: Technique, path: CameraPath, finish: Callable[[], None], fps: float,
            rate: float | None, progress: Progress | None, max_frames: int
            ) -> tuple[list[Frame], list[dict], list[Viewpoint], np.ndarray, np.ndarray]:
    """The played loop: frames, decisions, the viewpoints drawn, their start and display
    times (seconds from the first frame's start); at most ``max_frames`` frames."""
    duration = path.duration_s(fps)
    frames, decisions, drawn, starts, shown = [], [], [], [], []
    period = None if rate is None else 1.0 / rate
    t0 = time.perf_counter()
    while True:
        start = time.perf_counter() - t0
        if start > duration or len(frames) == max_frames:
            break
        vp = path.at_time(start, fps)
        f = technique.frame(vp)
        finish()
        end = time.perf_counter() - t0
        frames.append(replace(f, ms=(end - start) * 1e3))
        decisions.append(technique.decision())
        drawn.append(vp)
        starts.append(start)
        shown.append(end)
        if progress:
            progress(min(round(end / duration * len(path)), len(path)), len(path))
        if period is not None:  # a display rate: the next frame starts on its slot
            wait = (len(frames) * period) - (time.perf_counter() - t0)
            if wait > 0:
                time.sleep(wait)
    return frames, decisions, drawn, np.array(starts), np.array(shown)


def run_played(technique: Technique, path: CameraPath, *, fps: float = NOMINAL_FPS,
               rate: float | None = None, finish: Callable[[], None] | None = None,
               gl_renderer: str = "", progress: Progress | None = None,
               ground_truth: bool = False, reference: Reference | None = None,
               quality_stride: int = 1, flip: bool = False,
               max_frames: int | None = None) -> RunResult:
    """Play ``path`` in time with ``technique`` (module doc): its frames at ``fps`` frames
    a second of path, drawn as often as the technique can, or at most ``rate`` frames a
    second; with ``ground_truth`` each ``quality_stride``-th displayed frame compared, in
    the untimed replay, with ``reference`` (default: the renderer's full resolution) at
    its display time's viewpoint.  ``max_frames`` (default four a path frame) caps the
    frames drawn: the replay's plan (:meth:`~lodsprite.techniques.Technique.plan_replay`)
    is made before the run for every frame that may come.  Returns the frames, rows and
    summary (not written)."""
    if not fps > 0:
        raise InputError(f"a path's frame rate must be > 0, got {fps}")
    if rate is not None and not rate > 0:
        raise InputError(f"a display rate must be > 0, got {rate}")
    if quality_stride < 1:
        raise InputError(f"quality stride must be >= 1, got {quality_stride}")
    if len(path.viewpoints) < 2:
        raise InputError("a played run needs a path of at least two viewpoints")
    if ground_truth and not technique.replays:
        raise InputError(f"{technique.name} cannot replay its frames: no ground truth")
    renderer = technique.renderer
    finish = finish or renderer.gl.finish
    cap = 4 * len(path) if max_frames is None else int(max_frames)
    technique.plan_replay(set(range(0, cap, quality_stride)) if ground_truth else set())
    first_ms = warm_up(technique, path.viewpoints[0], finish)
    frames, decisions, drawn, starts, shown = _played(technique, path, finish, fps, rate,
                                                      progress, cap)
    own = technique.summary(frames)
    rows, columns = frame_rows(frames)
    for row, a, b in zip(rows, starts, shown, strict=True):
        row.update(start_s=float(a), shown_s=float(b), latency_ms=float(b - a) * 1e3)
    columns[columns.index("ms") + 1:columns.index("ms") + 1] = ["start_s", "shown_s",
                                                                 "latency_ms"]
    if ground_truth:
        judged = path.between(shown * fps)
        replay_frames(technique, drawn, judged, decisions, rows,
                      reference or full_resolution(renderer), quality_stride, flip, None,
                      None)
        columns += [c for c in quality_columns(rows) if c not in columns]
    summary = {**frames_summary(frames, technique.name, gl_renderer or (
        renderer.info.renderer if renderer else ""), first_ms), **own,
        **quality_summary(rows), "played_s": float(shown[-1]), "path_fps": float(fps),
        "display_rate": rate, "display_fps": len(frames) / float(shown[-1]),
        "latency_ms_mean": float(np.mean(shown - starts) * 1e3)}
    return RunResult(frames, decisions, rows, columns, summary)


__all__ = ["run_played"]
