"""``lodsprite reproduce sloan1997``: the measurements of Sloan, Cohen & Gortler (1997) on
this machine, beside the paper's.

* capture time of the default lumigraph (32² nodes of 256², JPEG);
* the full reconstruction's PSNR/SSIM against the object drawn directly, with and
  without depth correction (§2.3);
* Table 1: textured samples per covered pixel of each method (an occlusion query round
  the reconstruction's draw), texture load (uploads and MB per frame) and locality (how
  much more the PSNR in the image's central quarter exceeds the PSNR over the rest than
  it does for the full method: detail kept at the centre, dB);
* Figures 5-6: time and images per frame along a camera path under a small texture
  memory (4 MB, the RE2's) and a unified one (the O2's), plus the paper's single scale
  factor for comparison (§5.2);
* quality against the texture budget and against the frame-time target.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lodsprite.camera import perspective
from lodsprite.lumigraph.paths import object_path
from lodsprite.lumigraph.reference import read_object
from lodsprite.lumigraph.run import MethodRun, capture_lumigraph, measure
from lodsprite.lumigraph.store import Lumigraph
from lodsprite.paths import CameraPath

Update = Callable[[str, int, int], None]
TABLE1_METHODS = ("full", "subsample", "fixed", "arbitrary", "progressive", "line",
                  "projective")


@dataclass(frozen=True)
class SloanConfig:
    """What to run; :meth:`quick` is a small version for tests and a first look."""

    st: int = 32
    uv: int = 256
    size: int = 512
    quality_frames: int = 60
    fill_frames: int = 40
    critical_frames: int = 600
    sweep_frames: int = 150
    every: int = 10          # PSNR of every k-th frame in the critical runs
    target_fps: float = 30.0
    small_mb: float = 4.0
    unified_mb: float = 256.0
    texture_mbs: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0, 16.0, 64.0)
    target_fpss: tuple[float, ...] = (10.0, 20.0, 30.0, 60.0)
    profiles: dict = field(default_factory=dict)

    @classmethod
    def quick(cls) -> SloanConfig:
        return cls(st=8, uv=64, size=128, quality_frames=6, fill_frames=4,
                   critical_frames=24, sweep_frames=8, every=4, small_mb=0.05,
                   unified_mb=1.0, texture_mbs=(0.02, 0.05), target_fpss=(30.0, 60.0))

    def critical_profiles(self) -> dict[str, dict]:
        """The Figure 5-6 runs: RE2-like small texture memory, O2-like unified memory, and
        the small memory with the paper's one scale factor for all costs."""
        return {"re2_small_memory": {"texture_mb": self.small_mb},
                "o2_unified_memory": {"texture_mb": self.unified_mb},
                "re2_single_factor": {"texture_mb": self.small_mb, "per_component": False}}


def to_and_fro(path: CameraPath, frames: int) -> CameraPath:
    """``path`` swept forth and back until ``frames`` viewpoints."""
    vps = list(path.viewpoints)
    loop = vps + vps[-2:0:-1]
    out = [loop[i % len(loop)] for i in range(frames)]
    return CameraPath(path.name + "-sweep", tuple(out), path.fov_y_deg)


def reproduce_sloan1997(cfg: SloanConfig, out_dir: Path, update: Update | None = None
                        ) -> dict:
    """Run every measurement; returns the results (written by the report layer)."""
    out_dir = Path(out_dir)
    lf_dir = out_dir / "lumigraph"

    def step(name):
        return (lambda done, total: update(name, done, total)) if update else None

    cap = capture_lumigraph("still-life", lf_dir, cfg.st, cfg.uv, progress=step("capture"))
    slab = Lumigraph(lf_dir).slabs[0]
    size = (cfg.size, cfg.size)
    r: dict = {"config": {k: v for k, v in cfg.__dict__.items() if k != "profiles"},
               "capture_s": cap["capture_s"], "nodes": cap["nodes"], "uv": cfg.uv,
               "faces": cap["faces"]}
    r["lumigraph_mb"] = sum(p.stat().st_size for p in (lf_dir / "slab0").iterdir()) / 2**20
    path = object_path(slab, cfg.quality_frames)
    for key, dc in (("full", True), ("full_no_depth_correction", False)):
        _, s = measure(lf_dir, "full", path, size=size, ground_truth=True,
                       depth_correction=dc, quality_every=2, progress=step(key), flip=True)
        r[key] = s
    r["psnr_full"] = r["full"]["psnr_mean"]
    r["psnr_no_depth_correction"] = r["full_no_depth_correction"]["psnr_mean"]
    r["table1"] = table1(lf_dir, object_path(slab, cfg.fill_frames), size, step("table 1"))
    r["fill_rate"] = {m: v["fill_rate"] for m, v in r["table1"].items()}
    long = to_and_fro(object_path(slab, max(2, cfg.critical_frames // 2)), cfg.critical_frames)
    r["critical"], r["critical_frames"] = {}, {}
    for name, opts in cfg.critical_profiles().items():
        rows, s = measure(lf_dir, "critical", long, size=size, ground_truth=True,
                          quality_every=cfg.every, progress=step(name),
                          target_fps=cfg.target_fps, **opts)
        r["critical"][name] = _profile(s, opts)
        r["critical_frames"][name] = {k: [row[k] for row in rows]
                                      for k in ("ms", "images", "uploads")}
    sweep = to_and_fro(object_path(slab, max(2, cfg.sweep_frames // 2)), cfg.sweep_frames)
    r["quality_vs_texture_mb"] = [
        _profile(measure(lf_dir, "critical", sweep, size=size, ground_truth=True,
                         quality_every=max(1, cfg.every // 2), target_fps=cfg.target_fps,
                         texture_mb=mb, progress=step(f"{mb:g} MB"))[1], {"texture_mb": mb})
        for mb in cfg.texture_mbs]
    r["quality_vs_target"] = [
        _profile(measure(lf_dir, "critical", sweep, size=size, ground_truth=True,
                         quality_every=max(1, cfg.every // 2), target_fps=fps,
                         texture_mb=cfg.unified_mb, progress=step(f"{fps:g} fps"))[1],
                 {"texture_mb": cfg.unified_mb})
        for fps in cfg.target_fpss]
    r["gl_renderer"] = r["full"]["gl_renderer"]
    return r


def _profile(s: dict, opts: dict) -> dict:
    return {"target_ms": s["target_ms"], "mean_ms": s["mean_ms"], "median_ms": s["median_ms"],
            "p99_ms": s["p99_ms"], "max_ms": s["max_ms"],
            "images_per_frame_mean": s["images_per_frame_mean"],
            "uploads_per_frame_mean": s["uploads_per_frame_mean"],
            "psnr_mean": s.get("psnr_mean"), "ssim_mean": s.get("ssim_mean"),
            "flip_mean": s.get("flip_mean"),
            "texture_mb": opts.get("texture_mb"), "texture_layers": s["texture_layers"],
            "per_component": opts.get("per_component", True), "scale": s["scale"],
            "decode_ms": s["decode_ms"], "frames": s["frames"]}


def table1(lf_dir: Path, path: CameraPath, size: tuple[int, int],
           progress: Callable[[int, int], None] | None = None) -> dict:
    """Per method: textured samples per covered and per screen pixel (GL occlusion query
    round the reconstruction's draw), uploads and MB uploaded per frame, and locality
    (relative to ``full``, which comes first)."""
    from lodsprite.gl.context import GLContext
    from lodsprite.metrics import psnr

    lf = Lumigraph(lf_dir)
    obj = read_object(Path(lf_dir))
    w, h = size
    proj = perspective(path.fov_y_deg, w / h, lf.header.near, 4 * lf.header.far)
    centre = np.zeros((h, w), bool)
    centre[h // 4: 3 * h // 4, w // 4: 3 * w // 4] = True
    out = {}
    with GLContext() as gl:
        for k, name in enumerate(TABLE1_METHODS):
            run = MethodRun(gl, lf, size, True, obj, name, {})
            try:
                m = run.method
                m.frame(0, path.viewpoints[0], proj)  # untimed: first nodes resident
                per_cov, per_px, ups, part, loc = [], [], [], [], []
                for i, vp in enumerate(path.viewpoints):
                    f = m.frame(i, vp, proj, count_samples=True)
                    covered = m.output.read_rgba()[..., 3] > 0.5 / 255
                    per_cov.append(m.samples / max(1, covered.sum()))
                    per_px.append(m.samples / (w * h))
                    ups.append(f.extra["uploads"])
                    if name == "progressive":
                        part.append(m.partial)
                    got = m.output.read_rgb8()
                    run.truth.render(proj @ vp.view_matrix(), run.target.fbo)
                    want = run.target.read_color()
                    loc.append(psnr(got[centre], want[centre]) - psnr(got[~centre],
                                                                      want[~centre]))
                node_mb = m.rec.node_bytes / 2 ** 20
                out[name] = {"fill_rate": float(np.mean(per_cov)),
                             "fill_rate_per_screen_pixel": float(np.mean(per_px)),
                             "uploads_per_frame": float(np.mean(ups)),
                             "texture_mb_per_frame": float(np.mean(ups)) * node_mb,
                             "locality_db": float(np.mean(loc))}
                if part:
                    x = float(np.mean(part))
                    out[name].update(partial_x=x, paper_at_x=6 * x * x - 3 * x + 3)
            finally:
                run.release()
            if progress:
                progress(k + 1, len(TABLE1_METHODS))
    base = out["full"]["locality_db"]
    for v in out.values():
        v["locality_db"] -= base
    return out

