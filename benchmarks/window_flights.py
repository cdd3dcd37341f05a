"""Flights through a large terrain store in the window (issue 21, must-have 4).

For each mode and path, ``lodsprite view STORE --mode MODE --play PATH --frames N --exit
--out DIR`` in a real window (a virtual X screen through xvfbwrapper when there is no
display): the median and p99 frame time from the view's own summary.json, the tiles it
loaded, and the peak resident memory of the view's whole process tree (the window and
its tile reader process), sampled from ``/proc`` every 50 ms while it runs.

    python benchmarks/window_flights.py STORE.zarr [--modes adaptive sprite-adaptive] \
        [--paths chen1999 flyover] [--frames 460] [--size 512x512]

Make a 16k² store first: ``lodsprite tile fractal:16384 --out fractal_16384.zarr``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

CLI = [sys.executable, "-c", "from lodsprite.cli import main; main()"]


def tree_rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and all its descendants, in MB (0 if gone)."""
    children: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            status = (entry / "status").read_text()
        except OSError:
            continue
        fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
        p = int(entry.name)
        children.setdefault(int(fields.get("PPid", "0").strip()), []).append(p)
        rss[p] = int(fields.get("VmRSS", "0 kB").split()[0])
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        todo += children.get(p, [])
    return total / 1024.0


def fly(store: str, mode: str, path: str, frames: int, size: str, out: Path) -> dict:
    """One flight; its summary plus ``peak_tree_rss_mb`` and ``wall_s``."""
    args = ["view", store, "--mode", mode, "--play", path, "--frames", str(frames),
            "--size", size, "--exit", "--out", str(out)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(CLI + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    peak = 0.0
    while proc.poll() is None:
        peak = max(peak, tree_rss_mb(proc.pid))
        time.sleep(0.05)
    _, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"lodsprite {' '.join(args)} failed:\n{err}")
    summary = json.loads((out / "summary.json").read_text())
    return {**summary, "peak_tree_rss_mb": peak, "wall_s": time.perf_counter() - t0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("--modes", nargs="+", default=["adaptive", "sprite-adaptive"])
    parser.add_argument("--paths", nargs="+", default=["chen1999", "flyover"])
    parser.add_argument("--frames", type=int, default=460)
    parser.add_argument("--size", default="512x512")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    display = nullcontext()
    if not os.environ.get("DISPLAY"):
        from xvfbwrapper import Xvfb

        display = Xvfb(width=1280, height=1024, colordepth=24)
    results = []
    with display, tempfile.TemporaryDirectory() as tmp:
        for path in args.paths:
            for mode in args.modes:
                s = fly(args.store, mode, path, args.frames, args.size,
                        Path(tmp) / f"{mode}-{path}")
                results.append({"mode": mode, "path": path, **s})
                print(f"{mode:9s} {path:9s} frames {s['frames']}  median {s['median_ms']:.1f} ms"
                      f"  p99 {s['p99_ms']:.1f} ms  peak RSS {s['peak_tree_rss_mb']:.0f} MB"
                      f"  wall {s['wall_s']:.0f} s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
