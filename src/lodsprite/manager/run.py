"""``lodsprite crowd``: build the crowd, walk the path, write ``frames.csv`` and
``summary.json`` (Gumbau et al., §5.3)."""

from __future__ import annotations

import platform
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.manager.core import finer_near, linear
from lodsprite.manager.scene import Crowd, build_crowd, walkthrough
from lodsprite.paths import CameraPath
from lodsprite.report.io import write_csv, write_json

Progress = Callable[[int, int], None]
SNAPSHOTS = {"linear": linear, "finer-near": finer_near}
FRAME_COLUMNS = ["frame", "ms", "fps", "lod_ms", "extractions", "draw_calls", "triangles",
                 "visible", "exponent", "switches"]


@dataclass(frozen=True)
class CrowdConfig:
    """What ``lodsprite crowd`` runs (see its ``--help``)."""

    objects: int = 3000
    trees: int = 0
    mesh: str | None = None
    mode: str = "manager"
    slots: int = 16
    active: int = 300
    target_fps: float | None = None
    frames: int = 600
    size: tuple[int, int] = (640, 480)
    range_near: float = 5.0
    range_far: float = 150.0
    seed: int = 1
    snapshots: str = "linear"  # D_T's distribution: linear | finer-near (§4.3)

    def validate(self) -> None:
        """Impossible options are an :class:`InputError`, before anything is built."""
        if self.objects < 0 or self.trees < 0:
            raise InputError(f"object counts must be >= 0, got --objects {self.objects} "
                             f"--trees {self.trees}")
        if self.objects + self.trees == 0:
            raise InputError("the crowd is empty: give --objects or --trees")
        if self.slots < 1:
            raise InputError(f"--slots must be at least 1, got {self.slots}")
        if self.active < 1:
            raise InputError(f"--active must be at least 1, got {self.active}")
        if self.target_fps is not None and not self.target_fps > 0:
            raise InputError(f"--target-fps must be > 0, got {self.target_fps}")
        if self.snapshots not in SNAPSHOTS:
            raise InputError(f"--snapshots must be one of {', '.join(SNAPSHOTS)}, got "
                             f"{self.snapshots!r}")
        if self.frames < 2:
            raise InputError(f"--frames must be at least 2, got {self.frames}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be 16..8192 pixels a side, got {w}x{h}")


_MODELS: dict = {}


def crowd_models(mesh: str | None, trees: int):
    """The crowd member (built-in ogre or ``mesh``) and, with trees, the tree; built-ins
    are made once per process."""
    from lodsprite.manager.builtins import mesh_model, ogre, tree

    if mesh is not None:
        member = mesh_model(mesh)
    else:
        member = _MODELS.get("ogre") or _MODELS.setdefault("ogre", ogre())
    t = (_MODELS.get("tree") or _MODELS.setdefault("tree", tree())) if trees else None
    return member, t


def make_crowd(cfg: CrowdConfig) -> Crowd:
    member, t = crowd_models(cfg.mesh, cfg.trees)
    return build_crowd([member], cfg.objects, cfg.trees, t, seed=cfg.seed)


def run_crowd(cfg: CrowdConfig, out_dir: Path | None = None, path: CameraPath | None = None,
              progress: Progress | None = None, keep_frames: tuple[int, ...] = ()
              ) -> tuple[list[dict], dict, dict[int, np.ndarray]]:
    """Walk ``path`` (default: the walkthrough) through the crowd of ``cfg``; returns the
    rows, the summary and the images of ``keep_frames``; writes ``frames.csv`` and
    ``summary.json`` to ``out_dir`` if given."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.target import RenderTarget
    from lodsprite.manager.engine import CrowdEngine

    cfg.validate()
    crowd = make_crowd(cfg)
    path = path or walkthrough(crowd, cfg.frames)
    rows, images = [], {}
    with GLContext() as gl:
        target = RenderTarget(gl, *cfg.size)
        engine = CrowdEngine(gl, crowd, target, cfg.mode, cfg.slots, cfg.active,
                             cfg.target_fps, cfg.range_near, cfg.range_far,
                             SNAPSHOTS[cfg.snapshots], fov_y_deg=path.fov_y_deg)
        try:
            warm = engine.frame(path.viewpoints[0])  # untimed: shaders compiled, first LODs
            gl.finish()
            for i, vp in enumerate(path.viewpoints):
                f = engine.frame(vp)
                rows.append({"frame": i, "ms": f.ms, "fps": 1e3 / f.ms, "lod_ms": f.lod_ms,
                             "extractions": f.extractions, "draw_calls": f.draw_calls,
                             "triangles": f.triangles, "visible": f.visible,
                             "exponent": f.exponent, "switches": f.switches})
                if i in keep_frames:
                    images[i] = target.read_color()
                if progress:
                    progress(i + 1, len(path))
        finally:
            engine.release()
            target.release()
        renderer = gl.info.renderer
    summary = summarise(rows, cfg, path, renderer, len(crowd))
    summary["warmup_extractions"] = warm.extractions
    if out_dir is not None:
        write_csv(Path(out_dir) / "frames.csv", rows, FRAME_COLUMNS)
        write_json(Path(out_dir) / "summary.json", summary)
    return rows, summary, images


def summarise(rows: list[dict], cfg: CrowdConfig, path: CameraPath, renderer: str,
              objects: int) -> dict:
    ms = np.array([r["ms"] for r in rows])
    seconds = ms.sum() / 1e3
    col = {k: np.array([r[k] for r in rows], dtype=np.float64) for k in FRAME_COLUMNS[1:]}
    return {"frames": len(rows), "mode": cfg.mode, "objects": objects, "trees": cfg.trees,
            "mesh": cfg.mesh or "ogre", "slots": cfg.slots, "active": cfg.active,
            "snapshots": cfg.snapshots,
            "target_fps": cfg.target_fps, "path": path.name, "size": list(cfg.size),
            "extractions_total": int(col["extractions"].sum()),
            "fps_mean": float(len(rows) / seconds), "frame_ms_mean": float(ms.mean()),
            "frame_ms_median": float(np.median(ms)),
            "frame_ms_p99": float(np.percentile(ms, 99)),
            "triangles_mean": float(col["triangles"].mean()),
            "draw_calls_mean": float(col["draw_calls"].mean()),
            "lod_cpu_ms_mean": float(col["lod_ms"].mean()),
            "switches_per_s": float(col["switches"].sum() / seconds),
            "exponent_final": float(col["exponent"][-1]),
            "gl_renderer": renderer, "machine": platform.machine()}
