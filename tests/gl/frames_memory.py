"""Render many small terrain frames in this (fresh) process and report its memory.

Run by ``test_terrain_render.py`` with ``sys.executable`` so that the resident set it
measures is that of a process which did nothing but these frames (no earlier tests'
garbage, no tracemalloc)::

    python3 tests/gl/frames_memory.py WARMUP WINDOW WINDOWS [--tracemalloc]

Prints one JSON object: ``frames`` (the frame count at the end of the warm-up and of
each window of ``WINDOW`` frames: ``WINDOWS + 1`` values), ``rss`` (bytes: the least
resident set of this process sampled every ``SAMPLE`` frames within the warm-up's last
stretch and within each window; the least, because llvmpipe and malloc hold buffers of
several MB for a while and give them back, which a single sample would catch or miss by
chance, while a leak raises every sample), ``py`` (traced Python heap bytes at the end
of the warm-up and of each window, only with ``--tracemalloc``, which then also skews
``rss``: run it apart) and ``leaked`` (type names of GL objects dropped without
``release()``, found by moderngl's ``context_gc``).
"""

from __future__ import annotations

import ctypes
import gc
import json
import resource
import sys
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/conftest.py

import numpy as np  # noqa: E402

from conftest import make_field  # noqa: E402
from lodsprite.camera import look_at  # noqa: E402
from lodsprite.gl.context import GLContext  # noqa: E402
from lodsprite.gl.terrain import TerrainDrawer, TerrainGeometry  # noqa: E402

SAMPLE = 50  # frames between resident-set samples
_LIBC = ctypes.CDLL(None) if hasattr(ctypes.CDLL(None), "malloc_trim") else None


def rss_bytes() -> int:
    """This process's resident set now (bytes), from /proc/self/statm, after glibc's
    ``malloc_trim(0)`` has handed free heap pages back: memory freed after LLVM's shader
    compiles and other passing buffers stays resident otherwise, and a leak would fill
    those holes for tens of MB before the resident set showed it."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def measure(warmup: int, window: int, windows: int, trace: bool) -> dict:
    """Draw ``warmup + window * windows`` frames (32² px, a 64² field, full resolution
    and the 8² level in turn, round a 50-view orbit); sample memory as described above."""
    gl = GLContext()
    gl.mgl.gc_mode = "context_gc"  # a GL object dropped without release() lands in objects
    hf = make_field(64)
    geo = TerrainGeometry(gl, hf, np.full((8, 8, 3), (200, 40, 40), np.uint8))
    r = TerrainDrawer(gl, geo, 32, 32)
    vps = [look_at((2000 * np.cos(a), 2000 * np.sin(a), 900.0), (0, 0, 0))
           for a in np.linspace(0, 2 * np.pi, 50)]
    out: dict = {"frames": [], "rss": [], "py": []}
    if trace:
        tracemalloc.start()
    done = 0
    for n in [warmup] + [window] * windows:
        least = None
        for i in range(done, done + n):
            r.render(vps[i % len(vps)], 8 if i % 2 else None)
            if (i + 1 - done) % SAMPLE == 0 and done + n - i <= window:
                gl.finish()
                least = min(rss_bytes(), least or sys.maxsize)
        done += n
        gl.finish()
        gc.collect()
        out["frames"].append(done)
        out["rss"].append(min(rss_bytes(), least or sys.maxsize))
        if trace:
            out["py"].append(tracemalloc.get_traced_memory()[0])
    # Objects released properly become InvalidObject; anything else was leaked.
    out["leaked"] = [type(o).__name__ for o in gl.mgl.objects
                     if type(o.mglo).__name__ != "InvalidObject"]
    gl.check_error("frames")
    r.release()
    geo.release()
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    trace = "--tracemalloc" in args
    warmup, window, windows = (int(a) for a in args if a != "--tracemalloc")
    sys.stdout.write(json.dumps(measure(warmup, window, windows, trace)) + "\n")
