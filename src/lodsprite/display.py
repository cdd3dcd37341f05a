"""Error over display time: what a viewer of a run played in time sees, judged on a common
grid of ticks of path time.

A played run (:mod:`lodsprite.playback`) shows frame ``k`` from ``shown_s[k]`` until the
next frame replaces it.  Judging each shown frame once counts an image on screen for
3 ms like one on screen for 300 ms.  Here the display is sampled at ticks ``j / hz``
seconds of path time (``hz`` = max(display rate, :data:`MIN_TICK_HZ`)): at each tick the
image on screen (the last frame shown at or before it) is compared with the reference
at that instant's viewpoint, so that an image held long counts long, and a frame the
camera has moved on from costs what the viewer sees.  On consecutive ticks the flicker
(:func:`lodsprite.metrics.flicker`) is taken on ticks 1/60 s apart, the same interval
at every display rate: a held image against a moving reference, shimmer and popping all
score.

The summary: ``rmse_time_weighted`` (the mean over ticks, i.e. each shown image's error
weighted by its time on screen), ``flip_time_weighted`` (with FLIP), ``flicker`` (mean
over the tick pairs 1/60 s apart), ``rmse_worst_second`` (the worst mean over the ticks
of one second of path time), ``ticks`` and ``tick_hz``.

Reference images are cached (:class:`ReferenceCache`) by a key the caller gives (what
makes two references' images equal: the terrain, size and samples) and the viewpoint, so
techniques and display rates judged along one path share them.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite import vdp
from lodsprite.errors import InputError

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.techniques.base import Technique

MIN_TICK_HZ = 60.0


def tick_hz(display_rate: float | None) -> float:
    """Ticks a second for a run at ``display_rate`` (None: as fast as it draws)."""
    return max(float(display_rate or 0.0), MIN_TICK_HZ)


def tick_times(first_s: float, end_s: float, hz: float) -> np.ndarray:
    """Tick times ``j / hz`` seconds from the first at or after ``first_s`` to the last at or
    before ``end_s``; empty when none falls between them."""
    if not hz > 0:
        raise InputError(f"a tick rate must be > 0, got {hz}")
    j0 = math.ceil(first_s * hz - 1e-9)
    j1 = math.floor(end_s * hz + 1e-9)
    return np.arange(j0, j1 + 1, dtype=np.float64) / hz


def on_screen(shown_s: np.ndarray, ticks: np.ndarray) -> np.ndarray:
    """Index of the frame on screen at each tick (the last shown at or before it; -1 before
    the first); ``shown_s`` nondecreasing."""
    return np.searchsorted(np.asarray(shown_s), np.asarray(ticks) + 1e-12, side="right") - 1


def weights(shown_s: np.ndarray, end_s: float, hz: float) -> np.ndarray:
    """Ticks each frame is on screen for, from its display to ``end_s``: its weight in
    the time-weighted error."""
    idx = on_screen(shown_s, tick_times(float(shown_s[0]), end_s, hz))
    return np.bincount(idx[idx >= 0], minlength=len(shown_s))


def worst_second(times_s: np.ndarray, values: np.ndarray, window_s: float = 1.0) -> float:
    """The largest mean of ``values`` over the samples whose ``times_s`` (ascending) fall in
    a window ``[t, t + window_s)`` starting at a sample; the mean of all when the samples
    span less than the window."""
    t = np.asarray(times_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if not len(v):
        return float("nan")
    if t[-1] - t[0] < window_s:
        return float(v.mean())
    c = np.concatenate([[0.0], np.cumsum(v)])
    ends = np.searchsorted(t, t + window_s - 1e-9, side="left")
    starts = np.arange(len(t))
    full = t + window_s <= t[-1] + 1e-9  # windows wholly inside the judged span
    means = (c[ends] - c[starts])[full] / (ends - starts)[full]
    return float(means.max())


class ReferenceCache:
    """Reference images by ``(key, viewpoint)``, least recently used dropped past
    ``max_bytes``; ``reference(viewpoint) -> (h, w, 3) uint8`` draws a missing one."""

    def __init__(self, reference: Callable[[Any], np.ndarray], key: Any = None,
                 max_bytes: int = 2 << 30) -> None:
        self.reference, self.key, self.max_bytes = reference, key, int(max_bytes)
        self._images: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._bytes = 0
        self.hits = self.misses = 0

    @staticmethod
    def viewpoint_key(vp: Viewpoint) -> bytes:
        return np.concatenate([vp.x, vp.y, vp.z, vp.o]).astype(np.float64).tobytes()

    def __call__(self, viewpoint: Viewpoint) -> np.ndarray:
        k = (self.key, self.viewpoint_key(viewpoint))
        image = self._images.get(k)
        if image is not None:
            self.hits += 1
            self._images.move_to_end(k)
            return image
        self.misses += 1
        image = np.asarray(self.reference(viewpoint))
        self._images[k] = image
        self._bytes += image.nbytes
        while self._bytes > self.max_bytes and len(self._images) > 1:
            _, old = self._images.popitem(last=False)
            self._bytes -= old.nbytes
        return image


def judge_display(technique: Technique, drawn: Sequence[Viewpoint], decisions: list[dict],
                  shown_s: np.ndarray, viewpoint_at: Callable[[np.ndarray], list],
                  reference: Callable[[Any], np.ndarray], hz: float, end_s: float,
                  stride: int = 1, flip: bool = False, flip_every: int = 1,
                  video: tuple[float, float] | None = None, video_display: str | None = None
                  ) -> tuple[list[dict], dict]:
    """Judge a played run on ticks of ``hz`` (module doc): frame ``k``, drawn at
    ``drawn[k]`` with ``decisions[k]`` and shown at ``shown_s[k]`` seconds, replayed
    (:meth:`~lodsprite.techniques.Technique.replay`, in order, once) while it is on
    screen; the reference at ``viewpoint_at(ticks)`` (seconds of path time to
    viewpoints).  The flicker compares ticks 1/60 s apart (consecutive ticks at 60 Hz,
    every other at 120: one interval at every rate).  ``stride`` > 1 judges the pairs of
    ticks ``j, j + 1/60 s`` for ``j`` a multiple of it; FLIP (with ``flip``) is taken on
    the first tick of every ``flip_every``-th pair (FLIP costs far more than RMSE).  Pairs
    are counted from tick 0 of the path's time, so runs at rates whose ``stride / hz``
    agree are judged at the same instants (and share cached references).  Returns the
    tick rows (``tick``, the tick's number from the path's start at ``hz``, ``t_s``,
    ``frame``, ``rmse``, ``flip``,
    ``flicker``) and the summary keys.  ``video`` (``(start_s, end_s)`` of path time):
    every tick in it is also collected, the image on screen and the reference, and the
    two sequences judged by ColorVideoVDP at ``hz`` frames a second
    (:func:`lodsprite.vdp.jod`, on ``video_display``): ``cvvdp_jod``, ``cvvdp_window_s``
    in the summary; those ticks add no rows."""
    from lodsprite import metrics

    shown_s = np.asarray(shown_s, dtype=np.float64)
    ticks = tick_times(float(shown_s[0]), end_s, hz)
    gap = max(1, round(hz / MIN_TICK_HZ))  # ticks in 1/60 s: the flicker's interval
    number = np.rint(ticks * hz).astype(np.int64)  # tick numbers from the path's start
    judge = np.ones(len(ticks), dtype=bool)
    if stride > 1:
        judge = (number % stride == 0) | (number % stride == gap % stride)
    filmed = np.zeros(len(ticks), dtype=bool)
    if video is not None:
        vdp.require()
        filmed = (ticks >= video[0] - 1e-9) & (ticks <= video[1] + 1e-9)
    keep = judge | filmed
    ticks, number, judge, filmed = ticks[keep], number[keep], judge[keep], filmed[keep]
    frames = on_screen(shown_s, ticks)
    views = viewpoint_at(ticks * 1.0) if len(ticks) else []
    rows: list[dict] = []
    current, image = -1, None
    judged: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # tick number -> (image, truth)
    film: tuple[np.ndarray, np.ndarray] | None = None  # the window's (test, reference)
    at = 0
    for t, j, k, vp, row_here, film_here in zip(ticks, number, frames, views, judge,
                                                 filmed, strict=True):
        if k != current:
            image = np.array(technique.replay(drawn[k], decisions[k]))
            current = k
        truth = reference(vp)
        if film_here:
            if film is None:
                vdp.check_size(int(filmed.sum()), *image.shape[:2])
                film = (np.empty((int(filmed.sum()), *image.shape), np.uint8),
                        np.empty((int(filmed.sum()), *image.shape), np.uint8))
            film[0][at], film[1][at] = image, truth
            at += 1
        if not row_here:
            continue
        row = {"tick": int(j), "t_s": float(t), "frame": int(k),
               "rmse": metrics.rmse(image, truth)}
        if flip and (stride == 1 and j % flip_every == 0
                     or stride > 1 and j % (stride * flip_every) == 0):
            row["flip"] = metrics.flip(image, truth)
        before = judged.get(int(j) - gap)
        if before is not None:
            row["flicker"] = metrics.flicker(image, before[0], truth, before[1])
        judged[int(j)] = (image, truth)
        judged.pop(int(j) - 2 * gap, None)
        rows.append(row)
    summary = display_summary(rows, hz)
    if film is not None:
        summary["cvvdp_jod"] = vdp.jod(film[0], film[1], hz, video_display or vdp.DISPLAY)
        summary["cvvdp_window_s"] = [float(ticks[filmed][0]), float(ticks[filmed][-1])]
        summary["cvvdp_display"] = video_display or vdp.DISPLAY
    return rows, summary


def display_summary(rows: list[dict], hz: float) -> dict:
    """The time-weighted figures of judged tick rows (module doc)."""
    if not rows:
        return {"ticks": 0, "tick_hz": hz}
    rmse = np.array([r["rmse"] for r in rows])
    out: dict = {"ticks": len(rows), "tick_hz": hz,
                 "rmse_time_weighted": float(rmse.mean()),
                 "rmse_worst_second": worst_second([r["t_s"] for r in rows], rmse)}
    flips = [r["flip"] for r in rows if "flip" in r]
    if flips:
        out["flip_time_weighted"] = float(np.mean(flips))
    flick = [r["flicker"] for r in rows if "flicker" in r]
    if flick:
        out["flicker"] = float(np.mean(flick))
    return out


__all__ = ["MIN_TICK_HZ", "ReferenceCache", "display_summary", "judge_display", "on_screen",
           "tick_hz", "tick_times", "weights", "worst_second"]
