"""Benchmark: work beside a busy draw loop (issue 21, must-have 7).

moderngl holds the GIL through each draw call, so a Python thread beside the draws
starves.  This measures the lumigraph node loader and the terrain store's tile reader
beside full-resolution draws on the calling thread: nodes fetched and decoded per second
(JPEG, N_UV² node images) and 65² tiles read per second from a Zarr store, with the draws
and without them (``--alone``).

    python benchmarks/beside_draws.py [--nodes 16] [--uv 256] [--seconds 8] [--alone]
                                      [--tiles fractal:2048]
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
                renderer.terrain_gl.ctx.finish()
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


def tile_loads(store_dir: Path, seconds: float, draws: bool) -> dict:
    """Level-0 tiles read per second by the store's tile loader, the calling thread
    drawing as in :func:`node_loads` and pumping the loader once a frame."""
    from lodsprite import Renderer, get_path, load_scene
    from lodsprite.terrain.quadtree import Node, Quadtree
    from lodsprite.terrain.store import TerrainStore
    from lodsprite.terrain.streaming import tile_loader

    renderer = Renderer(load_scene("fractal:512"), (512, 512))
    path = get_path("chen1999", renderer.scene.hf, 100)
    tree = Quadtree(TerrainStore(store_dir), grid=64)
    nodes = [Node(0, i, j) for i in range(64) for j in range(64) if tree.exists(Node(0, i, j))]
    loader = tile_loader(tree, host_mb=2048)
    pump = getattr(loader, "pump", lambda: None)
    frames = 0
    try:
        renderer.render(path.viewpoints[0])
        loader.want([(1.0, nodes[0])])
        while loader.loaded < 1:
            pump()
            time.sleep(0.001)
        t0 = time.perf_counter()
        loader.want([(float(-m), n) for m, n in enumerate(nodes[1:])])
        while loader.loaded + len(loader.bad) < len(nodes) and time.perf_counter() - t0 < seconds:
            pump()
            if draws:
                renderer.render(path.viewpoints[frames % len(path.viewpoints)])
                renderer.terrain_gl.ctx.finish()
            else:
                time.sleep(0.005)
            frames += 1
        dt = time.perf_counter() - t0
        return {"draws": draws, "tiles": len(nodes) - 1, "loaded": loader.loaded - 1,
                "seconds": round(dt, 2), "tiles_per_s": round((loader.loaded - 1) / dt, 1),
                "frames": frames, "frame_ms": round(dt * 1e3 / max(1, frames), 2)}
    finally:
        loader.close()
        renderer.release()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=16, help="nodes per side of the slab")
    ap.add_argument("--uv", type=int, default=256, help="node image size (pixels)")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--alone", action="store_true", help="also without the draws")
    ap.add_argument("--tiles", metavar="SPEC", help="also tiles of a store built from SPEC")
    args = ap.parse_args()
    runs = [True, False] if args.alone else [True]
    with tempfile.TemporaryDirectory() as tmp:
        lf = make_lumigraph(Path(tmp), args.nodes, args.uv)
        for draws in runs:
            print(json.dumps({"loader": "lumigraph", **node_loads(lf, args.seconds, draws)}))
        if args.tiles:
            from lodsprite.terrain.store import build_store

            build_store(args.tiles, Path(tmp) / "t.zarr", tile=128, chunk=64)
            for draws in runs:
                print(json.dumps({"loader": "tiles",
                                  **tile_loads(Path(tmp) / "t.zarr", args.seconds, draws)}))


if __name__ == "__main__":
    main()
