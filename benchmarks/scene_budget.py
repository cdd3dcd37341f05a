"""One frame budget (issue 23): the cost models on real layers, and the scheduler against
independent per-layer feedback.

``calibrate``: each layer's knob swept along one path on the real techniques (the
adaptive terrain's ε on ``--terrain``, the LODManager crowd's LOD exponent), one frame
per (knob, viewpoint): the fit ``ms = a + b · work`` (work: the layer's own counter,
triangles) and its R², and ``work ~ knob ** alpha`` (alpha and its R² in log-log): the
forms :mod:`lodsprite.scene.costs` assumes.

``two-layers``: two real layers under one budget without the layered technique (the
adaptive terrain's ε and the LODManager crowd's exponent, drawn one after the other),
scheduler against independent feedback: median, p99, std, knob changes, shares.

``compare``: the layered scene technique (``scene``) on ``--scene`` (default: a small
one, 600 walking ogres on fractal:512) along ``--path`` under
``--target-fps`` with ``schedule = scheduler`` and ``independent``: target_ms, median,
p99, std of frame ms, the frames with every knob at its cheapest setting seen (``floor``:
the budget cannot bind lower), each layer's median ms and knob changes (oscillation).

    python benchmarks/scene_budget.py calibrate [--terrain fractal:1024] [--size 128]
                                                [--frames 40] [--objects 300]
    python benchmarks/scene_budget.py two-layers [--frames 300] [--target-fps F]
    python benchmarks/scene_budget.py compare [--scene SCENE.toml] [--target-fps 30]
                                              [--frames 300] [--size 128]

Times are wall-clock on whatever shares the machine: noisy unless it is idle.
"""

from __future__ import annotations

import argparse
import time

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
    from lodsprite.manager.technique import create
    from lodsprite.scene import open_scene

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


TWO_SSE = (16.0, 11.3, 8.0, 5.7, 4.0, 2.8, 2.0, 1.4, 1.0)
TWO_EXPONENTS = (4.0, 2.8, 2.0, 1.4, 1.0, 0.7, 0.5, 0.35, 0.25)


def two_layers(terrain: str, objects: int, size: int, frames: int, target_fps: float | None
               ) -> None:
    """Two real layers under one budget without the layered technique: the adaptive
    terrain (knob ε) and the LODManager crowd (knob: its exponent, its own feedback off),
    drawn one after the other each frame on one context (no compositing: times only)."""
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.gl.target import RenderTarget
    from lodsprite.manager.engine import CrowdEngine
    from lodsprite.manager.run import CrowdConfig, make_crowd
    from lodsprite.manager.scene import walkthrough
    from lodsprite.scene import load_scene
    from lodsprite.scene.budget import LayerBudget, LayerControl
    from lodsprite.terrain.quadtree import ranges

    scene = load_scene(terrain)
    crowd = make_crowd(CrowdConfig(objects=objects))
    with Renderer(scene, (size, size)) as r:
        t = techniques.create("adaptive", r, sse=TWO_SSE[0])
        a = t.terrain
        target = RenderTarget(r.gl, size, size)
        e = CrowdEngine(r.gl, crowd, target, "manager", fov_y_deg=60.0)

        def set_sse(v):
            a.sse = float(v)
            a.r = ranges(a.tree.errors, v, a.target.size[1], a.fov, a.tree.node_diagonals())

        def set_p(v):
            e.feedback.exponent = float(v)

        sky = scene.path("flyover", frames).viewpoints
        walk = walkthrough(crowd, frames).viewpoints

        def fly(budget, n, stride=1):
            ms = []
            for i in range(0, n * stride, stride):
                controls = [LayerControl("terrain", TWO_SSE, a.sse, set_sse),
                            LayerControl("objects", TWO_EXPONENTS, e.feedback.exponent, set_p)]
                budget.before(controls)
                t0 = time.perf_counter()
                ft = a.frame(sky[i % len(sky)])
                fo = e.frame(walk[i % len(walk)])
                r.gl.finish()
                total = (time.perf_counter() - t0) * 1e3
                budget.after({"terrain": (controls[0].value, ft.ms, ft.triangles),
                              "objects": (controls[1].value, fo.ms, fo.triangles)}, total)
                ms.append(total)
            return np.array(ms)

        if target_fps is None:          # a target that binds: 0.6 x the finest settings'
            set_sse(TWO_SSE[-1])        # median over views spread along the path
            set_p(TWO_EXPONENTS[-1])
            fly(LayerBudget(), 3)
            target_fps = 1e3 / (0.6 * np.median(fly(LayerBudget(), 12, max(1, frames // 12))))
        print(f"two layers (fractal terrain ε + {objects}-ogre crowd p), {size}², "
              f"{frames} frames, target {1e3 / target_fps:.1f} ms")
        print(f"{'schedule':<12} {'median':>7} {'p99':>7} {'std':>6}  knob changes, shares")
        for schedule in ("scheduler", "independent"):
            set_sse(TWO_SSE[0])
            set_p(TWO_EXPONENTS[0])
            budget = LayerBudget(schedule, 1e3 / target_fps)
            ms = fly(budget, frames)
            s = budget.summary()
            print(f"{schedule:<12} {np.median(ms):7.2f} {np.percentile(ms, 99):7.2f} "
                  f"{ms.std():6.2f}  terrain {s['knob_changes_terrain']}, objects "
                  f"{s['knob_changes_objects']}; share {s['share_terrain']:.2f} / "
                  f"{s['share_objects']:.2f}")
        e.release()
        target.release()
        t.release()


SMALL_SCENE = """[terrain]
source = "fractal:512:3"
[[objects]]
mesh = "ogre"
count = 600
seed = 1
walk_mps = 1.5
area = [-300.0, -300.0, 300.0, 300.0]
[view]
path = "flyover:40:600"
"""


def compare(scene_file: str, target_fps: float, frames: int, size: int, path: str) -> None:
    import tempfile
    from pathlib import Path

    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.harness import run_path
    from lodsprite.scene.budget import steadiness
    from lodsprite.scene.world import load_scene_file

    if not scene_file:
        scene_file = str(Path(tempfile.mkdtemp()) / "small.toml")
        Path(scene_file).write_text(SMALL_SCENE)
    world = load_scene_file(scene_file)
    cam = world.path(path or world.default_path, frames)

    def fly(schedule, fps):
        with Renderer(world, (size, size)) as r:
            t = techniques.create("scene", r, world=world, schedule=schedule,
                                  target_fps=fps)
            try:
                return run_path(t, cam).frames
            finally:
                t.release()

    if target_fps is None:      # a target that binds: 0.7 x the default knobs' median
        target_fps = 1e3 / (0.7 * np.median([f.ms for f in fly("none", None)]))
    print(f"{scene_file}: {frames} frames at {size}², target {1e3 / target_fps:.1f} ms")
    print(f"{'schedule':<12} {'median':>7} {'p99':>7} {'std':>6} {'floor':>6}  "
          "median ms by layer; knob changes")
    for schedule in ("scheduler", "independent"):
        frames_run = fly(schedule, target_fps)
        ms = np.array([f.ms for f in frames_run])
        knobs = [k for k in frames_run[0].extra if k.startswith("knob_")]
        changes = {k[5:]: int(steadiness(np.array([f.extra[k] for f in frames_run]), ms)
                              ["changes"]) for k in knobs}
        per_layer = {k[5:]: round(float(np.median([f.extra["ms_" + k[5:]]
                                                   for f in frames_run])), 1) for k in knobs}
        lowest = {k: min(f.extra[k] for f in frames_run) for k in knobs}
        floor = np.mean([all(f.extra[k] == lowest[k] for k in knobs) for f in frames_run])
        print(f"{schedule:<12} {np.median(ms):7.2f} {np.percentile(ms, 99):7.2f} "
              f"{ms.std():6.2f} {floor:6.0%}  {per_layer}; {changes}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", choices=("calibrate", "two-layers", "compare"))
    ap.add_argument("--terrain", default="fractal:1024")
    ap.add_argument("--objects", type=int, default=300)
    ap.add_argument("--scene", default="")
    ap.add_argument("--path", default="")
    ap.add_argument("--target-fps", type=float, default=None,
                    help="default: one that binds (0.6-0.7 x the unbudgeted median)")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--size", type=int, default=128)
    a = ap.parse_args()
    if a.part == "compare":
        compare(a.scene, a.target_fps, a.frames, a.size, a.path)
        return
    if a.part == "two-layers":
        two_layers(a.terrain, a.objects, a.size, a.frames, a.target_fps)
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
