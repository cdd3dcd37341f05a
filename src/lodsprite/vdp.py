"""ColorVideoVDP (Mantiuk, Hanji, Ashraf, Asano, Chapiro 2024; the ``cvvdp`` package) on
the played sequences: what a viewer sees of a run, as a video against the reference's.

Per-frame RMSE, FLIP and the flicker of :mod:`lodsprite.display` judge pixels; ColorVideoVDP
models the visual system over space, time and colour and gives one figure for a whole
sequence in JOD (just-objectionable differences: 10 is indistinguishable from the
reference, each unit less is one where 75 % of viewers would prefer the reference).  It
sees what flicker and held frames do to a viewer, weighted by the display's model.

It is an optional extra (``pip install 'lodsprite[vdp]'``: cvvdp, PyTorch, torchvision);
:func:`require` raises :class:`~lodsprite.errors.InputError` naming it when missing.
The metric runs in a process of its own (spawned once, kept for the next call): PyTorch
is never imported beside the GL context (a CUDA build of PyTorch imported into a process
with a Mesa EGL context crashed it here), and its threads never share a process with the
renderers.  Runs on the CPU here; on a CUDA machine PyTorch's device is used.

The sequence judged is a window of the played run (:func:`window`): every display tick of
``seconds`` of path time centred in the run, the image on screen at each tick against
the reference at that instant (:func:`lodsprite.display.judge_display`), played to the
metric at the tick rate.  The display model is cvvdp's ``standard_fhd`` (a 24-inch
1920×1080 SDR monitor seen from 60 cm, 200 cd/m²) unless another is named.
"""

from __future__ import annotations

import atexit
import functools
import importlib.util
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from lodsprite.errors import InputError

VDP_EXTRA = "lodsprite[vdp]"
DISPLAY = "standard_fhd"
MAX_VIDEO_BYTES = 4 << 30
"""Cap on one window's two sequences (test and reference, uint8), checked before they are
allocated."""


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def available() -> bool:
    """Whether the extra is installed (cvvdp, PyTorch and torchvision found; none of
    them imported here)."""
    return all(_installed(m) for m in ("pycvvdp", "torch", "torchvision"))


def require() -> None:
    """:class:`InputError` naming the extra that installs ColorVideoVDP, where it is
    missing."""
    if not available():
        raise InputError("ColorVideoVDP needs the vdp extra (cvvdp, PyTorch): "
                         f"pip install '{VDP_EXTRA}'")


def window(first_s: float, end_s: float, seconds: float) -> tuple[float, float]:
    """``seconds`` of path time centred in ``[first_s, end_s]`` (all of it when shorter)."""
    if not seconds > 0:
        raise InputError(f"a ColorVideoVDP window must be > 0 s, got {seconds}")
    span = end_s - first_s
    if span <= seconds:
        return float(first_s), float(end_s)
    a = first_s + (span - seconds) / 2
    return float(a), float(a + seconds)


def check_request(seconds: float | None, played: bool, ground_truth: bool) -> None:
    """:class:`InputError` unless ``seconds`` (None: not asked for) goes with a run played
    in time and judged against the reference, and is > 0."""
    if seconds is not None and not (played and ground_truth and seconds > 0):
        raise InputError(f"--vdp goes with --play and --ground-truth and is > 0 s, got "
                         f"{seconds}")


def check_size(frames: int, height: int, width: int) -> None:
    """:class:`InputError` when a window's two uint8 sequences would exceed
    :data:`MAX_VIDEO_BYTES`."""
    need = 2 * frames * height * width * 3
    if need > MAX_VIDEO_BYTES:
        raise InputError(f"a ColorVideoVDP window of {frames} frames at {width}x{height} "
                         f"needs {need / 2**30:.1f} GiB (at most "
                         f"{MAX_VIDEO_BYTES / 2**30:.0f}): shorten it")


@functools.lru_cache(maxsize=2)
def _metric(display: str) -> Any:  # in the metric's process
    import pycvvdp

    return pycvvdp.cvvdp(display_name=display, quiet=True)


def _jod(test: np.ndarray, reference: np.ndarray, fps: float, display: str) -> float:
    import torch

    with torch.no_grad():
        q, _ = _metric(display).predict(test, reference, dim_order="FHWC",
                                        frames_per_second=float(fps))
    return float(q)


_POOL: ProcessPoolExecutor | None = None


def _pool() -> ProcessPoolExecutor:
    """The metric's process (spawned, not forked: a fork would copy the GL context)."""
    global _POOL
    if _POOL is None:
        _POOL = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        atexit.register(_POOL.shutdown)
    return _POOL


def jod(test: np.ndarray, reference: np.ndarray, fps: float, display: str = DISPLAY) -> float:
    """ColorVideoVDP of ``test`` against ``reference``: ``(frames, h, w, 3)`` uint8 sRGB
    sequences shown at ``fps`` frames a second on ``display`` (a cvvdp display model's
    name).  Returns JOD, 10 for identical sequences."""
    test, reference = np.asarray(test), np.asarray(reference)
    if test.shape != reference.shape or test.ndim != 4 or test.shape[-1] != 3:
        raise InputError(f"ColorVideoVDP takes two (frames, h, w, 3) sequences of one "
                         f"shape, got {test.shape} and {reference.shape}")
    if test.dtype != np.uint8 or reference.dtype != np.uint8:
        raise InputError("ColorVideoVDP takes uint8 sRGB frames")
    if not fps > 0:
        raise InputError(f"a frame rate must be > 0, got {fps}")
    require()
    return _pool().submit(_jod, test, reference, float(fps), display).result()


__all__ = ["DISPLAY", "MAX_VIDEO_BYTES", "VDP_EXTRA", "available", "check_request",
           "check_size", "jod", "require", "window"]
