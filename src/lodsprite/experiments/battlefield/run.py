"""``lodsprite reproduce battlefield``: a whole scene under one frame budget (issue 23,
must-have 5): the battlefield of Chen, Swan & Kaufman 1999 (terrain with entities on it)
with the layers of :class:`~lodsprite.layered.technique.LayeredTechnique` and the
budget of Funkhouser & Séquin 1993 (:mod:`lodsprite.scene.budget`).

The scene (:mod:`.scene`): a 4k² fractal store (or ``--terrain``), ``instances`` walking
ogres and ``trees`` trees (LODManager engine, Gumbau et al.), two light fields
(lumigraphs, Sloan et al. 1997) captured of built-in objects; along each path of
``paths`` (``flyover:300:3000``: 300 m up along 3 km over the crowd; ``weave``: 8 m up,
weaving among the crowd,
:mod:`lodsprite.paths.weave`), ``frames`` frames each, on one renderer:

* ``scheduler`` and ``independent``: the budget's predictive scheduler against today's
  independent per-layer feedback, both at ``target_fps``, timed, every
  ``sample_every``-th frame replayed untimed against the full-detail scene (every layer
  at full detail: :func:`~lodsprite.layered.technique.reference`, rendered once per
  path) for RMSE (grey levels) and FLIP;
* ``reuse`` (issue 32): the scheduler at ``reuse_fps`` with the static layers reused
  (``keyframes="worker"``: the terrain, by the adaptive renderer at the keyframe
  tolerance, and the trees in LOD-sprite keyframes from the scene's keyframe worker
  process, which shares the machine's cores with the display;
  :mod:`lodsprite.layered.reuse`), quality as the two above;
* ``manager`` and ``no_manager``, on the first ``extraction_frames`` frames (every object
  extracting its own LODs is slow: about 0.8 s a frame here): the LOD exponent fixed at
  ``exponent``, the crowd
  engine's LODManager sharing LODs against every object extracting its own (the same
  engine with ``share`` off): extractions counted by the engine;
* ``profile`` and ``linear``: every object type's ``lod`` set to ``profile`` (Scoggins
  et al. 2000 error profiles, which the objects layer hooks on the crowd engine) then
  ``linear`` (distance-linear),
  on the sampled frames only (each at its own time along the path, the terrain at full
  resolution as the reference's, and every object's LOD updated each frame: the
  LODManager's active list of 300 would leave most of 3100 objects at the LOD of a frame
  30 before), the linear run's
  exponent searched (``match_steps`` runs at most, a secant on log triangles) so that its
  triangles match the profile run's: RMSE and FLIP at equal triangles.  The linear run
  kept is chosen on one half of the sampled frames (its triangles on them against the
  profile run's) and both are reported on the other half
  (:func:`~lodsprite.experiments.base.split_sampled`): the noise that chose a run is not
  the figure reported.

Every run is warmed up untimed by the harness at its first viewpoint (every layer's
shaders compiled, the adaptive terrain's first view streamed in); that warm-up is each
run's ``first_frame_ms`` and is in none of its other figures.  Quality is taken on every
``sample_every``-th frame (20 a path in the default config), ``rmse`` and ``flip`` on the
reported half of them, ``rmse_chosen`` and ``flip_chosen`` on the chosen half.

The scheduler's and the independent feedback's figures pool the frames of every path
(``frames × len(paths)`` frames); per path detail is in ``paths``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lodsprite.experiments.base import SplitSampled

Update = Callable[[str, int, int], None]
#: What the linear run is matched on: its objects' triangles on the chosen frames.
MATCH_KEY = "triangles_objects_chosen"


@dataclass(frozen=True)
class BattlefieldConfig(SplitSampled):
    """The default run: a 4k² store, 3000 walking ogres, 100 trees, two light fields of
    6 slabs of 8² nodes of 64² pixels, 300 frames along each of two paths at 256², a 5 fps
    target (reuse: 15 fps); 680 s here with the reuse runs (the idle 2-core machine,
    2026-12-03; 20 sampled frames a path; docs/commands/reproduce.md).  :meth:`quick` is
    the tests'."""

    terrain: str = "fractal:4096:1"
    instances: int = 3000
    trees: int = 100
    lightfields: int = 2
    area_m: float = 400.0       # the crowd walks in [-area, area]², the trees stand in 1.5×
    ogre_m: float = 2.2
    tree_m: float = 12.0
    lightfield_m: float = 25.0
    walk_mps: float = 1.5
    ogre_lod: str = "linear"
    tree_lod: str = "profile"
    lf_st: int = 8
    lf_uv: int = 64
    lf_slabs: int = 6
    paths: tuple[str, ...] = ("flyover:300:3000", "weave:8:400:3")  # weave: over the crowd
    frames: int = 300
    image: int = 256
    target_fps: float = 5.0     # binds: a 100-frame run's fixed-exponent frames took 221-319 ms
    extraction_frames: int = 50   # the manager / no_manager runs: the first frames of a path
    sample_every: int = 15      # 20 sampled frames a path: 10 to choose on, 10 to report
    terrain_mode: str = "adaptive"
    terrain_grid: int = 32      # the adaptive renderer's nodes: 32² quads (docs/scenes.md)
    lod_floor: float = 0.02     # the coarsest LOD of ogres and trees: 2 % of their triangles
    exponent: float = 1.0       # the fixed-exponent runs' LOD exponent
    match_steps: int = 4        # linear runs at most, matching the profile run's triangles
    reuse_mode: str = "sprite-adaptive"  # reuse: keyframes by the adaptive renderer, worker
    reuse_fps: float = 15.0     # reuse: its own target, 3x the scheduler's (issue 32)
    reuse_proxy: str = "geometry"  # reuse: what spriteframes draw the keyframes on

    @classmethod
    def quick(cls, **kw) -> BattlefieldConfig:
        return cls(**{**dict(terrain="fractal:256:1", instances=120, trees=3, area_m=120.0,
                             paths=("flyover:300:3000", "weave:8:120:3"), lf_st=4,
                             extraction_frames=12,
                             lf_uv=32, lf_slabs=6, frames=12, image=64, target_fps=30.0,
                             reuse_fps=90.0,
                             sample_every=3, match_steps=2), **kw})

    @property
    def sample_frames(self) -> list[int]:
        return list(range(0, self.frames, self.sample_every))


def _stats(ms: np.ndarray) -> dict:
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)),
            "std_ms": float(ms.std()), "mean_ms": float(ms.mean()), "frames": int(ms.size)}


def _mean(rows: list[dict], key: str) -> float | None:
    return float(np.mean([r[key] for r in rows])) if rows and key in rows[0] else None


def _halves(q: list[dict], chosen: set[int], flick: list[dict] = ()) -> dict:
    """Quality of the replayed rows ``q`` on the reported frames (``rmse``, ``flip``,
    ``triangles_objects_reported``) and on the frames ``chosen`` (their ``frame``
    indices: ``rmse_chosen``, ``flip_chosen``, ``triangles_objects_chosen``); ``flicker``
    and ``flicker_chosen`` from the rows ``flick`` (the frame after a sampled one, in the
    half of the sampled frame before it)."""
    out: dict = {}
    for half, rows in (("", [r for r in q if r["frame"] not in chosen]),
                       ("_chosen", [r for r in q if r["frame"] in chosen])):
        out[f"rmse{half}"], out[f"flip{half}"] = _mean(rows, "rmse"), _mean(rows, "flip")
        out[f"flicker{half}"] = _mean(
            [r for r in flick if (r["frame"] - 1 in chosen) == (half == "_chosen")],
            "flicker")
        out[f"triangles_objects{half or '_reported'}"] = (
            float(np.mean([r.get("triangles_objects", 0) for r in rows])) if rows else None)
    out["quality_frames_reported"] = len(q) - sum(r["frame"] in chosen for r in q)
    return out


def _row(result, target_ms: float | None, chosen: set[int]) -> dict:
    """One run's figures: timing (its warm-up apart: ``first_frame_ms``), quality on the
    reported and the ``chosen`` frames (:func:`_halves`), triangles, extractions,
    per-layer columns."""
    rows = result.rows
    ms = np.array([r["ms"] for r in rows], np.float64)
    q = [r for r in rows if "rmse" in r]
    flick = [r for r in rows if "flicker" in r]
    cols = {k: [r.get(k) for r in rows] for k in rows[0]
            if k.startswith(("ms_", "knob_", "triangles_")) or k in ("triangles", "extractions")}
    cols.update({k: [r.get(k) for r in rows] for k in ("rmse", "flip") if q})
    s = result.summary
    return {"target_ms": target_ms, **_stats(ms), "first_frame_ms": s["first_frame_ms"],
            **_halves(q, chosen, flick), "quality_frames": len(q),
            "triangles_mean": float(np.mean([r["triangles"] for r in rows])),
            "triangles_objects_mean": float(np.mean([r.get("triangles_objects", 0)
                                                     for r in rows])),
            "extractions": int(sum(r.get("extractions", 0) for r in rows)),
            **{k: v for k, v in s.items() if k.startswith(("share_", "mean_ms_", "keyframe"))},
            "columns": {"ms": ms.tolist(), **cols}}


class PathRuns:
    """Every run of one path on one renderer, against the full-detail images of the
    sampled frames (rendered once, then the reference is released)."""

    def __init__(self, renderer, world, cam, cfg: BattlefieldConfig) -> None:
        from lodsprite.layered.technique import reference

        self.renderer, self.world, self.cam, self.cfg = renderer, world, cam, cfg
        image, release = reference(renderer, world, cam)
        # the sampled frames and the frame after each (its flicker; the harness judges it
        # when the quality stride skips frames)
        frames = sorted({j for i in cfg.sample_frames for j in (i, i + 1)
                         if j < len(cam.viewpoints)})
        try:
            self.images = {id(cam.viewpoints[i]): image(cam.viewpoints[i]) for i in frames}
        finally:
            release()

    def run(self, *, schedule: str = "none", target_fps: float | None = None,
            exponent: float | None = None, share: bool = True, quality: bool = True,
            sampled: bool = False, first: int | None = None, keyframes: str = "inline",
            terrain_mode: str | None = None, **terrain_options) -> dict:
        """One run of the ``scene`` technique (see the module doc); ``sampled``: the
        sampled frames only, each at its own time; ``first``: the first frames only;
        ``terrain_options``: the terrain layer's (reuse: ``proxy``, ``pair``)."""
        from lodsprite.harness import run_path
        from lodsprite.layered.technique import ACTIVE, FRAME_S, LayeredTechnique
        from lodsprite.paths import CameraPath

        cfg, cam = self.cfg, self.cam
        frame_s, stride = FRAME_S, cfg.sample_every
        chosen = set(cfg.chosen_frames)
        if sampled:
            cam = CameraPath(cam.name, tuple(cam.viewpoints[i] for i in cfg.sample_frames),
                             cam.fov_y_deg)
            frame_s, stride = FRAME_S * cfg.sample_every, 1
            chosen = {k for k, i in enumerate(cfg.sample_frames) if i in chosen}
        elif first is not None:
            cam = CameraPath(cam.name, cam.viewpoints[:first], cam.fov_y_deg)
        # the sampled frames (profile against linear LOD) draw the terrain at full
        # resolution, as the reference does: 30 frames apart, the adaptive renderer would
        # show tiles still streaming in (a low eye under a coarse tile's surface), and
        # the comparison is of the objects' LODs
        t = LayeredTechnique(self.renderer, self.world,
                             terrain_mode="full" if sampled else (terrain_mode
                                                                  or cfg.terrain_mode),
                             keyframes=keyframes,
                             schedule=schedule, target_fps=target_fps,
                             exponent=cfg.exponent if exponent is None else exponent,
                             frame_s=frame_s, grid=cfg.terrain_grid,
                             # the sampled frames are 30 apart: every object's LOD is
                             # brought to its choice each frame, not 300 of them
                             active=None if sampled else ACTIVE, **terrain_options)
        hooked = False
        try:
            if t.objects is not None:  # the layer wires profile LOD for lod = "profile"
                hooked = t.objects.engine.desired_hook is not None
                if not share:
                    t.objects.engine.manager.share = False  # each object extracts its own
            result = run_path(t, cam, ground_truth=quality, quality_stride=stride, flip=True,
                              reference=lambda vp: self.images[id(vp)])
        finally:
            t.release()
        return {**_row(result, None if target_fps is None else 1e3 / target_fps, chosen),
                "profile_lod": hooked}

    def with_lod(self, kind: str, **kw) -> dict:
        """A run with every object type's ``lod`` set to ``kind``."""
        for t in self.world.objects.types:
            t.lod = kind
        return self.run(**kw)

    def profile_vs_linear(self) -> dict:
        """The profile run, then linear runs whose exponent is searched to match its
        triangles on the chosen frames; the closest linear run there is kept, with every
        exponent tried (its quality reported on the other frames)."""
        kept = [t.lod for t in self.world.objects.types]
        key = MATCH_KEY
        try:
            prof = self.with_lod("profile", sampled=True)
            goal = prof[key]  # the objects' (the terrain is the same)
            tried: list[tuple[float, dict]] = []
            e = self.cfg.exponent
            for _ in range(max(1, self.cfg.match_steps)):
                lin = self.with_lod("linear", sampled=True, exponent=e)
                tried.append((e, lin))
                if abs(lin[key] / max(goal, 1.0) - 1.0) < 0.02:
                    break
                e = _next_exponent(tried, goal)
        finally:
            for t, lod in zip(self.world.objects.types, kept, strict=True):
                t.lod = lod
        e, lin = min(tried, key=lambda x: abs(x[1][key] - goal))
        return {"profile": prof, "linear": lin, "linear_exponent": e,
                "exponents_tried": [x[0] for x in tried],
                "triangles_tried": [x[1][key] for x in tried]}


def _next_exponent(tried: list[tuple[float, dict]], goal: float) -> float:
    """The next LOD exponent to try (a larger exponent is coarser): a secant on
    ``log triangles`` against the exponent from the last two runs, else a doubling or
    halving; kept within 0.05..16."""
    e1, r1 = tried[-1]
    t1 = np.log(max(r1[MATCH_KEY], 1.0))
    g = np.log(max(goal, 1.0))
    if len(tried) >= 2:
        e0, r0 = tried[-2]
        t0 = np.log(max(r0[MATCH_KEY], 1.0))
        if abs(t1 - t0) > 1e-9:
            return float(np.clip(e1 + (g - t1) * (e1 - e0) / (t1 - t0), 0.05, 16.0))
    return float(np.clip(e1 * (2.0 if t1 > g else 0.5), 0.05, 16.0))


def pooled(per_path: dict, key: str) -> dict:
    """The runs ``key`` of every path as one: timing over all their frames, quality over
    all their reported frames."""
    runs = [p[key] for p in per_path.values()]
    ms = np.concatenate([r["columns"]["ms"] for r in runs])
    n = np.array([r["quality_frames_reported"] for r in runs], np.float64)

    def mean(k):
        vals = [r[k] for r in runs]
        return None if any(v is None for v in vals) else float(np.average(vals, weights=n))

    return {"target_ms": runs[0]["target_ms"], **_stats(ms), "rmse": mean("rmse"),
            "flip": mean("flip"), "flicker": mean("flicker"),
            "triangles_mean": float(np.mean([r["triangles_mean"] for r in runs]))}


def run_path_set(renderer, world, spec: str, cfg: BattlefieldConfig,
                 step: Callable[[str], None]) -> dict:
    """Every run along the path ``spec``."""
    cam = world.path(spec, cfg.frames)
    p = PathRuns(renderer, world, cam, cfg)
    out: dict = {"path": cam.name}
    for name, kw in (("scheduler", {"schedule": "scheduler", "target_fps": cfg.target_fps}),
                     ("reuse", {"schedule": "scheduler", "target_fps": cfg.reuse_fps,
                                "keyframes": "worker", "terrain_mode": cfg.reuse_mode,
                                "proxy": cfg.reuse_proxy}),
                     ("independent", {"schedule": "independent",
                                      "target_fps": cfg.target_fps}),
                     ("manager", {"quality": False, "first": cfg.extraction_frames}),
                     ("no_manager", {"quality": False, "share": False,
                                     "first": cfg.extraction_frames})):
        step(f"{spec}: {name}")
        out[name] = p.run(**kw)
    step(f"{spec}: profile vs linear")
    out["profile_vs_linear"] = p.profile_vs_linear()
    return out


def reproduce_battlefield(cfg: BattlefieldConfig, out_dir: Path,
                          update: Update | None = None) -> dict:
    """The scene, every path's runs, the pooled figures: results.json's dictionary."""
    from lodsprite.api import Renderer
    from lodsprite.experiments.battlefield.scene import write_scene
    from lodsprite.scene.world import load_scene_file

    out_dir = Path(out_dir)
    total = 1 + 6 * len(cfg.paths)
    done = [0]

    def step(name: str) -> None:
        if update:
            update(name, done[0], total)
        done[0] += 1

    step("scene: store, light fields")
    scene_file, made = write_scene(cfg, out_dir)
    world = load_scene_file(scene_file)
    per_path: dict = {}
    fov = world.path(cfg.paths[0], 2).fov_y_deg
    with Renderer(world, (cfg.image, cfg.image), fov) as renderer:
        gl = renderer.info.renderer
        for spec in cfg.paths:
            per_path[spec] = run_path_set(renderer, world, spec, cfg, step)
    if update:
        update("done", total, total)
    return results(cfg, per_path, made, world, scene_file, gl)


def results(cfg: BattlefieldConfig, per_path: dict, made: dict, world, scene_file: Path,
            gl_renderer: str) -> dict:
    """results.json: the issue's keys, then the detail (``world``: the scene file's
    scene)."""
    from lodsprite.scene.world import summary

    pvl = [p["profile_vs_linear"] for p in per_path.values()]

    def mean(side: str, key: str) -> float | None:
        vals = [x[side][key] for x in pvl]
        return None if any(v is None for v in vals) else float(np.mean(vals))

    config = {k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.__dict__.items()}
    return {
        "scheduler": pooled(per_path, "scheduler"),
        "independent": pooled(per_path, "independent"),
        "reuse": pooled(per_path, "reuse"),
        "profile_vs_linear": {
            "rmse_profile": mean("profile", "rmse"), "rmse_linear": mean("linear", "rmse"),
            "flip_profile": mean("profile", "flip"), "flip_linear": mean("linear", "flip"),
            "triangles_profile": mean("profile", "triangles_objects_reported"),
            "triangles_linear": mean("linear", "triangles_objects_reported"),
            "triangles_profile_chosen": mean("profile", MATCH_KEY),
            "triangles_linear_chosen": mean("linear", MATCH_KEY),
            "profile_lod_available": all(x["profile"]["profile_lod"] for x in pvl)},
        "extractions_with_manager": int(sum(p["manager"]["extractions"]
                                            for p in per_path.values())),
        "extractions_without_manager": int(sum(p["no_manager"]["extractions"]
                                               for p in per_path.values())),
        "paths": per_path, "config": config, "scene_file": str(scene_file), **made,
        "world": summary(world), "instances": world.objects.count, "gl_renderer": gl_renderer,
        "sample_frames": cfg.sample_frames, "chosen_frames": cfg.chosen_frames,
        "reported_frames": cfg.reported_frames}


def with_terrain(cfg: BattlefieldConfig, terrain: str | None) -> BattlefieldConfig:
    """``cfg`` over ``terrain`` when one is given (``--terrain``)."""
    return cfg if terrain is None else replace(cfg, terrain=terrain)
