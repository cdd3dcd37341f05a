"""One frame budget (issue 23): the cost models on real layers, and the scheduler against
independent per-layer feedback.

``calibrate``: each layer's knob swept along one path on the real techniques (the
adaptive terrain's ε on ``--terrain``, the LODManager crowd's LOD exponent), one frame
per (knob, viewpoint): the fit ``ms = a + b · work`` (work: the layer's own counter,
triangles) and its R², and ``work ~ knob ** alpha`` (alpha and its R² in log-log): the
forms :mod:`lodsprite.scene.costs` assumes.

``compare``: the layered scene technique (``scene``) along ``--path`` under
``--target-fps`` with ``schedule = scheduler`` and ``independent``: target_ms, median,
p99, std of frame ms, and the knob changes per layer (oscillation).

    python benchmarks/scene_budget.py calibrate [--terrain fractal:1024] [--size 128]
                                                [--frames 40] [--objects 300]
    python benchmarks/scene_budget.py compare --scene SCENE.toml [--target-fps 30]
                                              [--frames 300] [--size 128]

Times are wall-clock on whatever shares the machine: noisy unless it is idle.
"""

from __future__ import annotations

import argparse

import numpy as np

TERRAIN_SSE = (16.0, 8.0, 4.0, 2.0, 1.0)
CROWD_EXPONENTS = (4.0, 2.0, 1.0, 0.5, 0.25)


def fit(knob: np.ndarray, work: np.ndarray, ms: np.ndarray, view: np.ndarray
        ) -> dict[str, float]:
    """``ms = a + b · work`` and, within each viewpoint ``view`` (the work model is
    relative to the current frame's), ``log work = c_view + alpha · log knob``; R² of
    each."""
    b, a = np.polyfit(work, ms, 1)
    r2 = 1 - np.var(ms - (a + b * work)) / max(np.var(ms), 1e-12)
    lk, lw = np.log(knob), np.log(np.maximum(work, 1.0))
    for g in np.unique(view):
        lk[view == g] -= lk[view == g].mean()
        lw[view == g] -= lw[view == g].mean()
    alpha, c = np.polyfit(lk, lw, 1)
    r2_alpha = 1 - np.var(lw - (c + alpha * lk)) / max(np.var(lw), 1e-12)
    return {"a_ms": float(a), "b_ms_per_unit": float(b), "r2": float(r2),
            "alpha": float(alpha), "r2_alpha": float(r2_alpha)}


def sweep(values, viewpoints, frame) -> tuple[np.ndarray, ...]:
    """``frame(value, viewpoint) -> (work, ms)`` over every value at every viewpoint
    (values interleaved per viewpoint, so that each sees the same views): knob, work, ms,
    viewpoint index, ``(n,)`` each."""
    rows = [(v, *frame(v, vp), i) for i, vp in enumerate(viewpoints) for v in values]
    return tuple(np.array(c, dtype=np.float64) for c in zip(*rows, strict=True))


def calibrate_terrain(terrain: str, size: int, frames: int) -> dict[str, float]:
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.scene import load_scene
    from lodsprite.terrain.quadtree import ranges

    scene = load_scene(terrain)
    with Renderer(scene, (size, size)) as r:
        t = techniques.create("adaptive", r, sse=1.0)
        a = t.terrain

        def frame(sse, vp):
            if a.sse != sse:
                a.sse = float(sse)
                a.r = ranges(a.tree.errors, sse, a.target.size[1], a.fov,
                             a.tree.node_diagonals())
            f = a.frame(vp)
            return f.triangles, f.ms

        vps = scene.path("flyover", frames).viewpoints
        for vp in vps[:3]:                                  # streaming settles, untimed
            for s in TERRAIN_SSE:
                frame(s, vp)
        out = fit(*sweep(TERRAIN_SSE, vps, frame))
        t.release()
    return out


def calibrate_crowd(objects: int, size: int, frames: int) -> dict[str, float]:
    from lodsprite.api import Renderer
    from lodsprite.manager.scene import walkthrough
    from lodsprite.manager.technique import create, open_scene

    scene = open_scene(f"crowd:{objects}")
    with Renderer(scene, (size, size), fov_y_deg=60.0) as r:
        t = create(r, "manager")
        e = t.engine

        def frame(p, vp):
            e.feedback.exponent = float(p)
            for _ in range(2):          # the manager's extractions for the new exponent
                e.frame(vp)
            f = e.frame(vp)
            return f.triangles, f.ms - f.lod_ms

        vps = walkthrough(scene.objects, frames).viewpoints
        out = fit(*sweep(CROWD_EXPONENTS, vps, frame))
        t.release()
    return out


def compare(scene_file: str, target_fps: float, frames: int, size: int, path: str) -> None:
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.harness import run_path
    from lodsprite.scene.budget import steadiness
    from lodsprite.scene.world import load_world

    world = load_world(scene_file)
    cam = world.scene.path(path or world.path, frames)
    print(f"{'schedule':<12} {'target':>7} {'median':>7} {'p99':>7} {'std':>6}  knob changes")
    for schedule in ("scheduler", "independent"):
        with Renderer(world.scene, (size, size)) as r:
            t = techniques.create("scene", r, world=world, schedule=schedule,
                                  target_fps=target_fps)
            res = run_path(t, cam)
            ms = np.array([f.ms for f in res.frames])
            changes = {k[5:]: steadiness(np.array([f.extra[k] for f in res.frames]), ms)
                       ["changes"] for k in res.frames[0].extra if k.startswith("knob_")}
            print(f"{schedule:<12} {1e3 / target_fps:7.2f} {np.median(ms):7.2f} "
                  f"{np.percentile(ms, 99):7.2f} {ms.std():6.2f}  {changes}")
            t.release()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=("calibrate", "compare"))
    ap.add_argument("--terrain", default="fractal:1024")
    ap.add_argument("--objects", type=int, default=300)
    ap.add_argument("--scene", default="")
    ap.add_argument("--path", default="")
    ap.add_argument("--target-fps", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--size", type=int, default=128)
    a = ap.parse_args()
    if a.part == "compare":
        if not a.scene:
            ap.error("compare needs --scene SCENE.toml")
        compare(a.scene, a.target_fps, a.frames, a.size, a.path)
        return
    for name, res in (("terrain (adaptive, ε px)", calibrate_terrain(a.terrain, a.size,
                                                                      a.frames)),
                      ("objects (LODManager, exponent)", calibrate_crowd(a.objects, a.size,
                                                                         a.frames))):
        print(f"{name:<32} ms = {res['a_ms']:.3f} + {res['b_ms_per_unit'] * 1e3:.4f}e-3 · "
              f"triangles (R² {res['r2']:.2f}); triangles ~ knob^{res['alpha']:.2f} "
              f"(R² {res['r2_alpha']:.2f})")


if __name__ == "__main__":
    main()
