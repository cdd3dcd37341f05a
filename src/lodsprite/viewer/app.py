"""``lodsprite view``: options checked, scene and path loaded, techniques chosen, window run.

The scene (:func:`lodsprite.scene.open_scene`) gives the camera home, its paths and the
mode to start in; the registry (:mod:`lodsprite.techniques`) the techniques that draw its
layers.  Nothing here branches on the kind of scene.

Every user error surfaces as a :class:`~lodsprite.errors.InputError` before the window
opens; with no display the error is :class:`~lodsprite.viewer.window.NoDisplayError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from lodsprite import techniques
from lodsprite.errors import InputError
from lodsprite.scene import Scene
from lodsprite.techniques import TechniqueFactory
from lodsprite.techniques.configs import TechniqueOptions, takes_options
from lodsprite.techniques.scenes import open_scene
from lodsprite.viewer.core import PlayPlan
from lodsprite.viewer.window import WindowOptions, check_display, run_viewer

#: The window size when neither ``--size`` nor a scene file's ``[view]`` gives one.
WINDOW = (1024, 768)


@takes_options
@dataclass(frozen=True)
class ViewOptions(TechniqueOptions):
    """What ``lodsprite view`` was asked for (see ``lodsprite view --help``); the
    techniques' options in ``options`` (name -> value given; also taken as keywords and
    read as attributes, as :class:`~lodsprite.run.RenderConfig`'s)."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    grid: int | None = None
    mode: str | None = None  # default: the scene's (sprite, critical, manager)
    size: tuple[int, int] | None = None  # None: a scene file's [view] size, else WINDOW
    fps: float = 60.0
    threaded: bool = True
    play: str | None = None
    frames: int | None = None
    screenshots: Path | None = None
    every: int = 1
    exit: bool = False
    out: Path | None = None
    record: Path | None = None
    fov_y_deg: float = 45.0
    target_fps: float | None = None  # a crowd's LOD feedback target
    options: dict = field(default_factory=dict)

    def resolved(self) -> ViewOptions:
        """These options with every one left out that has a terrain default filled
        (:func:`lodsprite.techniques.defaults.fill_defaults`); values given are kept.
        A store's ``key_sse`` default makes ``sprite`` (and no ``--mode``) mean
        ``sprite-adaptive``: on a store, LOD-sprite's keyframes are adaptive.  Where
        keyframes are rendered is chosen here too, once (:meth:`_default_keyframes`)."""
        from lodsprite.techniques.defaults import DEFAULTED, fill_defaults, terrain_defaults

        given = {k: self.options.get(k) for k in DEFAULTED}
        keyframes = self.options.get("keyframes", self._default_keyframes())
        out = replace(self, options={
            **self.options, "keyframes": keyframes,
            **fill_defaults(self.terrain, given, worker=keyframes == "worker")})
        store_keys = terrain_defaults(self.terrain)["key_sse"] is not None
        if store_keys and self.mode in (None, "sprite") and "key_sse" in out.options:
            out = replace(out, mode="sprite-adaptive")
        return out

    def _default_keyframes(self) -> str:
        """Where keyframes are rendered unless ``--keyframes`` says: by the worker in
        memory, and over a store with tiles (``--tiles`` > 1), where tiles from the worker
        beat inline tiles in both frame time and error (docs/figures.md,
        keyframes_played.py); inline for a store's whole keyframes, whose lowest error is
        inline's (the worker's spriteframes draw the coarse level, not the store's
        ``--proxy-sse`` proxy).  Tiles stay inline with ``--cache-mb`` (worker tiles
        keep no cache).
        ``--inline-keyframes``: inline."""
        from lodsprite.techniques.defaults import terrain_defaults

        store = terrain_defaults(self.terrain)["key_sse"] is not None
        tiles = (self.options.get("tiles") or 1) > 1
        if tiles and (self.options.get("cache_mb") or 0) > 0:  # worker tiles keep no cache
            return "inline"
        return "worker" if self.threaded and (not store or tiles) else "inline"

    def technique_options(self) -> dict:
        """The options the registry's techniques pick theirs from."""
        self = self.resolved()
        return {**self.options,
                "target_fps": self.target_fps,
                "schedule": "none" if self.target_fps is None else "scheduler"}  # scene

    def validate(self) -> None:
        known = techniques.all_options()
        for name, value in self.options.items():
            known[name].check(value)
        if self.target_fps is not None and not self.target_fps > 0:
            raise InputError("--target-fps must be > 0")
        if self.mode == "distributed" and not self.server:
            raise InputError("--mode distributed needs --server HOST:PORT")
        if self.every < 1:
            raise InputError(f"--every must be at least 1, got {self.every}")
        if not (self.fps >= 0):
            raise InputError(f"--fps must be >= 0 (0: no cap), got {self.fps}")
        w, h = self.size or WINDOW
        if not (64 <= w <= 8192 and 64 <= h <= 8192):
            raise InputError(f"window size must be between 64 and 8192 pixels, got {w}x{h}")
        if self.play is None and (self.exit or self.out is not None or self.frames is not None):
            raise InputError("--exit, --out and --frames go with --play PATH")
        if self.record is not None and self.record.suffix.lower() != ".json":
            raise InputError(f"--record writes a JSON path file: name it .json, got "
                             f"'{self.record}'")


def factories(o: ViewOptions, scene: Scene) -> dict[str, TechniqueFactory]:
    """The viewer's modes: the registry's techniques that draw ``scene``'s layers, with the
    command's options (``distributed`` only with a server)."""
    from lodsprite.scene.world import World

    skip = () if o.server else ("distributed",)
    if isinstance(scene.objects, World):  # a scene file's: the crowd modes draw a crowd
        skip = (*skip, *techniques.names(["objects"]))
    if any(lf.placed for lf in scene.lightfields):  # placed: drawn by the scene technique
        skip = (*skip, *techniques.names(["lightfield"]))
    return techniques.factories(scene.layers, skip, **o.technique_options())


def view(o: ViewOptions) -> dict:
    """Run the viewer; returns the summary of the frames shown (empty if none)."""
    o = o.resolved()
    o.validate()
    # a store's grid from a coarse level: its default modes draw the store itself
    scene = open_scene(o.terrain, o.texture, o.grid, light=True, target_fps=o.target_fps)
    o, view_fov = with_scene_view(o, scene)
    if o.server and "terrain" not in scene.layers:
        raise InputError("--server goes with a terrain")
    if o.target_fps is not None and "objects" not in scene.layers:
        raise InputError("--target-fps goes with a crowd (a scene of objects)")
    modes = factories(o, scene)
    mode = o.mode or scene.mode
    if mode not in modes:
        raise InputError(f"unknown mode '{mode}': use one of {', '.join(modes)}")
    check_display()
    home = scene.camera_home()
    plan, fov = None, view_fov or home.fov_y_deg or o.fov_y_deg
    if o.play is not None:
        path = scene.path(o.play, o.frames)
        if view_fov is not None:
            path = replace(path, fov_y_deg=view_fov)
        plan, fov = PlayPlan(path, o.out, o.screenshots, o.every, o.exit), path.fov_y_deg
    return run_viewer(scene, modes, mode, WindowOptions(o.size, fps=o.fps), plan, o.record,
                      fov, o.screenshots or Path("screenshots"))


def with_scene_view(o: ViewOptions, scene: Scene) -> tuple[ViewOptions, float | None]:
    """``o`` with a scene file's ``[view]`` size and ``target_fps`` where the command gave
    none (the window :data:`WINDOW` when neither does), and its ``fov`` (degrees, None
    when it gives none or ``scene`` is no scene file's), which replaces the path's."""
    v = scene.view
    if v is None:
        return replace(o, size=o.size or WINDOW), None
    target = o.target_fps if o.target_fps is not None else v.target_fps
    return replace(o, size=o.size or v.size_px() or WINDOW, target_fps=target), v.fov


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


