"""One scene model: a :class:`Scene` holds layers, and techniques draw them.

Layers (:data:`lodsprite.techniques.LAYERS`): ``terrain`` (a height field in memory, its
colour texture, and the spec it came from, which may name a store of any size),
``objects`` (an object set: mesh types and their instances, e.g. the LODManager's crowd)
and ``lightfield`` (a lumigraph folder).  A scene also says how to look at it: its camera
home (:class:`CameraHome`), the paths it plays by name (:attr:`Scene.path`) and the
technique to start with.  The GL surface (:class:`lodsprite.api.Renderer`) knows no scene
kind; the viewer asks the scene, and the registry gives it the techniques that draw the
scene's layers.  (Several layers in one frame is a later step: a scene may hold them all.)

:func:`open_scene` opens a spec of any kind through :data:`SCENE_KINDS`, openers named by
dotted path (this package imports no technique package).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.terrain import (
    DEFAULT_EXAGGERATION,
    DEFAULT_GRID,
    HeightField,
    load_terrain,
    make_texture,
)
from lodsprite.terrain.loaders import STORE_MAX_SIDE
from lodsprite.terrain.storefield import COARSE_SIDE

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.paths import CameraPath


@dataclass(frozen=True)
class CameraHome:
    """Where the camera starts and how it moves: ``home`` viewpoint, orbit ``centre``
    (metres), fly ``speed_mps``, ``ground`` (vectorised ``(x, y) -> z`` the eye stays
    ``clearance_m`` above; None: no ground) and the closest orbit ``min_distance_m``."""

    home: Viewpoint
    centre: np.ndarray
    speed_mps: float
    ground: Callable[[Any, Any], Any] | None = None
    clearance_m: float = 2.0
    min_distance_m: float = 1.0
    fov_y_deg: float | None = None  # the scene's own field of view (None: the viewer's)


@dataclass(frozen=True)
class Scene:
    """Layers and how to view them.

    ``hf``/``texture``: the terrain layer (working height field, metres, and its
    ``(H, W, 3) uint8`` texture; None: no terrain); ``terrain_spec``/``texture_spec``: what
    they were loaded from (a store's path, for techniques that read the store itself);
    ``objects``: an object set (a :class:`~lodsprite.manager.scene.Crowd`) or None;
    ``lightfield``: a lumigraph folder or None; ``home``: the camera home (None: the
    terrain's default); ``paths``: ``(name, frames) -> CameraPath`` for the scene's own path
    names (None: the terrain's :func:`~lodsprite.paths.get_path`); ``mode``: the technique
    to start with.
    """

    hf: HeightField | None = None
    texture: np.ndarray | None = None
    terrain_spec: str = ""
    texture_spec: str = ""
    objects: Any = None
    lightfield: str | None = None
    home: CameraHome | None = None
    paths: Callable[[str, int | None], CameraPath] | None = field(default=None, repr=False)
    mode: str = "sprite"
    label: str = ""

    @property
    def layers(self) -> tuple[str, ...]:
        """The layers the scene holds, among ``terrain``, ``objects``, ``lightfield``."""
        return tuple(name for name, have in (("terrain", self.hf is not None),
                                             ("objects", self.objects is not None),
                                             ("lightfield", self.lightfield is not None))
                     if have)

    @property
    def name(self) -> str:
        return self.label or self.terrain_spec or str(self.lightfield or "scene")

    def camera_home(self) -> CameraHome:
        """The scene's camera home, or the terrain's: south of and above it looking at
        its centre, at ``width / 8`` m/s, its surface as ground."""
        if self.home is not None:
            return self.home
        if self.hf is None:
            raise ValueError("a scene without terrain needs a camera home")
        from lodsprite.camera import look_at

        hf = self.hf
        _, hi = hf.bounds()
        centre = np.array([0.0, 0.0, float(hf.heights.mean())])
        eye = (0.0, -0.9 * hf.depth, float(hi[2]) + 0.5 * hf.width)
        return CameraHome(look_at(eye, centre), centre, hf.width / 8.0, hf.height_at)

    def path(self, spec: str, frames: int | None = None) -> CameraPath:
        """The camera path ``spec`` names for this scene (a built-in name or a JSON file)."""
        if self.paths is not None:
            return self.paths(spec, frames)
        from lodsprite.paths import get_path

        return get_path(spec, self.hf, frames)


#: ``load_scene(light=True)`` on a store: the working grid is resampled from the store's
#: finest level of at most this many samples a side (or the grid's own, if larger): the
#: level LOD-sprite's level-0 reader holds whole anyway (:data:`~lodsprite.terrain.
#: storefield.COARSE_SIDE`).
LIGHT_SIDE = COARSE_SIDE


def load_scene(terrain: str = "jacksboro", texture: str = "terrain", grid: int | None = None,
               exaggeration: float = DEFAULT_EXAGGERATION, light: bool = False,
               textured: bool = True) -> Scene:
    """Load, resample and texture a terrain (raises :class:`~lodsprite.TerrainError`).

    ``light=True`` is for techniques that draw a store itself (the adaptive modes, full
    resolution over level 0): the scene's working grid (``grid + 1`` squared samples,
    for paths, camera, near planes and ground clamps) is resampled from the store's
    finest level of at most :data:`LIGHT_SIDE` a side, not from level 0 up to 4096²
    (issue 22: +411 MB peak and ~8 s of load for a 4k² store).  No effect on other
    terrains.  ``textured=False``: no colour texture (frames shaded from heights)."""
    from lodsprite.terrain.store import is_store

    side = STORE_MAX_SIDE
    if light and is_store(terrain):
        side = max(LIGHT_SIDE, (DEFAULT_GRID if grid is None else grid) + 1)
    hf = load_terrain(terrain, grid=grid, exaggeration=exaggeration, store_side=side)
    return Scene(hf, make_texture(texture, hf) if textured else None, terrain, texture)


def _is_lumigraph(spec: str) -> bool:
    return (Path(spec) / "lumigraph.json").is_file()


def _is_crowd(spec: str) -> bool:
    return spec == "crowd" or spec.startswith("crowd:")


#: Scene kinds other than terrain: (test of the spec, opener ``"module:callable"`` taking
#: ``(spec, **options)``).  A spec no test claims is a terrain (:func:`load_scene`).
def _is_scene_file(spec: str) -> bool:
    return spec.lower().endswith(".toml")


SCENE_KINDS: list[tuple[Callable[[str], bool], str]] = [
    (_is_scene_file, "lodsprite.layered.technique:open_scene"),
    (_is_lumigraph, "lodsprite.lumigraph.technique:open_scene"),
    (_is_crowd, "lodsprite.manager.technique:open_scene"),
]


def open_scene(spec: str, texture: str = "terrain", grid: int | None = None,
               exaggeration: float = DEFAULT_EXAGGERATION, light: bool = False,
               **options: Any) -> Scene:
    """The scene ``spec`` names: a lumigraph folder, ``crowd[:OBJECTS[:TREES]]``, or a
    terrain (DEM, store, ``fractal:N``...; ``texture``, ``grid``, ``exaggeration`` and
    ``light`` apply, see :func:`load_scene`)."""
    for claims, opener in SCENE_KINDS:
        if claims(spec):
            module, _, attr = opener.partition(":")
            return getattr(importlib.import_module(module), attr)(spec, **options)
    return load_scene(spec, texture, grid, exaggeration, light=light)
