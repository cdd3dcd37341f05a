"""``lodsprite render --scene FILE``: a scene file's layers along its path, timed; with
``ground_truth`` every frame replayed untimed against the full-detail scene
(:func:`lodsprite.techniques.layered.reference`).  Writes ``frames.csv`` (the core
columns, ``ms_terrain``, ``ms_objects``, ``ms_lightfields``, ``knob_<layer>`` ...) and
``summary.json`` (the core keys, ``share_<layer>``, the budget's keys)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lodsprite.errors import InputError


def render_scene(scene_file: str | Path, out_dir: Path, size: tuple[int, int] = (512, 512),
                 frames: int | None = None, terrain_mode: str = "adaptive",
                 target_fps: float | None = None, ground_truth: bool = False,
                 flip: bool = False, path: str | None = None, progress=None,
                 **options: Any) -> dict[str, Any]:
    """Run the ``scene`` technique over the world of ``scene_file`` along its ``[view]``
    path (or ``path``) and write the run to ``out_dir``; returns the summary.
    ``target_fps`` runs the budget's scheduler (none without)."""
    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.harness import run_path, write_run
    from lodsprite.scene.world import load_world
    from lodsprite.techniques.layered import reference

    if target_fps is not None and not target_fps > 0:
        raise InputError(f"--target-fps must be > 0, got {target_fps}")
    world = load_world(scene_file)
    cam = world.scene.path(path or world.path, frames)
    schedule = "scheduler" if target_fps is not None else "none"
    with Renderer(world.scene, size, cam.fov_y_deg) as renderer:
        t = techniques.create("scene", renderer, world=world, terrain_mode=terrain_mode,
                              schedule=schedule, target_fps=target_fps, **options)
        ref = None
        try:
            image = None
            if ground_truth:
                image, ref = reference(renderer, world, cam, t.frame_s)
            result = run_path(t, cam, progress=progress, ground_truth=ground_truth,
                              reference=image, flip=flip)
        finally:
            t.release()
            if ref is not None:
                ref.release()
        summary = {**result.summary, "mode": "scene", "scene": str(scene_file),
                   "terrain": world.scene.terrain_spec, "path": path or world.path,
                   "size": list(size), "gl_version": renderer.info.version}
    write_run(Path(out_dir), result, summary)
    return summary
