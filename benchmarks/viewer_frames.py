"""In-window frame times of LOD-sprite against the offscreen spriteframe time (issue 13).

For each terrain, in one run:

* offscreen: ``lodsprite render --mode sprite`` along chen1999 (inline keyframes, EGL
  context): the median spriteframe time, the reference; and the same spriteframes one per
  frame period, as the window paces them (the like-for-like reference on a CPU
  rasteriser, where an idle gap slows the next frame);
* in a window (``lodsprite view --play chen1999 --mode sprite --exit``), keyframes from the
  worker process (default) and inline (``--inline-keyframes``): median and p99 frame time
  (from the start of a frame to its buffer swap), the technique's own time, keyframes and
  the error of the frames shown;
* offscreen, keyframes from the worker process, paced as the window: the worker's start
  (the process and the first keyframe), the median and p99 frame time, and the process's
  median time per keyframe (the first, start-up one, left out).

Prints p99 / median and median / offscreen spriteframe for each.  Needs a display: with
none, it starts a virtual one (Xvfb, through xvfbwrapper).

    python benchmarks/viewer_frames.py [--terrains jacksboro fractal:4096] [--frames 460]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
from contextlib import nullcontext
from pathlib import Path

import numpy as np

CLI = [sys.executable, "-c", "from lodsprite.cli import main; main()"]


def run(args: list[str]) -> None:
    proc = subprocess.run(CLI + args, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"lodsprite {' '.join(args)} failed:\n{proc.stderr}")


def offscreen_sprite_ms(terrain: str, frames: int, size: str, tmp: Path) -> float:
    """Median spriteframe time of ``lodsprite render --mode sprite`` (frames back to back)."""
    out = tmp / f"off-{terrain.replace(':', '_')}"
    run(["render", "--terrain", terrain, "--mode", "sprite", "--frames", str(frames),
         "--size", size, "--out", str(out)])
    with open(out / "frames.csv") as f:
        ms = [float(r["ms"]) for r in csv.DictReader(f) if r["kind"] == "sprite"]
    return float(np.median(ms))


def offscreen_paced_sprite_ms(terrain: str, frames: int, size: str, fps: float) -> float:
    """The same spriteframes offscreen, one per frame period (``fps``) as in the window:
    on a CPU rasteriser an idle gap between frames makes the next one slower (threads
    and cores wake up), so this is the like-for-like reference of a paced window."""
    import time

    import lodsprite

    w, h = (int(v) for v in size.split("x"))
    scene = lodsprite.load_scene(terrain)
    path = lodsprite.get_path("chen1999", scene.hf, frames)
    ms = []
    with lodsprite.Renderer(scene, (w, h)) as renderer:
        sprite = renderer.sprite()
        sprite.frame(path.viewpoints[0])
        for vp in path.viewpoints:
            start = time.perf_counter()
            f = sprite.frame(vp)
            if f.type == "sprite":
                ms.append(f.ms)
            rest = 1.0 / fps - (time.perf_counter() - start) if fps > 0 else 0.0
            if rest > 0:
                time.sleep(rest)
    return float(np.median(ms))


def offscreen_worker(terrain: str, frames: int, size: str, fps: float) -> dict:
    """The worker-process engine along chen1999 offscreen, one frame per period."""
    import time

    import lodsprite

    w, h = (int(v) for v in size.split("x"))
    scene = lodsprite.load_scene(terrain)
    path = lodsprite.get_path("chen1999", scene.hf, frames)
    with lodsprite.Renderer(scene, (w, h)) as renderer:
        t0 = time.perf_counter()
        sprite = renderer.sprite(threaded=True)
        try:
            sprite.frame(path.viewpoints[0])
            start_s = time.perf_counter() - t0
            ms = []
            for vp in path.viewpoints:
                begin = time.perf_counter()
                ms.append(sprite.frame(vp).ms)
                rest = 1.0 / fps - (time.perf_counter() - begin) if fps > 0 else 0.0
                if rest > 0:
                    time.sleep(rest)
            key_ms = sprite.engine.worker.render_ms[1:]
        finally:
            sprite.release()
    return {"start_s": start_s, "median_ms": float(np.median(ms)),
            "p99_ms": float(np.percentile(ms, 99)), "keyframes": len(key_ms),
            "key_ms": float(np.median(key_ms)) if key_ms else float("nan")}


def window_run(terrain: str, frames: int, size: str, fps: float, inline: bool,
               tmp: Path) -> dict:
    out = tmp / f"win-{terrain.replace(':', '_')}-{'inline' if inline else 'worker'}"
    run(["view", terrain, "--play", "chen1999", "--frames", str(frames), "--mode", "sprite",
         "--size", size, "--fps", str(fps), "--exit", "--out", str(out)]
        + (["--inline-keyframes"] if inline else []))
    s = json.loads((out / "summary.json").read_text())
    with open(out / "frames.csv") as f:
        err = np.array([float(r["error_px"]) for r in csv.DictReader(f)])
    s["error_mean"] = float(np.mean(err))
    s["error_max"] = float(np.max(err))
    s["over_eps"] = float(np.mean(err >= 1.0))
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrains", nargs="+", default=["jacksboro", "fractal:4096"])
    ap.add_argument("--frames", type=int, default=460)
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--fps", type=float, default=60.0)
    a = ap.parse_args()
    display = nullcontext()
    if not os.environ.get("DISPLAY"):
        from xvfbwrapper import Xvfb

        display = Xvfb(width=1280, height=1024, colordepth=24)
    print(f"chen1999, {a.frames} frames, {a.size}, window frame cap {a.fps:g} fps")
    print("| terrain | keyframes | median ms | p99 ms | p99/median | technique median ms | "
          "offscreen sprite ms | median/offscreen | offscreen paced ms | median/paced | "
          "keyframes taken | error mean / max px | frames >= ε |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with display, tempfile.TemporaryDirectory() as tmp:
        for terrain in a.terrains:
            ref = offscreen_sprite_ms(terrain, a.frames, a.size, Path(tmp))
            paced = offscreen_paced_sprite_ms(terrain, a.frames, a.size, a.fps)
            for inline in (False, True):
                s = window_run(terrain, a.frames, a.size, a.fps, inline, Path(tmp))
                # the window's whole frame (start to after the swap) against the
                # technique's own (ms: frame() and ctx.finish(), as offscreen)
                w, p99 = s["window_median_ms"], s["window_p99_ms"]
                print(f"| {terrain} | {'inline' if inline else 'worker process'} | "
                      f"{w:.2f} | {p99:.2f} | {p99 / w:.2f} | {s['median_ms']:.2f} | "
                      f"{ref:.2f} | {w / ref:.2f} | {paced:.2f} | "
                      f"{w / paced:.2f} | {s['keyframes']} | "
                      f"{s['error_mean']:.2f} / {s['error_max']:.2f} | "
                      f"{100 * s['over_eps']:.0f} % |", flush=True)
        print("\n| terrain | worker start s | median ms | p99 ms | keyframes after the first "
              "| worker ms per keyframe (median) |\n|---|---|---|---|---|---|")
        for terrain in a.terrains:
            o = offscreen_worker(terrain, a.frames, a.size, a.fps)
            print(f"| {terrain} | {o['start_s']:.2f} | {o['median_ms']:.2f} | "
                  f"{o['p99_ms']:.2f} | {o['keyframes']} | {o['key_ms']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
