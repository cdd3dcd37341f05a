"""``lodsprite crowd``: build the crowd, walk the path, write ``frames.csv`` and
``summary.json`` (Gumbau et al., §5.3)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.manager.core import finer_near, linear
from lodsprite.manager.scene import Crowd, build_crowd, walkthrough
from lodsprite.paths import CameraPath

Progress = Callable[[int, int], None]
SNAPSHOTS = {"linear": linear, "finer-near": finer_near}


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
    """``lodsprite crowd``, a shortcut onto the batch driver
    (:func:`lodsprite.run.run_scene`): walk ``path`` (default: the walkthrough) through
    the crowd of ``cfg`` with the registry's technique ``cfg.mode``; returns the rows, the
    summary and the images of ``keep_frames`` (from the untimed replay); writes
    ``frames.csv`` and ``summary.json`` to ``out_dir`` if given."""
    from lodsprite.driver import Measure
    from lodsprite.run import run_scene
    from lodsprite.scene import Scene

    cfg.validate()
    crowd = make_crowd(cfg)
    path = path or walkthrough(crowd, cfg.frames)
    result = run_scene(
        Scene(objects=crowd, label="crowd"), cfg.mode,
        {"target_fps": cfg.target_fps, "slots": cfg.slots,
         "active": cfg.active, "range_near": cfg.range_near, "range_far": cfg.range_far,
         "dist": SNAPSHOTS[cfg.snapshots]},
        path, cfg.size, None if out_dir is None else Path(out_dir),
        Measure(keep=tuple(keep_frames)), progress=progress,
        summary={"mode": cfg.mode, "objects": len(crowd), "trees": cfg.trees,
                 "mesh": cfg.mesh or "ogre", "slots": cfg.slots, "active": cfg.active,
                 "snapshots": cfg.snapshots, "target_fps": cfg.target_fps,
                 "path": path.name, "size": list(cfg.size)})
    return result.rows, result.summary, result.images
