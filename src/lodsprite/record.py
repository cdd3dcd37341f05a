"""The one frame record: :class:`Frame`, what every engine hands its driver for a frame.

Every technique's :meth:`~lodsprite.techniques.Technique.frame`, and the engines under them
(LOD-sprite's, the crowd's LOD manager, the distributed client, the lumigraph methods, the
adaptive terrain renderer, the layers of a composed scene), return a :class:`Frame`; the
harness (:func:`lodsprite.harness.run_path`) and the window
(:class:`~lodsprite.viewer.core.ViewerCore`) write their ``frames.csv`` rows from it
(:func:`frame_rows`) and the core keys of their ``summary.json`` (:func:`frames_summary`),
so that ``ms`` and every core column mean the same whoever drove the run; what a run
hands back (:class:`RunResult`) and what judges it (:data:`Reference`) are here too, so a
technique names them without the harness.  An engine's
own figures go in :attr:`Frame.extra` (each key a column of ``frames.csv``).  This module
imports nothing of the package but its errors, so that every layer can hand one back.
"""

from __future__ import annotations

import math
import platform
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lodsprite.errors import InputError

#: The first columns of every ``frames.csv``, batch or window: the frame's index, then
#: :class:`Frame`'s fields; the engine's own (:attr:`Frame.extra`) follow.
CORE_COLUMNS = ("frame", "kind", "ms", "triangles", "error_px")
#: The first keys of every ``summary.json`` (:func:`frames_summary`).
CORE_KEYS = ("frames", "median_ms", "mean_ms", "std_ms", "p95_ms", "p99_ms", "max_ms",
             "total_s", "first_frame_ms", "gl_renderer")


@dataclass(frozen=True)
class Frame:
    """One frame, for every technique.

    ``kind``: what the frame was (``full``, ``lod``, ``adaptive``, ``keyframe``,
    ``first_sprite``, ``sprite``, a lumigraph method's frame kind, a crowd mode, ...);
    ``ms``: its time (milliseconds, GL work finished; the harness replaces it with its own
    clock); ``triangles`` drawn; ``error_px``: the error of the image shown (pixels, NaN
    where the technique does not measure one); ``extra``: the technique's own columns of
    ``frames.csv`` (scalars; e.g. ``keyframe``, ``resident``, ``uploads``).
    """

    kind: str
    ms: float
    triangles: int = 0
    error_px: float = math.nan
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def type(self) -> str:
        """The frame's kind (the name it had before one frame record served all)."""
        return self.kind

    @property
    def keyframes(self) -> int:
        """Keyframes taken so far (0 for a technique without keyframes)."""
        return int(self.extra.get("keyframes", 0))

    @property
    def keyframe(self) -> int:
        """The index of the keyframe the frame shows (-1: none, or a technique without
        keyframes)."""
        return int(self.extra.get("keyframe", -1))


def timing_summary(ms: np.ndarray) -> dict[str, float]:
    """The core timing keys of per-frame times ``ms`` (milliseconds): median, mean,
    standard deviation, p95, p99, max (ms) and total (s)."""
    ms = np.asarray(ms, dtype=np.float64)
    if ms.size == 0:
        raise InputError("a run needs at least one frame")
    return {"frames": int(ms.size), "median_ms": float(np.median(ms)),
            "mean_ms": float(ms.mean()), "std_ms": float(ms.std()),
            "p95_ms": float(np.percentile(ms, 95)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()), "total_s": float(ms.sum() / 1e3)}


def frames_summary(frames: list[Frame], technique: str, gl_renderer: str,
                   first_frame_ms: float) -> dict[str, Any]:
    """The core keys of a run's ``summary.json`` (:data:`CORE_KEYS`) from its frames (their
    ``ms``: the technique's frame and ``ctx.finish()``), whoever drove it (the harness, the
    window): timing, ``first_frame_ms`` (the warm-up), ``gl_renderer``, ``technique``,
    ``triangles_mean``, ``machine``, ``python``."""
    return {**timing_summary(np.array([f.ms for f in frames])),
            "first_frame_ms": first_frame_ms, "gl_renderer": gl_renderer,
            "technique": technique,
            "triangles_mean": float(np.mean([f.triangles for f in frames])),
            "machine": platform.machine(), "python": platform.python_version()}


def frame_rows(frames: list[Frame]) -> tuple[list[dict], list[str]]:
    """The rows of ``frames.csv`` and their columns: the core ones, then the technique's
    own (in the order first seen)."""
    rows, extra = [], {}
    for i, f in enumerate(frames):
        rows.append({"frame": i, "kind": f.kind, "ms": f.ms, "triangles": f.triangles,
                     "error_px": f.error_px, **f.extra})
        extra.update(dict.fromkeys(f.extra))
    return rows, [*CORE_COLUMNS, *(k for k in extra if k not in CORE_COLUMNS)]


#: A reference image maker: a viewpoint to its reference image ``(h, w, 3) uint8``
#: (:func:`lodsprite.harness.scene_reference`).
Reference = Callable[[Any], np.ndarray]


@dataclass
class RunResult:
    """What :func:`run_path` measured: the frames (times from the harness's clock), the
    decisions recorded, the rows of ``frames.csv`` with their column order, the summary."""

    frames: list[Frame]
    decisions: list[dict]
    rows: list[dict]
    columns: list[str]
    summary: dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False  # stopped by Ctrl-C: the frames finished so far
    #: Replayed images a caller asked to keep, by frame (:class:`lodsprite.run.Measure`).
    images: dict[int, np.ndarray] = field(default_factory=dict)
    #: A played run's display ticks judged (:func:`lodsprite.display.judge_display`).
    ticks: list[dict] = field(default_factory=list)
