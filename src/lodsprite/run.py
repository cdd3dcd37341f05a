"""Rendering a camera path with timings: the engine behind ``lodsprite render``.

Modes ``full``, ``lod`` and ``sprite`` run in this process.  The distributed mode is not
core: the command line hands it to :func:`lodsprite.distributed.run.render_distributed`
(this module never imports :mod:`lodsprite.distributed`).

Per-frame time covers issuing the frame's GL work and waiting for it to finish
(``ctx.finish()``) — the view-frustum culling, uniform and instance uploads
included.  Reading pixels back (for saving frames) happens after the clock
stops, for every mode alike.  One untimed warm-up frame precedes the timed ones
so that shader compilation and first-use driver work are not charged to frame 0.
"""

from __future__ import annotations

import platform
from contextlib import ExitStack
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import (
    DEFAULT_GUARD_PX,
    DEFAULT_VISIBILITY,
    VISIBILITY_MODES,
    SpriteRenderer,
)
from lodsprite.paths import CameraPath, get_path
from lodsprite.progress import Progress
from lodsprite.report.io import write_csv, write_json, write_png
from lodsprite.scene import Scene, load_scene
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX, FRAME_TYPES, LodSpriteEngine
from lodsprite.terrain import DEFAULT_EXAGGERATION
from lodsprite.terrain.lod import DEFAULT_COARSE, level_step

MODES = ("full", "lod", "sprite", "adaptive")
FRAME_COLUMNS = ["frame", "mode", "ms", "triangles"]
SPRITE_COLUMNS = ["type", "error_px", "keyframe", "key_x", "key_y", "key_z"]
ADAPTIVE_COLUMNS = ["nodes", "uploaded", "resident", "loaded", "evicted"]
QUALITY_COLUMNS = ["rmse_sprite", "psnr_sprite", "ssim_sprite", "rmse_lod", "psnr_lod", "ssim_lod",
                   "rmse_lod_border"]
MAX_GUARD_PX = 1024


@dataclass(frozen=True)
class RenderConfig:
    """What to render: terrain, texture and path specs, mode, level, image size, frames."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    path: str = "chen1999"
    mode: str = "full"
    lod: int = DEFAULT_COARSE
    size: tuple[int, int] = (512, 512)
    frames: int | None = None
    grid: int | None = None
    exaggeration: float = DEFAULT_EXAGGERATION
    fov_y_deg: float | None = None  # None: the path's own (45° for the built-in paths)
    save_frames: bool = False
    epsilon: float = DEFAULT_EPSILON_PX
    ground_truth: bool = False
    quality_stride: int = 1
    visibility: str = DEFAULT_VISIBILITY
    border: bool = True
    guard_px: int = DEFAULT_GUARD_PX
    sse: float = 1.0          # adaptive: screen-space error tolerance, pixels
    key_sse: float | None = None  # sprite: keyframes by the adaptive renderer at this SSE
    gpu_mb: float = 256.0     # adaptive: GPU tile cache budget
    host_mb: float = 512.0    # adaptive: host tile cache budget

    def validate(self) -> None:
        if self.mode not in MODES:
            raise InputError(f"unknown mode '{self.mode}': use one of {', '.join(MODES)}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be between 16 and 8192 pixels, got {w}x{h}")
        if self.frames is not None and self.frames < 2:
            raise InputError(f"--frames must be at least 2, got {self.frames}")
        if not self.epsilon > 0:
            raise InputError(f"--epsilon must be > 0 pixels, got {self.epsilon}")
        if self.visibility not in VISIBILITY_MODES:
            raise InputError(f"unknown visibility '{self.visibility}': use one of "
                             f"{', '.join(VISIBILITY_MODES)}")
        if not (isinstance(self.guard_px, int) and 0 <= self.guard_px <= MAX_GUARD_PX):
            raise InputError(f"--guard must be a whole number of pixels in 0..{MAX_GUARD_PX}, "
                             f"got {self.guard_px}")
        if self.quality_stride < 1:
            raise InputError(f"quality stride must be >= 1, got {self.quality_stride}")
        if self.ground_truth and self.mode != "sprite":
            raise InputError("--ground-truth needs --mode sprite")
        if self.key_sse is not None and (self.mode != "sprite" or not self.key_sse > 0):
            raise InputError("--key-sse goes with --mode sprite and must be > 0 pixels")
        if not (self.sse > 0 and self.gpu_mb > 0 and self.host_mb > 0):
            raise InputError(f"--sse, --gpu-mb and --host-mb must be > 0, got {self.sse}, "
                             f"{self.gpu_mb}, {self.host_mb}")


def parse_size(text: str) -> tuple[int, int]:
    """``'WxH'`` or ``'N'`` to ``(width, height)`` pixels."""
    parts = text.lower().split("x")
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) == 1:
        vals = vals * 2
    if len(vals) != 2:
        raise InputError(f"size must look like 512x512, got '{text}'")
    return vals[0], vals[1]


def timing_summary(ms: np.ndarray) -> dict:
    """Median, mean, standard deviation, p95 (ms) and total (s) of per-frame times."""
    ms = np.asarray(ms, dtype=np.float64)
    return {"median_ms": float(np.median(ms)), "mean_ms": float(ms.mean()),
            "std_ms": float(ms.std()), "p95_ms": float(np.percentile(ms, 95)),
            "total_s": float(ms.sum() / 1e3)}


def prepare(config: RenderConfig) -> tuple[Scene, CameraPath]:
    """Validate the config and load scene and path (all user errors surface here)."""
    config.validate()
    scene = load_scene(config.terrain, config.texture, config.grid, config.exaggeration)
    if config.mode in ("lod", "sprite"):
        level_step(scene.hf.quads, config.lod)
    return scene, get_path(config.path, scene.hf, config.frames)


def field_of_view(config: RenderConfig, path: CameraPath) -> float:
    """The vertical field of view (degrees) to render ``path`` with: the config's if set,
    else the path's own (a path file keeps the field of view it was recorded with)."""
    return path.fov_y_deg if config.fov_y_deg is None else config.fov_y_deg


def reference_images(pr: PathRenderer, viewpoint, lod: int) -> tuple[np.ndarray, ...]:
    """What a frame is compared with (untimed): the full-resolution frame, the plain
    coarse level, and the coarse level with the border ribbons; ``(H, W, 3) uint8`` each."""
    r = pr.renderer
    r.render(viewpoint, None)
    truth = r.target.read_color()
    r.render(viewpoint, lod)
    plain = r.target.read_color()
    r.render_proxy(viewpoint, lod, border=True)
    return truth, plain, r.target.read_color()


def frame_quality(image: np.ndarray, references: tuple[np.ndarray, ...]) -> dict:
    """RMSE, PSNR and SSIM of ``image`` and of the plain coarse level against the full
    resolution (:func:`reference_images`), and RMSE of the coarse level with ribbons."""
    from lodsprite.metrics import psnr, rmse, ssim

    truth, lod, lod_border = references
    return {"rmse_sprite": rmse(image, truth), "psnr_sprite": psnr(image, truth),
            "ssim_sprite": ssim(image, truth), "rmse_lod": rmse(lod, truth),
            "psnr_lod": psnr(lod, truth), "ssim_lod": ssim(lod, truth),
            "rmse_lod_border": rmse(lod_border, truth)}


def quality_summary(rows: list[dict]) -> dict:
    """Mean RMSE / SSIM over frames; PSNR from the mean squared error over frames (a
    keyframe equals its ground truth, whose per-frame PSNR would be infinite)."""
    out = {}
    for kind in ("sprite", "lod"):
        r = np.array([row[f"rmse_{kind}"] for row in rows])
        mse = float(np.mean(r**2))
        out[f"rmse_{kind}_mean"] = float(r.mean())
        out[f"psnr_{kind}_mean"] = float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)
        out[f"ssim_{kind}_mean"] = float(np.mean([row[f"ssim_{kind}"] for row in rows]))
    out["rmse_ratio"] = (out["rmse_sprite_mean"] / out["rmse_lod_mean"]
                         if out["rmse_lod_mean"] > 0 else float("nan"))
    # The plain coarse level with the border ribbons LOD-sprite draws (an ablation: how much
    # of LOD-sprite's gain is the ribbons' alone).
    out["rmse_lod_border_mean"] = float(np.mean([row["rmse_lod_border"] for row in rows]))
    return out


def sprite_summary(rows: list[dict]) -> dict:
    """Keyframe count and mean time per frame type (ms)."""
    out: dict = {"keyframes": sum(r["type"] == "keyframe" for r in rows)}
    for t in FRAME_TYPES:
        ms = [r["ms"] for r in rows if r["type"] == t]
        out[f"mean_ms_{t}"] = float(np.mean(ms)) if ms else float("nan")
    out["keyframe_fraction"] = out["keyframes"] / len(rows)
    out["mean_error_px"] = float(np.mean([r["error_px"] for r in rows]))
    return out


def sprite_frames(pr: PathRenderer, path: CameraPath, config: RenderConfig,
                  progress: Progress | None = None, on_frame=None,
                  keyframes: list | None = None) -> list[dict]:
    """Run LOD-sprite along ``path``; rows with type, error_px, ms, triangles, keyframe (the
    index of the keyframe shown) and quality against an untimed full-resolution ground
    truth when ``config.ground_truth``, and ``key_x, key_y, key_z``, the eye (metres) of the
    keyframe shown.  ``keyframes``, if given, is extended with the engine's keyframes,
    :class:`~lodsprite.sprite.policy.KeyChoice` records in order (what ``keyframe``
    indexes)."""
    sprite = SpriteRenderer(pr.renderer, config.lod, config.visibility, border=config.border,
                            guard_px=config.guard_px)
    adaptive = None
    if config.key_sse is not None:  # keyframes by the adaptive renderer
        adaptive = _adaptive(pr, config, path, config.key_sse)
        sprite.keyframe_drawer = adaptive.render_into
        from lodsprite.terrain.store import TerrainStore
        from lodsprite.terrain.storefield import store_field

        if isinstance(adaptive.tree.p, TerrainStore):  # proxy, ribbons, metric from level 0
            pr.geometry.set_full(store_field(adaptive.tree.p))
    try:
        vp0 = path.viewpoints[0]
        sprite.render_keyframe(vp0, 0.0)  # warm-up (shader compilation), untimed
        sprite.render_spriteframe(vp0)
        pr.ctx.finish()
        engine = LodSpriteEngine(sprite, config.epsilon)
        if adaptive is not None:  # streaming goes on between keyframes
            engine.between_keyframes = adaptive.prefetch
        rows = []
        for i, vp in enumerate(path.viewpoints):
            f = engine.frame(vp)
            row = {"frame": i, "mode": "sprite", "ms": f.ms, "triangles": f.triangles,
                   "type": f.type, "error_px": f.error_px, "keyframe": f.keyframe}
            if config.ground_truth or on_frame:
                image = engine.read_image()
                if on_frame:
                    on_frame(i, image)
                if config.ground_truth and i % config.quality_stride == 0:
                    row.update(frame_quality(image, reference_images(pr, vp, config.lod)))
            rows.append(row)
            if progress:
                progress(i + 1, len(path))
        for row in rows:  # the eye of the keyframe each frame shows, metres
            eye = engine.keyframes[row["keyframe"]].viewpoint.o
            row.update(key_x=float(eye[0]), key_y=float(eye[1]), key_z=float(eye[2]))
        if keyframes is not None:
            keyframes.extend(engine.keyframes)
        return rows
    finally:
        sprite.release()
        if adaptive is not None:
            adaptive.release()


def keyframe_records(keyframes: list, rows: list[dict]) -> list[dict]:
    """JSON records of the keyframes a LOD-sprite run rendered: ``keyframes`` is the
    engine's log (:class:`~lodsprite.sprite.policy.KeyChoice` in order); ``rows`` the
    run's frames with their ``keyframe`` index.  Each record holds the viewpoint, the frame
    projection, the frame that rendered it and ``ahead`` (placed ahead of the viewer by
    look-ahead)."""
    first: dict[int, int] = {}
    for i, row in enumerate(rows):
        first.setdefault(row["keyframe"], i)
    return [{"frame": first.get(k, -1), "viewpoint": key.viewpoint.to_dict(),
             "projection": {"fov_y_deg": key.projection.fov_y_deg,
                            "aspect": key.projection.aspect, "near": key.projection.near,
                            "far": key.projection.far},
             "ahead": bool(key.predicted)}
            for k, key in enumerate(keyframes)]


def render_path(config: RenderConfig, out_dir: Path, progress: Progress | None = None,
                video: Path | None = None) -> dict:
    """Render ``config``'s path; write ``frames.csv``, ``summary.json`` (and in sprite mode
    ``keyframes.json``, every keyframe rendered, indexed by the ``keyframe`` column) and
    optionally PNG frames to ``out_dir``; return the summary.

    ``video``: an MP4 file of the frames shown (:mod:`lodsprite.report.video`); with
    ``config.ground_truth`` each video frame is full resolution | LOD-sprite | difference.
    """
    from lodsprite.report.video import VideoWriter, check_video_path, side_by_side

    if video is not None:
        check_video_path(video)
    scene, path = prepare(config)
    out_dir = Path(out_dir)
    keyframes: list = []
    with PathRenderer(scene, config.size, field_of_view(config, path)) as pr, \
            ExitStack() as stack:
        writer = stack.enter_context(VideoWriter(video)) if video is not None else None

        def on_frame(i: int, image: np.ndarray) -> None:
            if config.save_frames:
                write_png(out_dir / "frames" / f"frame_{i:05d}.png", image)
            if writer is not None:
                if config.ground_truth:  # untimed, after the frame's clock stopped
                    pr.renderer.render(path.viewpoints[i], None)
                    image = side_by_side(pr.renderer.target.read_color(), image)
                writer.append(image)

        wanted = on_frame if config.save_frames or writer is not None else None
        extra: dict = {}
        if config.mode == "sprite":
            rows = sprite_frames(pr, path, config, progress, wanted, keyframes)
        elif config.mode == "adaptive":
            rows, extra = adaptive_frames(pr, scene, path, config, progress, wanted)
        else:
            rows = plain_frames(pr, path, config, progress, wanted)
        info = pr.ctx.info
        pr.ctx.check_error("render_path")
    ms = np.array([r["ms"] for r in rows])
    summary = {
        "frames": len(rows), "mode": config.mode, "terrain": config.terrain,
        "texture": config.texture, "path": config.path,
        "size": list(config.size), "grid": scene.hf.quads,
        "lod": config.lod if config.mode in ("lod", "sprite") else scene.hf.quads,
        "exaggeration": config.exaggeration,
        **timing_summary(ms),
        "triangles_mean": float(np.mean([r["triangles"] for r in rows])),
        "gl_renderer": info.renderer, "gl_version": info.version,
        "machine": platform.machine(), "python": platform.python_version(),
        "config": asdict(config), **extra,
    }
    columns = list(FRAME_COLUMNS)
    if config.mode == "adaptive":
        columns += ADAPTIVE_COLUMNS
    if config.mode == "sprite":
        summary.update({"epsilon": config.epsilon, "visibility": config.visibility,
                        **sprite_summary(rows)})
        columns += SPRITE_COLUMNS
        if config.ground_truth:
            summary.update(quality_summary(rows))
            columns += QUALITY_COLUMNS
    write_csv(out_dir / "frames.csv", rows, columns)
    if config.mode == "sprite":
        write_json(out_dir / "keyframes.json",
                   {"keyframes": keyframe_records(keyframes, rows)})
    write_json(out_dir / "summary.json", summary)
    return summary


def plain_frames(pr: PathRenderer, path: CameraPath, config: RenderConfig,
                 progress: Progress | None = None, on_frame=None) -> list[dict]:
    """Full-resolution or uniform-level frames along ``path`` (one untimed warm-up first)."""
    level = None if config.mode == "full" else config.lod
    pr.timed(path.viewpoints[0], level)
    rows = []
    for i, vp in enumerate(path.viewpoints):
        ms, tris = pr.timed(vp, level)
        rows.append({"frame": i, "mode": config.mode, "ms": ms, "triangles": tris})
        if on_frame:
            on_frame(i, pr.renderer.target.read_color())
        if progress:
            progress(i + 1, len(path))
    return rows


def _adaptive(pr: PathRenderer, config: RenderConfig, path: CameraPath, sse: float):
    """The adaptive renderer on ``pr``'s context and target, coloured with the scene's
    texture (as full resolution is), over the terrain's extent."""
    from lodsprite.terrain.adaptive import AdaptiveTerrain

    return AdaptiveTerrain(pr.ctx, pyramid_for(config, pr.geometry.hf), pr.renderer.target,
                           field_of_view(config, path), sse, gpu_mb=config.gpu_mb,
                           host_mb=config.host_mb, color=pr.geometry.color_tex)


def pyramid_for(config: RenderConfig, hf):
    """What the adaptive renderer draws: the store itself when ``--terrain`` is one, else
    the scene's height field ``hf`` as an in-memory pyramid (so it is the field full
    resolution draws)."""
    from lodsprite.terrain.pyramid import MemoryPyramid
    from lodsprite.terrain.store import TerrainStore, is_store

    if is_store(config.terrain):
        return TerrainStore(Path(config.terrain).expanduser(), config.exaggeration)
    return MemoryPyramid.from_heightfield(hf)


def peak_rss_mb() -> float:
    """This process's peak resident memory in MB: ``VmHWM`` of ``/proc/self/status``, which
    starts afresh at ``exec`` (``getrusage``'s ``ru_maxrss`` keeps the peak of the process
    that forked it, e.g. a harness holding a GL context), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KB on Linux


def adaptive_frames(pr: PathRenderer, scene: Scene, path: CameraPath, config: RenderConfig,
                    progress: Progress | None = None, on_frame=None
                    ) -> tuple[list[dict], dict]:
    """Adaptive frames along ``path`` (:mod:`lodsprite.terrain.adaptive`): no warm-up
    beyond the roots (the first frame's time is part of ``first_frame_s``)."""
    import time

    t0 = time.perf_counter()
    terrain = _adaptive(pr, config, path, config.sse)
    rows = []
    try:
        for i, vp in enumerate(path.viewpoints):
            f = terrain.frame(vp)
            if i == 0:
                first = time.perf_counter() - t0
            rows.append({"frame": i, "mode": "adaptive", "ms": f.ms, "triangles": f.triangles,
                         "nodes": f.nodes, "uploaded": f.uploaded, "resident": f.resident,
                         "loaded": f.loaded, "evicted": f.evicted})
            if on_frame:
                on_frame(i, pr.renderer.target.read_color())
            if progress:
                progress(i + 1, len(path))
        reader = getattr(terrain.loader, "reader_peak_mb", lambda: 0.0)()
        peak = peak_rss_mb() + reader  # with the tile reader process's (an upper bound)
        extra = {"sse": config.sse, "first_frame_s": first, "peak_rss_mb": peak,
                 "peak_rss_mb_reader": reader,
                 "tiles_resident": f.resident,
                 "tiles_loaded": f.loaded, "tiles_evicted": f.evicted, "tiles_bad": f.bad,
                 "gpu_cache_tiles": terrain.slots.capacity, "levels": terrain.tree.levels,
                 "gpu_cache_mb": terrain.slots.capacity * (terrain.tree.g + 1) ** 2 * 4 / 2 ** 20}
    finally:
        terrain.release()
    return rows, extra
