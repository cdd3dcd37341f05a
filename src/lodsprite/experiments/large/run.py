"""``lodsprite reproduce large``: how frame cost, memory and error scale with terrain size
(fractal stores of 1k², 2k², 4k², 16k², ...), for the adaptive renderer at 1 px and LOD-sprite
with adaptive keyframes, along the chen1999-shaped path and a low flyover.

Each timed run is :func:`lodsprite.run.render_path` in a process of its own
(:mod:`lodsprite.experiments.large.child`; so its peak resident memory and time to first
frame are its own).  The paths: ``chen1999`` (the issue's path; it scales
with the terrain, so over a large one it flies so high that coarse levels meet 1 px almost
everywhere) and ``flyover`` (1 km above the ground along 10 km, the same in metres at every
size).  The reference for the image error is *full resolution*, the store's own level-0
samples everywhere (the adaptive renderer with every node at level 0, settled), where the
store fits (sides up to ``FULL_MAX``); beyond, the adaptive renderer at 0.25 px, settled.
That stand-in is validated against full resolution at every size where both exist (2k² and
4k² included).  Errors (RMSE in grey levels, and FLIP) are measured on every
``sample_every``-th frame; full resolution's frame time is measured on those frames too
(``render --mode full`` on the working grid, the store's samples resampled to
``(side+1)²``).  LOD-sprite runs at ε = 1 px (the paper's) and at each ``sweep_eps``; the
comparison at equal error takes the fastest of those runs whose RMSE is at most the
adaptive renderer's.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lodsprite.experiments.large.child import render_in_child
from lodsprite.terrain.store import build_store, estimate_bytes

FULL_MAX = 4096
FULL_SSE = 1e-6  # px: every node refined to level 0 (full resolution)
Update = Callable[[str, int, int], None]


@dataclass(frozen=True)
class LargeConfig:
    sizes: tuple[int, ...] = (1024, 2048, 4096, 16384)
    paths: tuple[str, ...] = ("chen1999", "flyover")
    frames: int = 230
    image: int = 512
    sse: float = 1.0
    key_sse: float = 0.5
    ref_sse: float = 0.25
    sample_every: int = 23
    sweep_eps: tuple[float, ...] = (0.7, 0.5, 0.25)  # LOD-sprite also at these ε (equal error)
    huge: bool = False       # also 65536² (needs the disk and time it names)
    quick_512: bool = False  # the jacksboro runs on ``frames`` frames, not the whole path
    jacksboro: bool = True   # the 512² jacksboro comparison (tests leave it out)
    terrains: tuple[str, ...] = ()  # more terrains: stores, or sources to tile first

    @classmethod
    def quick(cls) -> LargeConfig:
        return cls(sizes=(256, 512), frames=24, image=128, sample_every=8, quick_512=True,
                   sweep_eps=(0.5,))


def huge_needs() -> dict:
    """What a 65536² store needs: disk (upper bound) and free space here."""
    need = estimate_bytes(65536, 65536, "float32")
    free = shutil.disk_usage(Path.cwd()).free
    return {"need_gb": need / 2 ** 30, "free_gb": free / 2 ** 30}


def _frames(folder: Path, keep: list[int]) -> dict[int, np.ndarray]:
    from lodsprite.api import read_image

    return {i: read_image(folder / "frames" / f"frame_{i:05d}.png") for i in keep}


def errors(a: dict, b: dict) -> tuple[float, float]:
    """Mean RMSE (grey levels) and mean FLIP of the images ``a`` against ``b``."""
    from lodsprite.metrics import flip, rmse

    return (float(np.mean([rmse(a[i], b[i]) for i in a])),
            float(np.mean([flip(a[i], b[i]) for i in a])))


def reference(store: Path, scene, path, cfg: LargeConfig, keep: list[int],
              sse: float) -> dict:
    """The settled adaptive frames at ``sse`` px (``FULL_SSE``: full resolution) of the
    sampled viewpoints of ``path`` (a :class:`~lodsprite.paths.CameraPath` over
    ``scene``, the store as ``render`` loads it, for its colours)."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.target import RenderTarget
    from lodsprite.gl.terrain import TerrainGeometry
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
    from lodsprite.terrain.store import TerrainStore

    full = sse <= FULL_SSE
    out = {}
    with GLContext() as gl:
        t = RenderTarget(gl, cfg.image, cfg.image)
        geo = TerrainGeometry(gl, scene.hf, scene.texture)
        # color None: the heights shading, as render colours a store (--shading auto)
        a = AdaptiveTerrain(gl, TerrainStore(store), t, path.fov_y_deg, sse,
                            gpu_mb=1024.0 if full else 256.0, host_mb=1024.0 if full else 512.0,
                            upload_budget=4096 if full else 16, color=None)
        try:
            for i in keep:
                a.settle(path.viewpoints[i])
                out[i] = t.read_color()
        finally:
            a.release()
            geo.release()
            t.release()
    return out


def sprite_lod(side: int) -> int:
    """LOD-sprite's coarse level for a store ``side`` samples a side: squares of about
    128 samples (3.8 km at 30 m), 16 to 128 squares a side (16, the paper's, up to 2k²).
    A fixed 16² over 16k² has squares 30 km wide: a low flight sees one or two square
    centres, and the proxy stands far off the ground in view."""
    q = 16
    while q < 128 and q * 128 < side:
        q *= 2
    return q


def run_path(store: Path, n: int, cfg: LargeConfig, path_spec: str, runs: Path) -> dict:
    """Adaptive, LOD-sprite and the references of one store along one path."""
    keep = list(range(0, cfg.frames, cfg.sample_every))
    common = {"path": path_spec, "frames": cfg.frames, "size": [cfg.image, cfg.image],
              "save_frames": True}
    lod = {"lod": sprite_lod(n)}
    from lodsprite import get_path, load_scene

    scene = load_scene(str(store))  # once: the references and the sampled path share it
    path = get_path(path_spec, scene.hf, cfg.frames)
    ad = render_in_child({"terrain": str(store), "mode": "adaptive", "sse": cfg.sse, **common},
                         runs / "adaptive")
    sp = render_in_child({"terrain": str(store), "mode": "sprite", "key_sse": cfg.key_sse,
                          **lod, **common}, runs / "sprite")
    res: dict = {}
    ref = stand_in = reference(store, scene, path, cfg, keep, cfg.ref_sse)
    res["reference"] = f"adaptive at {cfg.ref_sse} px, settled"
    if n <= FULL_MAX:
        ref = reference(store, scene, path, cfg, keep, FULL_SSE)
        res["reference"] = "full resolution (level 0 everywhere, settled)"
        res["reference_vs_full_rmse"], res["reference_vs_full_flip"] = errors(stand_in, ref)
        sampled = sampled_path(path, keep, runs / "sampled.json")
        fu = render_in_child({"terrain": str(store), "mode": "full", "grid": n,
                              "path": str(sampled), "frames": len(keep),
                              "size": [cfg.image, cfg.image]}, runs / "full")
        res["median_ms_full"] = fu["median_ms"]
    ea = errors(_frames(runs / "adaptive", keep), ref)
    es = errors(_frames(runs / "sprite", keep), ref)
    sweep = [{"epsilon": 1.0, "total_s": sp["total_s"], "median_ms": sp["median_ms"],
              "keyframes": sp["keyframes"], "rmse": es[0], "flip": es[1]}]
    for eps in cfg.sweep_eps:
        folder = runs / f"sprite_eps{eps:g}"
        s = render_in_child({"terrain": str(store), "mode": "sprite", "key_sse": cfg.key_sse,
                             "epsilon": eps, **lod, **common}, folder)
        e = errors(_frames(folder, keep), ref)
        sweep.append({"epsilon": eps, "total_s": s["total_s"], "median_ms": s["median_ms"],
                      "keyframes": s["keyframes"], "rmse": e[0], "flip": e[1]})
    res["sprite_sweep"] = sweep
    res["equal_error"] = equal_error(sweep, ea[0], ad["total_s"])
    res.update(
        median_ms_adaptive=ad["median_ms"],
        p99_ms_adaptive=float(np.percentile(json_col(runs / "adaptive"), 99)),
        median_ms_sprite=sp["median_ms"],
        p99_ms_sprite=float(np.percentile(json_col(runs / "sprite"), 99)),
        total_s_adaptive=ad["total_s"], total_s_sprite=sp["total_s"],
        rmse_adaptive=ea[0], flip_adaptive=ea[1], rmse_sprite=es[0], flip_sprite=es[1],
        peak_rss_mb=ad["peak_rss_mb"], first_frame_s=ad["first_frame_s"],
        tiles_loaded=ad["tiles_loaded"], tiles_evicted=ad["tiles_evicted"],
        gpu_cache_mb=ad["gpu_cache_mb"], keyframes_sprite=sp["keyframes"],
        speedup_sprite_vs_adaptive=ad["total_s"] / sp["total_s"], sprite_lod=sprite_lod(n))
    return res


def equal_error(sweep: list[dict], rmse_adaptive: float, total_s_adaptive: float
                ) -> dict | None:
    """The fastest LOD-sprite run of ``sweep`` whose RMSE is at most adaptive's, with its
    speedup over adaptive (total times); None when no ε reaches adaptive's error."""
    ok = [s for s in sweep if s["rmse"] <= rmse_adaptive]
    if not ok:
        return None
    best = min(ok, key=lambda s: s["total_s"])
    return {**best, "speedup": total_s_adaptive / best["total_s"]}


def _store_for(spec: str, stores: Path) -> tuple[Path, dict, int]:
    """A terrain given with ``--terrain``: a store as it is, anything else tiled first."""
    from lodsprite.terrain.store import TerrainStore, is_store

    p = Path(spec).expanduser()
    if is_store(p):
        built: dict = {}
    else:
        name = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in p.name or spec)
        built = build_store(spec, stores / f"{name}.zarr")
        p = stores / f"{name}.zarr"
    return p, built, max(TerrainStore(p).shape(0))


def reproduce_large(cfg: LargeConfig, out_dir: Path, update: Update | None = None) -> dict:
    out_dir = Path(out_dir)
    sizes = list(cfg.sizes) + ([65536] if cfg.huge else [])
    jobs = [(str(n), f"fractal:{n}:1") for n in sizes] + [(t, t) for t in cfg.terrains]
    r: dict = {"config": {k: (list(v) if isinstance(v, tuple) else v)
                          for k, v in cfg.__dict__.items()}, "sizes": {}, "terrains": {},
               "huge": huge_needs(),
               "sample_frames": list(range(0, cfg.frames, cfg.sample_every))}
    for step, (key, spec) in enumerate(jobs):
        if update:
            update("stores", step, len(jobs))
        if spec.startswith("fractal:"):
            store, n = out_dir / "stores" / f"fractal_{key}.zarr", int(key)
            built = build_store(spec, store)
        else:
            store, built, n = _store_for(spec, out_dir / "stores")
        tile = {"tile_s": built.get("seconds"), "tile_mb_per_s": built.get("mb_per_s"),
                "side": n}
        safe = key if key.isdigit() else f"terrain{step}"
        per_path = {p: run_path(store, n, cfg, p, out_dir / "runs" / safe / p)
                    for p in cfg.paths}
        first, *rest = cfg.paths
        res = {**tile, **per_path[first], **{p: per_path[p] for p in rest}}
        (r["sizes"] if spec.startswith("fractal:") else r["terrains"])[key] = res
        if update:
            update("stores", step + 1, len(jobs))
    if cfg.jacksboro:
        r.update(_jacksboro(cfg, out_dir))
    return r


def rmse_ratio_vs_lod(summary: dict) -> float:
    """A sprite run's RMSE against full resolution over its plain coarse level's, from the
    ``summary.json`` of ``render --mode sprite --ground-truth`` (``rmse_mean``,
    ``rmse_lod_mean``)."""
    return summary["rmse_mean"] / summary["rmse_lod_mean"]


def _jacksboro(cfg: LargeConfig, out_dir: Path) -> dict:
    """The 512² jacksboro of chen1999: LOD-sprite with adaptive keyframes against full
    resolution, beside the plain LOD-sprite."""
    r: dict = {}
    small = {"terrain": "jacksboro", "path": "chen1999", "size": [cfg.image, cfg.image],
             **({"frames": cfg.frames} if cfg.quick_512 else {})}
    runs = out_dir / "runs" / "jacksboro"
    full = render_in_child({**small, "mode": "full"}, runs / "full")
    key = render_in_child({**small, "mode": "sprite", "key_sse": cfg.key_sse,
                           "ground_truth": True}, runs / "sprite_adaptive_keys")
    plain = render_in_child({**small, "mode": "sprite", "ground_truth": True}, runs / "sprite")
    r["speedup_sprite_vs_full_512"] = full["total_s"] / key["total_s"]
    r["rmse_ratio_sprite_vs_lod_512"] = rmse_ratio_vs_lod(key)
    r["jacksboro"] = {"total_s_full": full["total_s"], "total_s_sprite_adaptive_keys":
                      key["total_s"], "total_s_sprite": plain["total_s"],
                      "speedup_plain_sprite": full["total_s"] / plain["total_s"],
                      "rmse_ratio_plain_sprite": rmse_ratio_vs_lod(plain),
                      "keyframes": key["keyframes"],
                      "mean_ms_keyframe": key["mean_ms_keyframe"],
                      "mean_ms_sprite": key["mean_ms_sprite"]}
    return r


def sampled_path(path, keep: list[int], file: Path) -> Path:
    """The viewpoints ``keep`` of ``path`` as a path file."""
    from lodsprite.paths import CameraPath

    file.parent.mkdir(parents=True, exist_ok=True)
    CameraPath("sampled", tuple(path.viewpoints[i] for i in keep), path.fov_y_deg
               ).to_json(file)
    return file


def json_col(folder: Path, column: str = "ms") -> list[float]:
    import csv

    with open(folder / "frames.csv") as f:
        return [float(row[column]) for row in csv.DictReader(f)]
