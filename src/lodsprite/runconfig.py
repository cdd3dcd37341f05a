"""What a batch run renders: :class:`RenderConfig` (terrain, path, technique and its
options), and the scene and camera path it opens (:func:`prepare`).

Data and scene preparation only, no timed loop: the batch driver (:mod:`lodsprite.run`)
and the distributed client's runner both start from here, so the distributed layer
imports no batch module.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from lodsprite import vdp
from lodsprite.errors import InputError
from lodsprite.paths import CameraPath, get_path
from lodsprite.scene import Scene, load_scene
from lodsprite.techniques.configs import TechniqueOptions, takes_options
from lodsprite.techniques.terrain import resolve_shading
from lodsprite.terrain import DEFAULT_EXAGGERATION
from lodsprite.terrain.loaders import load_level0
from lodsprite.terrain.lod import level_step
from lodsprite.terrain.store import is_store

__all__ = ["RenderConfig", "field_of_view", "parse_size", "prepare", "render_modes"]


def render_modes() -> tuple[str, ...]:
    """``--mode`` choices: the registry's terrain techniques that ``render`` runs itself
    (:attr:`~lodsprite.techniques.TechniqueSpec.batch`; the distributed client is handed
    on by the command line, sprite-adaptive is ``sprite`` with ``--key-sse``), plug-ins
    included."""
    from lodsprite import techniques

    return tuple(s.name for s in techniques.specs(("terrain",)) if s.batch)


def __getattr__(name: str):
    if name == "MODES":  # the registry's now (plug-ins are discovered when first asked)
        return render_modes()
    raise AttributeError(name)


@takes_options
@dataclass(frozen=True)
class RenderConfig(TechniqueOptions):
    """What to render: terrain, texture and path specs, mode, image size, frames, and the
    technique's options (``options``: name -> value given, each declared once by the
    technique's :class:`~lodsprite.techniques.Option`; also taken as keywords,
    ``RenderConfig(mode="sprite", epsilon=2.0)``, and read as attributes, ``c.epsilon``).
    An option with a terrain-dependent default (``lod``, ``key_sse``, ``tiles``...) left
    out is filled by :meth:`resolved` (:mod:`lodsprite.techniques.defaults`)."""

    terrain: str = "jacksboro"
    texture: str = "terrain"
    path: str = "chen1999"
    mode: str = "full"
    size: tuple[int, int] = (512, 512)
    frames: int | None = None
    grid: int | None = None
    exaggeration: float = DEFAULT_EXAGGERATION
    fov_y_deg: float | None = None  # None: the path's own (45° for the built-in paths)
    save_frames: bool = False
    ground_truth: bool = False
    quality_stride: int = 1
    flip: bool = False        # with ground_truth: FLIP per frame too
    save_every: int = 1       # with save_frames: save every n-th frame of the replay only
    display_fps: float | None = None  # a run played in time: at most this many frames a s
    play: bool = False        # play the path in time (always so with worker keyframes)
    vdp_seconds: float | None = None  # played, ground truth: ColorVideoVDP over this long
    options: dict = field(default_factory=dict)

    def resolved(self, store: bool | None = None) -> RenderConfig:
        """This config with every option left out that has a terrain default filled
        (:func:`lodsprite.techniques.defaults.fill_defaults`: LOD-sprite on a store gets
        the store's, any other mode or terrain the 1999 options; ``store=False``: the
        1999 options whatever the terrain, as the distributed client); values given are
        kept."""
        from lodsprite.techniques.defaults import DEFAULTED, fill_defaults

        given = {k: self.options.get(k) for k in DEFAULTED}
        if self.mode != "sprite":  # only what the mode's technique takes
            from lodsprite import techniques

            try:
                takes = {o.name for o in techniques.get(self.mode).options}
            except InputError:  # not a technique's name: validate says so
                takes = set(given)
            given = {k: v for k, v in given.items() if k in takes or k in self.options}
        if all(v is not None for k, v in given.items() if k not in ("key_sse", "proxy_sse")) \
                and ("key_sse" in self.options or self.mode != "sprite" or store is False):
            return self  # nothing to fill
        if self.mode != "sprite":
            store = False
        filled = fill_defaults(self.terrain, given, store,
                               worker=self.options.get("keyframes") == "worker")
        return replace(self, options={**self.options, **filled})

    @property
    def technique(self) -> str:
        """The registry's name of what this config renders."""
        c = self.resolved()
        return "sprite-adaptive" if c.mode == "sprite" and c.options.get("key_sse") else c.mode

    def technique_options(self) -> dict:
        """The options given (terrain defaults filled)."""
        return dict(self.resolved().options)

    @property
    def played(self) -> bool:
        """Whether the run plays its path in time (:mod:`lodsprite.playback`): asked for
        (``play``), or keyframes from a worker process (``keyframes="worker"``), which
        arrive while the camera moves on."""
        return self.play or self.options.get("keyframes") == "worker"

    def validate(self) -> None:
        """Raise :class:`InputError` for a bad option (checked with the defaults filled):
        each option's value by its declaration (:meth:`Option.check`), then what goes
        with what.  An option given that the technique does not take is refused, never
        ignored."""
        from lodsprite import techniques

        given = set(self.options)
        self = self.resolved()
        modes = render_modes()
        if self.mode not in modes:
            raise InputError(f"unknown mode '{self.mode}': use one of {', '.join(modes)}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise InputError(f"image size must be between 16 and 8192 pixels, got {w}x{h}")
        if self.frames is not None and self.frames < 2:
            raise InputError(f"--frames must be at least 2, got {self.frames}")
        if self.quality_stride < 1:
            raise InputError(f"quality stride must be >= 1, got {self.quality_stride}")
        if self.save_every < 1:
            raise InputError(f"save_every must be >= 1, got {self.save_every}")
        if self.display_fps is not None and not (self.played and self.display_fps > 0):
            raise InputError("--display-fps goes with --play or --keyframes worker and is "
                             "> 0, got "
                             f"{self.display_fps}")
        vdp.check_request(self.vdp_seconds, self.played, self.ground_truth)
        spec, known = techniques.get(self.technique), techniques.all_options()
        takes = {o.name for o in spec.options}
        foreign = sorted(given - takes)
        if foreign:
            flags = ", ".join(known[n].cli if n in known else n for n in foreign)
            verb = "does" if len(foreign) == 1 else "do"
            raise InputError(f"{flags} {verb} not go with --mode {self.mode} (the "
                             f"{spec.name} technique); its options: "
                             f"{', '.join(sorted(known[n].cli for n in takes if n in known))}")
        for name, value in self.options.items():
            mine = [o for o in spec.options if o.name == name]
            (mine[0] if mine else known[name]).check(value)
        worker = self.options.get("keyframes") == "worker"
        if worker and (self.mode != "sprite" or self.options.get("proxy_sse") is not None):
            raise InputError("--keyframes worker goes with --mode sprite and no "
                             "--proxy-sse")
        if "key_sse" in self.options and self.mode != "sprite":
            raise InputError("--key-sse goes with --mode sprite")
        if self.options.get("tiles", 1) > 1 and self.mode != "sprite":
            raise InputError("--tiles goes with --mode sprite")
        if "proxy_sse" in self.options and "key_sse" not in self.options:
            raise InputError("--proxy-sse needs adaptive keyframes (--mode sprite --key-sse "
                             "PX, whose tile caches the proxy shares)")


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


def prepare(config: RenderConfig, light: bool = True) -> tuple[Scene, CameraPath]:
    """Validate the config and load scene and path (all user errors surface here).

    Over a store, the techniques that draw the store itself (their spec's ``light``) get a
    light scene (:func:`~lodsprite.scene.load_scene` ``light=True``, with ``ground_truth``
    too: its reference is level 0, :func:`lodsprite.harness.scene_reference`), and no
    colour texture where frames are shaded from heights.  ``light=False``: the working
    grid whatever the mode (the distributed client, whose server loads the scene so)."""
    from lodsprite import techniques

    config = config.resolved()
    config.validate()
    level0 = None
    store = is_store(config.terrain)
    if config.mode == "full" and store:  # level 0's own samples, whole
        level0 = load_level0(config.terrain, config.exaggeration)  # (refused if too large)
    light = light and store and techniques.get(config.technique).light
    textured = resolve_shading(Scene(terrain_spec=config.terrain), config.shading) == "texture"
    scene = load_scene(config.terrain, config.texture, config.grid, config.exaggeration,
                       light=light, textured=textured or not light)
    if level0 is not None:  # the texture stays the working grid's: the same extent
        scene = replace(scene, hf=level0)
    if config.mode in ("lod", "sprite"):  # the level checked before any GL work
        level_step(scene.hf.quads, config.lod)
    return scene, get_path(config.path, scene.hf, config.frames)


def field_of_view(config: RenderConfig, path: CameraPath) -> float:
    """The vertical field of view (degrees) to render ``path`` with: the config's if set,
    else the path's own (a path file keeps the field of view it was recorded with)."""
    return path.fov_y_deg if config.fov_y_deg is None else config.fov_y_deg
