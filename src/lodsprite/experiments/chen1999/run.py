"""Reproduction of Chen, Swan & Kaufman (1999) §4: Figures 8-14 measured side by side.

Everything in ``results.json`` is measured in one run on one machine:

* full resolution, the plain coarse level and LOD-sprite are timed over the same
  frames of the same path (``speedup = total_s_full / total_s_sprite``);
* for large fields the full-resolution time may be measured on an even sample of
  frames (at least 46) and scaled to the whole path (``full_sampled``);
* image quality compares each LOD-sprite frame and the plain coarse frame with an
  untimed full-resolution render of the same viewpoint (optionally every k-th frame);
* every keyframe is logged with the viewpoint and projection it was rendered from
  (``keyframe_views``; with look-ahead, ahead of the viewer), and each frame with the
  index of the keyframe it shows (``per_frame.keyframe``) and that keyframe's eye
  (``per_frame.keyframe_eye``).  Figures 13-14 show the keyframe their LOD-sprite image
  was drawn from, re-rendered from its logged viewpoint and projection.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import write_json, write_png
from lodsprite.gl.sprite import DEFAULT_GUARD_PX, DEFAULT_VISIBILITY, SpriteDrawer
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.harness import quality_summary
from lodsprite.metrics import difference_image
from lodsprite.paths import chen1999
from lodsprite.progress import Progress
from lodsprite.run import RenderConfig, keyframe_records, sprite_frames
from lodsprite.scene import Scene, load_scene
from lodsprite.sprite.engine import KEYFRAME
from lodsprite.sprite.policy import KeyChoice
from lodsprite.terrain import make_texture

FIG10_FRAMES = (115, 230, 460, 920, 1840)
FIG11_EPSILON = (0.25, 0.5, 1.0, 2.0, 4.0)
MIN_FULL_SAMPLE = 46
QUALITY_SWEEP_STRIDE = 10
# lodsprite demo (ReproduceConfig.demo): what it keeps of the paper's run.
DEMO_FIG10_FRAMES = (115, 230, 460)
DEMO_FULL_SAMPLE = 92
DEMO_QUALITY_STRIDE = 5


@dataclass(frozen=True)
class ReproduceConfig:
    """Parameters of the reproduction; defaults are the paper's (512², 16², 460 frames, 1 px)."""

    terrain: str = "jacksboro"
    grid: int | None = None
    size: int = 512
    frames: int = 460
    epsilon: float = 1.0
    lod: int = 16
    visibility: str = DEFAULT_VISIBILITY
    border: bool = True
    guard_px: int = DEFAULT_GUARD_PX
    fig10_frames: tuple[int, ...] = FIG10_FRAMES
    fig11_epsilon: tuple[float, ...] = FIG11_EPSILON
    full_sample: int | None = None      # None: every frame up to 1024², else 46 frames
    quality_stride: int | None = None   # None: every frame up to 1024², else frames // 46
    sweeps: bool = True

    @classmethod
    def quick(cls, **kw) -> ReproduceConfig:
        """A short run (about a tenth of the work) for smoke tests and first looks."""
        base = {"size": 256, "frames": 115, "fig10_frames": (58, 115),
                "fig11_epsilon": (0.5, 1.0, 2.0), "quality_stride": 3}
        return cls(**{**base, **kw})

    @classmethod
    def demo(cls, **kw) -> ReproduceConfig:
        """``lodsprite demo``: the paper's set-up (512², the whole 460-frame path) with
        Fig. 10 up to the path's own length and no ε sweeps (Figs 11-12), full resolution
        timed on :data:`DEMO_FULL_SAMPLE` frames and quality on every
        :data:`DEMO_QUALITY_STRIDE`-th frame, to finish within two minutes on 2 cores (67-71 s
        measured)."""
        base = {"fig10_frames": DEMO_FIG10_FRAMES, "fig11_epsilon": (),
                "full_sample": DEMO_FULL_SAMPLE, "quality_stride": DEMO_QUALITY_STRIDE}
        return cls(**{**base, **kw})

    def render_config(self, **kw) -> RenderConfig:
        base = {"terrain": self.terrain, "texture": "terrain", "path": "chen1999",
                "mode": "sprite", "lod": self.lod, "size": (self.size, self.size),
                "frames": self.frames, "grid": self.grid, "epsilon": self.epsilon,
                "visibility": self.visibility, "border": self.border, "guard_px": self.guard_px}
        return RenderConfig(**{**base, **kw})


@dataclass
class _Work:
    """Counts frames done across the experiment's phases for one progress bar."""

    total: int
    progress: Progress | None
    done: int = 0

    def step(self, _i: int = 0, _n: int = 0) -> None:
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total)


def _sample_indices(frames: int, sample: int) -> np.ndarray:
    return np.unique(np.linspace(0, frames - 1, min(sample, frames)).round().astype(int))


def _timed_level(pr: TerrainGL, path, level: int | None, indices, work: _Work) -> np.ndarray:
    """Per-frame ms at ``level`` (None = full) for ``indices``, through the harness (the
    ``full`` or ``lod`` technique along those viewpoints); NaN elsewhere."""
    from lodsprite.api import Renderer
    from lodsprite.harness import run_path
    from lodsprite.paths import CameraPath
    from lodsprite.techniques import create

    ms = np.full(len(path), np.nan)
    sampled = CameraPath(path.name, tuple(path.viewpoints[int(i)] for i in indices),
                         path.fov_y_deg)
    with Renderer.wrap(pr) as renderer:
        t = create("full", renderer) if level is None else create("lod", renderer, lod=level)
        try:
            result = run_path(t, sampled, progress=work.step)
        finally:
            t.release()
    ms[np.asarray(indices, dtype=int)] = [f.ms for f in result.frames]
    return ms


def _sweep(pr: TerrainGL, scene: Scene, cfg: ReproduceConfig, work: _Work,
           total_s_full: float, main: list[dict]) -> dict:
    """Figures 10-12: keyframe fraction vs frames and vs ε; speedup vs ε (Figs 11-12
    only when ``cfg.fig11_epsilon`` has points).  Fig. 10's point at ``cfg.frames`` is
    the main run ``main`` (the same path, ε and settings), not run again."""
    fig10 = {"frames": [], "keyframes": [], "keyframe_fraction": []}
    for n in cfg.fig10_frames:
        rows = main if n == cfg.frames else sprite_frames(
            pr, chen1999(scene.hf, n), cfg.render_config(frames=n), work.step)
        k = sum(r["kind"] == KEYFRAME for r in rows)
        fig10["frames"].append(n)
        fig10["keyframes"].append(k)
        fig10["keyframe_fraction"].append(k / n)
    if not cfg.fig11_epsilon:
        return {"fig10": fig10}
    fig11 = {"epsilon": [], "keyframes": [], "keyframe_fraction": []}
    fig12 = {"epsilon": [], "total_s_sprite": [], "speedup": []}
    path = chen1999(scene.hf, cfg.frames)
    for eps in cfg.fig11_epsilon:
        # One timed run; quality (every QUALITY_SWEEP_STRIDE-th frame) in its untimed replay.
        rows = sprite_frames(pr, path, cfg.render_config(
            epsilon=eps, ground_truth=True, quality_stride=QUALITY_SWEEP_STRIDE), work.step)
        k = sum(r["kind"] == KEYFRAME for r in rows)
        total = sum(r["ms"] for r in rows) / 1e3
        fig11["epsilon"].append(eps)
        fig11["keyframes"].append(k)
        fig11["keyframe_fraction"].append(k / len(rows))
        fig12["epsilon"].append(eps)
        fig12["total_s_sprite"].append(total)
        fig12["speedup"].append(total_s_full / total)
        q = quality_summary(rows)
        for key in ("rmse", "rmse_lod"):
            fig11.setdefault(key, []).append(q[f"{key}_mean"])
        fig11.setdefault("rmse_ratio", []).append(q["rmse_ratio"])
    return {"fig10": fig10, "fig11": fig11, "fig12": fig12}


def sprite_summary(rows: list[dict]) -> dict:
    """Keyframe count and fraction, mean time per frame kind (ms), mean error (px)."""
    from lodsprite.sprite.engine import FRAME_TYPES

    out: dict = {"keyframes": sum(r["kind"] == KEYFRAME for r in rows)}
    for t in FRAME_TYPES:
        ms = [r["ms"] for r in rows if r["kind"] == t]
        out[f"mean_ms_{t}"] = float(np.mean(ms)) if ms else float("nan")
    out["keyframe_fraction"] = out["keyframes"] / len(rows)
    out["mean_error_px"] = float(np.mean([r["error_px"] for r in rows]))
    return out


def _pick_frame(rows: list[dict]) -> int:
    """The frame of Figures 13-14: the spriteframe with the largest error in the middle half
    of the path, i.e. LOD-sprite at its worst just before a new keyframe."""
    n = len(rows)
    best = (-1.0, n // 2)
    for i, r in enumerate(rows):
        if r["kind"] != KEYFRAME and n // 4 <= i < 3 * n // 4 and r["error_px"] > best[0]:
            best = (r["error_px"], i)
    return best[1]



def _figure_images(pr: TerrainGL, scene: Scene, cfg: ReproduceConfig, path, frame: int,
                   key: int, key_view: KeyChoice, key_frame: int, out_dir: Path) -> dict:
    """Figures 13 (checker texture) and 14 (terrain texture): full, coarse, LOD-sprite, and
    the keyframe LOD-sprite drew from (keyframe ``key``, rendered at frame ``key_frame``
    from ``key_view`` = its logged viewpoint and frame projection)."""
    images = {}
    vp = path.viewpoints[frame]
    key_vp, key_proj = key_view.viewpoint, key_view.projection
    for fig, texture in (("fig13", make_texture("checker", scene.hf)), ("fig14", None)):
        if texture is not None:
            pr.geometry.set_texture(texture)
        r = pr.drawer
        r.render(vp)
        full = r.target.read_color()
        r.render(vp, cfg.lod)
        lod = r.target.read_color()
        sprite = SpriteDrawer(r, cfg.lod, cfg.visibility, border=cfg.border,
                                guard_px=cfg.guard_px)
        try:
            sprite.render_keyframe(key_vp, 0.0, key_proj)
            keyframe = sprite.keyframe_color()
            sprite.render_spriteframe(vp)
            lsp = sprite.target.read_color()
        finally:
            sprite.release()
        entry = {"frame": frame, "keyframe": key, "keyframe_frame": key_frame}
        for name, img in (("full", full), ("lod", lod), ("sprite", lsp),
                          ("keyframe_image", keyframe)):
            write_png(out_dir / f"{fig}_{name}.png", img)
            entry[name] = f"{fig}_{name}.png"
        if fig == "fig14":
            for name, img in (("diff_lod", lod), ("diff_sprite", lsp)):
                write_png(out_dir / f"{fig}_{name}.png", difference_image(img, full))
                entry[name] = f"{fig}_{name}.png"
            entry["reference"] = _reference_image(pr, scene, vp, out_dir / f"{fig}_reference.png")
        images[fig] = entry
        if texture is not None:
            pr.geometry.set_texture(scene.texture)
    return images


def _reference_image(pr: TerrainGL, scene: Scene, vp, png: Path) -> str:
    """The band-limited reference at ``vp`` (what every quality figure is judged
    against), written to ``png``; its file name."""
    from lodsprite.harness import level_zero_reference

    w, h = pr.drawer.target.size
    ref = level_zero_reference(pr.ctx, scene, (w, h), pr.drawer.fov_y_deg, "auto")
    try:
        write_png(png, ref.image(vp))
    finally:
        ref.release()
    return png.name


def reproduce_chen1999(cfg: ReproduceConfig, out_dir: Path,
                       progress: Progress | None = None) -> dict:
    """Run the experiment; write PNG images, ``results.json``; return the results dict.

    Plots and ``report.md`` are written by :mod:`lodsprite.experiments.chen1999.report`.
    """
    if cfg.frames < 2 or cfg.size < 16:
        raise InputError("reproduce needs at least 2 frames and 16-pixel images")
    cfg.render_config().validate()
    scene = load_scene(cfg.terrain, "terrain", cfg.grid)
    path = chen1999(scene.hf, cfg.frames)
    large = scene.hf.quads > 1024
    sample = cfg.full_sample or (MIN_FULL_SAMPLE if large else cfg.frames)
    if sample < min(MIN_FULL_SAMPLE, cfg.frames):
        raise InputError(f"full-resolution sample must be at least {MIN_FULL_SAMPLE} frames")
    stride = cfg.quality_stride or (max(1, cfg.frames // MIN_FULL_SAMPLE) if large else 1)
    full_idx = _sample_indices(cfg.frames, sample)
    sweep_frames = (sum(n for n in cfg.fig10_frames if n != cfg.frames)
                    + cfg.frames * len(cfg.fig11_epsilon) if cfg.sweeps else 0)
    work = _Work(len(full_idx) + 3 * cfg.frames + sweep_frames, progress)
    out_dir = Path(out_dir)
    with TerrainGL(scene, (cfg.size, cfg.size)) as pr:
        ms_full = _timed_level(pr, path, None, full_idx, work)
        ms_lod = _timed_level(pr, path, cfg.lod, np.arange(cfg.frames), work)
        total_s_full = float(np.nanmean(ms_full)) * cfg.frames / 1e3
        # The harness times the run, then measures quality in an untimed replay of the
        # same decisions (each keyframe re-rendered from its logged viewpoint).
        keys: list[KeyChoice] = []
        main = sprite_frames(pr, path, cfg.render_config(ground_truth=True,
                                                         quality_stride=stride),
                             work.step, keyframes=keys)
        for _ in range(len(path)):  # the replay is not counted frame by frame
            work.step()
        # Frame at which each keyframe was rendered: the first frame showing it.
        key_views = keyframe_records(keys, main)
        frame = _pick_frame(main)
        key = main[frame]["keyframe"]
        images = _figure_images(pr, scene, cfg, path, frame, key, keys[key],
                                key_views[key]["frame"], out_dir)
        images["fig13"]["keyframe_ahead"] = images["fig14"]["keyframe_ahead"] = \
            key_views[key]["ahead"]
        sweeps = _sweep(pr, scene, cfg, work, total_s_full, main) if cfg.sweeps else {}
        info = pr.ctx.info
        pr.ctx.check_error("reproduce")
    return _results(cfg, scene, main, key_views, ms_full, ms_lod, full_idx, stride,
                    total_s_full, images, sweeps, info, out_dir)


def _results(cfg, scene, main, key_views, ms_full, ms_lod, full_idx, stride, total_s_full,
             images, sweeps, info, out_dir) -> dict:
    import platform

    quality_rows = [r for r in main if "rmse" in r]
    total_s_sprite = sum(r["ms"] for r in main) / 1e3
    results = {
        "experiment": "chen1999", "path": "chen1999", "terrain": cfg.terrain,
        "grid": scene.hf.quads,
        "lod": cfg.lod, "size": [cfg.size, cfg.size], "frames": cfg.frames,
        "epsilon": cfg.epsilon, "visibility": cfg.visibility, "border": cfg.border,
        "guard_px": cfg.guard_px,
        "gl_renderer": info.renderer, "gl_version": info.version,
        "machine": f"{platform.machine()}, {platform.system()}, python {platform.python_version()}",
        **sprite_summary(main),
        "total_s_full": total_s_full, "total_s_sprite": total_s_sprite,
        "total_s_lod": float(np.sum(ms_lod)) / 1e3,
        "speedup": total_s_full / total_s_sprite,
        "full_sampled": len(full_idx) < cfg.frames, "full_sample_frames": len(full_idx),
        "quality_stride": stride, "quality_frames": len(quality_rows),
        **quality_summary(main),  # the harness's keys: rmse_mean, rmse_lod_mean, flicker_mean
        "per_frame": {
            "type": [r["kind"] for r in main],
            "error_px": [r["error_px"] for r in main],
            "keyframe": [r["keyframe"] for r in main],
            "keyframe_eye": [key_views[r["keyframe"]]["viewpoint"]["o"] for r in main],
            "ms_sprite": [r["ms"] for r in main],
            "ms_full": [None if np.isnan(v) else float(v) for v in ms_full],
            "ms_lod": [float(v) for v in ms_lod],
            "rmse": [r.get("rmse") for r in main],
            "rmse_lod": [r.get("rmse_lod") for r in main],
        },
        "keyframe_views": key_views,
        "keyframes_ahead": sum(k["ahead"] for k in key_views),
        **sweeps,
        "images": images,
        "config": asdict(cfg),
    }
    write_json(out_dir / "results.json", results)
    return results
