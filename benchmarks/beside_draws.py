"""Benchmark: work beside a busy draw loop (issue 21, must-have 7).

moderngl holds the GIL through each draw call, so a Python thread beside the draws
starves.  This measures the lumigraph node loader beside full-resolution draws on the
calling thread: nodes fetched and decoded per second (JPEG, N_UV² node images), with the
draws and without them (``--alone``).

    python benchmarks/beside_draws.py [--nodes 16] [--uv 256] [--seconds 8] [--alone]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def make_lumigraph(root: Path, n_st: int, n_uv: int) -> Path:
    from lodsprite.lumigraph.capture import textured_plane
    from lodsprite.lumigraph.geometry import Slab
    from lodsprite.lumigraph.store import save

    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (n_uv, n_uv, 3), dtype=np.uint8)
    images = {(i, j): np.roll(base, 7 * i + j, axis=1) for i in range(n_st) for j in range(n_st)}
    slab = Slab(np.eye(4), st_size=3.0, uv_size=2.0, st_distance=2.5, n_st=n_st, n_uv=n_uv)
    return save(root / "lf", [slab], [images], textured_plane(2.0, 4), "x", 0.1, 10.0,
                codec="jpeg")


def node_loads(lf_dir: Path, seconds: float, draws: bool) -> dict:
    """Nodes decoded per second by the node loader while the calling thread draws
    full-resolution frames of a 512² terrain at 512² pixels (or sleeps 5 ms a frame,
    without ``draws``)."""
    from lodsprite import Renderer, get_path, load_scene
    from lodsprite.lumigraph.loader import NodeLoader
    from lodsprite.lumigraph.store import Lumigraph

    renderer = Renderer(load_scene("fractal:512"), (512, 512))
    path = get_path("chen1999", renderer.scene.hf, 100)
    loader = NodeLoader(Lumigraph(lf_dir))
    n = loader.n_st ** 2
    pump = getattr(loader, "pump", lambda: None)
    frames = 0
    try:
        renderer.render(path.viewpoints[0])
        loader.want(np.arange(1))  # started (a process's start-up is not counted)
        while loader.decoded < 1:
            pump()
            time.sleep(0.001)
        loader.drain_costs()
        t0 = time.perf_counter()
        loader.want(np.arange(n))
        while loader.decoded < n and time.perf_counter() - t0 < seconds:
            pump()
            if draws:
                renderer.render(path.viewpoints[frames % len(path.viewpoints)])
                renderer.paths.ctx.finish()
            else:
                time.sleep(0.005)
            frames += 1
        pump()
        dt = time.perf_counter() - t0
        costs = np.array([c[1:] for c in loader.drain_costs()]).reshape(-1, 2)
        return {"fetch_ms": round(float(costs[:, 0].mean()), 2),
                "decode_ms": round(float(costs[:, 1].mean()), 2),
                "draws": draws, "nodes": n, "decoded": loader.decoded, "seconds": round(dt, 2),
                "loads_per_s": round(loader.decoded / dt, 1), "frames": frames,
                "frame_ms": round(dt * 1e3 / max(1, frames), 2)}
    finally:
        loader.close()
        renderer.release()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=16, help="nodes per side of the slab")
    ap.add_argument("--uv", type=int, default=256, help="node image size (pixels)")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--alone", action="store_true", help="also without the draws")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lf = make_lumigraph(Path(tmp), args.nodes, args.uv)
        runs = [True, False] if args.alone else [True]
        for draws in runs:
            print(json.dumps(node_loads(lf, args.seconds, draws)))


if __name__ == "__main__":
    main()
