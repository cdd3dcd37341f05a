"""``lodsprite reproduce large``: how frame cost, memory and error scale with terrain size
(fractal stores of 1k², 4k², 16k², ...), for the adaptive renderer at 1 px and LOD-sprite
with adaptive keyframes, along the chen1999-shaped path.

Each timed run is its own ``lodsprite render`` process (so its peak resident memory and
time to first frame are its own).  The reference for the image error is full resolution
where it fits (sides up to ``FULL_MAX``), else the adaptive renderer at 0.25 px, settled
(each viewpoint redrawn until no tile is left to load); the stand-in is validated against
full resolution at the sizes where both exist.  Errors are measured on every
``sample_every``-th frame.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lodsprite.terrain.store import build_store, estimate_bytes

FULL_MAX = 4096
Update = Callable[[str, int, int], None]


@dataclass(frozen=True)
class LargeConfig:
    sizes: tuple[int, ...] = (1024, 4096, 16384)
    frames: int = 230
    image: int = 512
    sse: float = 1.0
    key_sse: float = 0.5
    ref_sse: float = 0.25
    sample_every: int = 23
    huge: bool = False       # also 65536² (needs the disk and time it names)
    quick_512: bool = False  # the jacksboro runs on ``frames`` frames, not the whole path
    jacksboro: bool = True   # the 512² jacksboro comparison (tests leave it out)

    @classmethod
    def quick(cls) -> LargeConfig:
        return cls(sizes=(256, 512), frames=24, image=128, sample_every=8, quick_512=True)


def huge_needs() -> dict:
    """What a 65536² store needs: disk (upper bound) and free space here."""
    need = estimate_bytes(65536, 65536, "float32")
    free = shutil.disk_usage(Path.cwd()).free
    return {"need_gb": need / 2 ** 30, "free_gb": free / 2 ** 30}


def _render(args: list[str], out: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()",
                        "render", *args, "--out", str(out)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"lodsprite render {' '.join(args)} failed: {r.stderr.strip()}")
    return json.loads((out / "summary.json").read_text())


def _frames(folder: Path, keep: list[int]) -> dict[int, np.ndarray]:
    from lodsprite.api import read_image

    return {i: read_image(folder / "frames" / f"frame_{i:05d}.png") for i in keep}


def _rmse(a: dict, b: dict) -> float:
    return float(np.mean([np.sqrt(np.mean((a[i].astype(np.float64)
                                           - b[i].astype(np.float64)) ** 2)) for i in a]))


def reference(store: Path, n: int, cfg: LargeConfig, keep: list[int]) -> dict:
    """The settled adaptive frames at ``cfg.ref_sse`` of the sampled viewpoints."""
    from lodsprite import get_path, load_scene
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.target import RenderTarget
    from lodsprite.gl.terrain import TerrainGeometry
    from lodsprite.terrain.adaptive import AdaptiveTerrain
    from lodsprite.terrain.store import TerrainStore

    scene = load_scene(str(store))
    path = get_path("chen1999", scene.hf, cfg.frames)
    out = {}
    with GLContext() as gl:
        t = RenderTarget(gl, cfg.image, cfg.image)
        geo = TerrainGeometry(gl, scene.hf, scene.texture)  # the colours render uses
        a = AdaptiveTerrain(gl, TerrainStore(store), t, path.fov_y_deg, cfg.ref_sse,
                            color=geo.color_tex)
        try:
            for i in keep:
                a.settle(path.viewpoints[i])
                out[i] = t.read_color()
        finally:
            a.release()
            geo.release()
            t.release()
    return out


def reproduce_large(cfg: LargeConfig, out_dir: Path, update: Update | None = None) -> dict:
    out_dir = Path(out_dir)
    keep = list(range(0, cfg.frames, cfg.sample_every))
    sizes = list(cfg.sizes) + ([65536] if cfg.huge else [])
    r: dict = {"config": {k: (list(v) if isinstance(v, tuple) else v)
                          for k, v in cfg.__dict__.items()}, "sizes": {},
               "huge": huge_needs(), "sample_frames": keep}
    common = ["--path", "chen1999", "--frames", str(cfg.frames), "--size",
              f"{cfg.image}x{cfg.image}", "--save-frames"]
    for step, n in enumerate(sizes):
        if update:
            update("sizes", step, len(sizes))
        store = out_dir / "stores" / f"fractal_{n}.zarr"
        built = build_store(f"fractal:{n}:1", store)
        res: dict = {"tile_s": built.get("seconds"), "tile_mb_per_s": built.get("mb_per_s")}
        runs = out_dir / "runs" / str(n)
        ad = _render(["--terrain", str(store), "--mode", "adaptive", "--sse", str(cfg.sse),
                      *common], runs / "adaptive")
        sp = _render(["--terrain", str(store), "--mode", "sprite", "--key-sse",
                      str(cfg.key_sse), *common], runs / "sprite")
        ref = reference(store, n, cfg, keep)
        res["reference"] = f"adaptive at {cfg.ref_sse} px, settled"
        if n <= FULL_MAX:  # full resolution of the sampled viewpoints only
            sampled = sampled_path(store, cfg, keep, runs / "sampled.json")
            fu = _render(["--terrain", str(store), "--mode", "full", "--grid", str(n),
                          "--path", str(sampled), "--frames", str(len(keep)), "--size",
                          f"{cfg.image}x{cfg.image}", "--save-frames"], runs / "full")
            shown = _frames(runs / "full", list(range(len(keep))))
            full = {k: shown[m] for m, k in enumerate(keep)}
            res["median_ms_full"] = fu["median_ms"]
            res["reference_vs_full_rmse"] = _rmse(ref, full)
            ref, res["reference"] = full, "full resolution"
        res.update(
            median_ms_adaptive=ad["median_ms"], p99_ms_adaptive=float(np.percentile(
                json_col(runs / "adaptive"), 99)), median_ms_sprite=sp["median_ms"],
            total_s_adaptive=ad["total_s"], total_s_sprite=sp["total_s"],
            rmse_adaptive=_rmse(_frames(runs / "adaptive", keep), ref),
            rmse_sprite=_rmse(_frames(runs / "sprite", keep), ref),
            peak_rss_mb=ad["peak_rss_mb"], first_frame_s=ad["first_frame_s"],
            tiles_loaded=ad["tiles_loaded"], gpu_cache_mb=ad["gpu_cache_mb"],
            keyframes_sprite=sp["keyframes"])
        r["sizes"][str(n)] = res
        if update:
            update("sizes", step + 1, len(sizes))
    if cfg.jacksboro:
        r.update(_jacksboro(cfg, out_dir))
    return r


def _jacksboro(cfg: LargeConfig, out_dir: Path) -> dict:
    """The 512² jacksboro of chen1999: LOD-sprite with adaptive keyframes against full
    resolution, beside the plain LOD-sprite."""
    r: dict = {}
    small = ["--terrain", "jacksboro", "--path", "chen1999", "--size",
             f"{cfg.image}x{cfg.image}"] + (["--frames", str(cfg.frames)] if cfg.quick_512
                                            else [])
    runs = out_dir / "runs" / "jacksboro"
    full = _render([*small, "--mode", "full"], runs / "full")
    key = _render([*small, "--mode", "sprite", "--key-sse", str(cfg.key_sse),
                   "--ground-truth"], runs / "sprite_adaptive_keys")
    plain = _render([*small, "--mode", "sprite", "--ground-truth"], runs / "sprite")
    r["speedup_sprite_vs_full_512"] = full["total_s"] / key["total_s"]
    r["rmse_ratio_sprite_vs_lod_512"] = key["rmse_sprite_mean"] / key["rmse_lod_mean"]
    r["jacksboro"] = {"total_s_full": full["total_s"], "total_s_sprite_adaptive_keys":
                      key["total_s"], "total_s_sprite": plain["total_s"],
                      "speedup_plain_sprite": full["total_s"] / plain["total_s"],
                      "rmse_ratio_plain_sprite": plain["rmse_sprite_mean"]
                      / plain["rmse_lod_mean"], "keyframes": key["keyframes"],
                      "mean_ms_keyframe": key["mean_ms_keyframe"],
                      "mean_ms_sprite": key["mean_ms_sprite"]}
    return r


def sampled_path(store: Path, cfg: LargeConfig, keep: list[int], file: Path) -> Path:
    """The chen1999-shaped path's sampled viewpoints as a path file."""
    from lodsprite import get_path, load_scene
    from lodsprite.paths import CameraPath

    path = get_path("chen1999", load_scene(str(store)).hf, cfg.frames)
    file.parent.mkdir(parents=True, exist_ok=True)
    CameraPath("sampled", tuple(path.viewpoints[i] for i in keep), path.fov_y_deg
               ).to_json(file)
    return file


def json_col(folder: Path, column: str = "ms") -> list[float]:
    import csv

    with open(folder / "frames.csv") as f:
        return [float(row[column]) for row in csv.DictReader(f)]
