"""``lodsprite view``: options checked, scene and path loaded, techniques chosen, window run.

Every user error surfaces as a :class:`~lodsprite.errors.InputError` before the window
opens; with no display the error is :class:`~lodsprite.viewer.window.NoDisplayError`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lodsprite import get_path, load_scene, terrain_techniques
from lodsprite.errors import InputError
from lodsprite.technique import TechniqueFactory, stage_scene
from lodsprite.viewer.core import PlayPlan
from lodsprite.viewer.window import WindowOptions, check_display, run_viewer

VIEW_MODES = ("full", "lod", "sprite", "distributed")


@dataclass(frozen=True)
class ViewOptions:
    """What ``lodsprite view`` was asked for (see ``lodsprite view --help``)."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    grid: int | None = None
    mode: str | None = None  # sprite for a terrain, critical for a lumigraph
    lod: int = 16
    epsilon: float = 1.0
    size: tuple[int, int] = (1024, 768)
    fps: float = 60.0
    threaded: bool = True
    play: str | None = None
    frames: int | None = None
    screenshots: Path | None = None
    every: int = 1
    exit: bool = False
    out: Path | None = None
    record: Path | None = None
    server: str | None = None
    fov_y_deg: float = 45.0
    target_fps: float | None = None  # a crowd's LOD feedback target

    @property
    def crowd(self) -> bool:
        """The scene is a crowd (``crowd[:OBJECTS[:TREES]]``)."""
        return self.terrain == "crowd" or self.terrain.startswith("crowd:")

    @property
    def lumigraph(self) -> bool:
        """The scene is a lumigraph folder (``lodsprite lumigraph capture``)."""
        return (Path(self.terrain) / "lumigraph.json").is_file()

    @property
    def modes(self) -> tuple[str, ...]:
        if self.crowd:
            from lodsprite.manager.technique import VIEW_MODES as CROWD_MODES

            return CROWD_MODES
        if self.lumigraph:
            from lodsprite.lumigraph.technique import VIEW_METHODS

            return VIEW_METHODS
        return VIEW_MODES

    @property
    def start_mode(self) -> str:
        if self.mode:
            return self.mode
        return "manager" if self.crowd else ("critical" if self.lumigraph else "sprite")

    def validate(self) -> None:
        if self.start_mode not in self.modes:
            raise InputError(f"unknown mode '{self.start_mode}': use one of "
                             f"{', '.join(self.modes)}")
        if (self.lumigraph or self.crowd) and self.server:
            raise InputError("--server goes with a terrain")
        if self.target_fps is not None and not (self.crowd and self.target_fps > 0):
            raise InputError("--target-fps goes with a crowd and must be > 0")
        if self.mode == "distributed" and not self.server:
            raise InputError("--mode distributed needs --server HOST:PORT")
        if self.every < 1:
            raise InputError(f"--every must be at least 1, got {self.every}")
        if not self.epsilon > 0:
            raise InputError(f"--epsilon must be > 0 pixels, got {self.epsilon}")
        if not (self.fps >= 0):
            raise InputError(f"--fps must be >= 0 (0: no cap), got {self.fps}")
        w, h = self.size
        if not (64 <= w <= 8192 and 64 <= h <= 8192):
            raise InputError(f"window size must be between 64 and 8192 pixels, got {w}x{h}")
        if self.play is None and (self.exit or self.out is not None or self.frames is not None):
            raise InputError("--exit, --out and --frames go with --play PATH")
        if self.record is not None and self.record.suffix.lower() != ".json":
            raise InputError(f"--record writes a JSON path file: name it .json, got "
                             f"'{self.record}'")


def factories(o: ViewOptions) -> dict[str, TechniqueFactory]:
    """The viewer's modes: the terrain techniques, and ``distributed`` with a server."""
    found = terrain_techniques(o.lod, o.epsilon, o.threaded)
    if o.server:
        from lodsprite.distributed.technique import distributed_factory

        found["distributed"] = distributed_factory(o.server, o.lod, o.epsilon)
    return found


def view(o: ViewOptions) -> dict:
    """Run the viewer; returns the summary of the frames shown (empty if none)."""
    o.validate()
    check_display()
    if o.lumigraph:
        return _view_lumigraph(o)
    if o.crowd:
        return _view_crowd(o)
    scene = load_scene(o.terrain, o.texture, o.grid)
    plan, fov = None, o.fov_y_deg
    if o.play is not None:
        path = get_path(o.play, scene.hf, o.frames)
        plan, fov = PlayPlan(path, o.out, o.screenshots, o.every, o.exit), path.fov_y_deg
    return run_viewer(scene, factories(o), o.start_mode, WindowOptions(o.size, fps=o.fps),
                      plan, o.record, fov, o.screenshots or Path("screenshots"))


def _view_lumigraph(o: ViewOptions) -> dict:
    """``lodsprite view LF``: the lumigraph's methods as the viewer's modes; ``--play``
    takes ``arc`` (the default path: an arc, or an orbit for six slabs) or a JSON file,
    in the lumigraph's own coordinates (turned into the viewer's)."""
    from lodsprite.lumigraph import technique as lt
    from lodsprite.lumigraph.run import default_path
    from lodsprite.lumigraph.store import Lumigraph
    from lodsprite.paths import load_path_json

    lf = Lumigraph(o.terrain)  # header checked before the window opens
    plan, fov = None, o.fov_y_deg
    if o.play is not None:
        path = lt.viewer_path(default_path(lf, o.frames or 240) if o.play == "arc"
                              else load_path_json(o.play))
        plan, fov = PlayPlan(path, o.out, o.screenshots, o.every, o.exit), path.fov_y_deg
    return run_viewer(stage_scene(o.terrain), lt.lumigraph_techniques(o.terrain),
                      o.start_mode, WindowOptions(o.size, fps=o.fps), plan, o.record, fov,
                      o.screenshots or Path("screenshots"), lt.lumigraph_controller(o.terrain))


def view_scene(scene, techniques: dict[str, TechniqueFactory], mode: str | None = None,
               size: tuple[int, int] = (1024, 768), fps: float = 60.0,
               path=None, fov_y_deg: float = 45.0) -> dict:
    """Open the viewer on ``scene`` with your own ``techniques`` (factories by mode name;
    keys 1-9 switch between them) starting in ``mode`` (default: the first).  ``path``: a
    :class:`~lodsprite.paths.CameraPath` to play once (then quit) instead of flying.
    Returns the summary of the frames shown.  Raises
    :class:`~lodsprite.viewer.window.NoDisplayError` with no display."""
    if not techniques:
        raise InputError("view_scene needs at least one technique")
    mode = mode if mode is not None else next(iter(techniques))
    plan = PlayPlan(path) if path is not None else None
    fov = path.fov_y_deg if path is not None else fov_y_deg
    return run_viewer(scene, techniques, mode, WindowOptions(tuple(size), fps=fps), plan,
                      None, fov)


def _view_crowd(o: ViewOptions) -> dict:
    """``lodsprite view crowd[:OBJECTS[:TREES]]``: the crowd's modes (manager, independent,
    discrete); ``--play walk`` plays the walkthrough, or a JSON path."""
    from lodsprite.manager.run import CrowdConfig, make_crowd
    from lodsprite.manager.scene import walkthrough
    from lodsprite.manager.technique import crowd_controller, crowd_techniques, parse_crowd
    from lodsprite.paths import load_path_json

    objects, trees = parse_crowd(o.terrain)
    cfg = CrowdConfig(objects=objects, trees=trees, target_fps=o.target_fps)
    cfg.validate()
    crowd = make_crowd(cfg)
    plan, fov = None, 60.0
    if o.play is not None:
        path = (walkthrough(crowd, o.frames or 600) if o.play == "walk"
                else load_path_json(o.play))
        plan, fov = PlayPlan(path, o.out, o.screenshots, o.every, o.exit), path.fov_y_deg
    return run_viewer(stage_scene(o.terrain), crowd_techniques(crowd, o.target_fps),
                      o.start_mode, WindowOptions(o.size, fps=o.fps), plan, o.record, fov,
                      o.screenshots or Path("screenshots"), crowd_controller(crowd))
