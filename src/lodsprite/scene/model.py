"""The scene model: a :class:`Scene` holds typed layers, and how to view them.

Layers (:data:`lodsprite.techniques.LAYERS`): ``terrain`` (a height field in memory, its
colour texture, and the spec it came from, which may name a store of any size),
``objects`` (an object set, :data:`ObjectSet`: a scene file's :class:`~lodsprite.scene.
world.World` or the LODManager's :class:`~lodsprite.manager.scene.Crowd`) and
``lightfield`` (light fields, :class:`LightField`: a lumigraph folder, placed in the
world or on its own).  A scene also says how to look at it: its camera home
(:class:`CameraHome`), the paths it plays by name (:attr:`Scene.path`), a scene file's
``[view]`` section and the technique to start with.  An object set holds no scene: a
world is the object sets' state over time, built from the file beside the scene's other
layers.  This module imports no rendering (nor does any of :mod:`lodsprite.scene`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

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
    from lodsprite.scene.file import ViewSection


class ObjectSet(Protocol):
    """An object set: a scene file's world (:class:`~lodsprite.scene.world.World`: types,
    instances walking on the terrain) or the LODManager's crowd
    (:class:`~lodsprite.manager.scene.Crowd`: LOD models standing on their own ground),
    each a count of instances; what else a layer reads of one it tells apart by its
    class.  A protocol, so the scene model names neither package it comes from."""

    def __len__(self) -> int: ...


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
class LightField:
    """A light field layer: a lumigraph ``source`` folder (as ``lodsprite lumigraph``
    writes), standing at ``position`` (world metres ``x, y``, on the ground) ``height_m``
    tall; ``position`` None: on its own, in the lumigraph's world (a lumigraph folder
    opened as a scene)."""

    source: Path
    position: tuple[float, float] | None = None
    height_m: float | None = None

    @property
    def placed(self) -> bool:
        """Whether it stands in a world (a scene file's ``[[lightfields]]``)."""
        return self.position is not None


@dataclass(frozen=True)
class Scene:
    """Typed layers and how to view them.

    The terrain layer: ``hf``/``texture`` (working height field, metres, and its
    ``(H, W, 3) uint8`` texture; None: no terrain) and ``terrain_spec``/``texture_spec``
    (what they were loaded from: a store's path, for techniques that read the store
    itself).  ``objects``: the object set (:data:`ObjectSet`) or None; ``lightfields``:
    the light fields (:class:`LightField`), none by default.  ``home``: the camera home
    (None: the terrain's default); ``paths``: ``(name, frames) -> CameraPath`` for the
    scene's own path names (None: the terrain's :func:`~lodsprite.paths.get_path`);
    ``view``: a scene file's ``[view]`` section (its default path, size, fov and frame-rate
    target; None: not a scene file's); ``terrain_mode``/``terrain_options``: a scene
    file's ``[terrain] mode`` and ``[terrain.options]``, checked against the technique's
    declarations (None and empty: not given); ``mode``: the technique to start with;
    ``source``: the scene file or folder it was opened from; ``path_name``: the path a
    run plays when none is named (None: a scene file's ``[view]`` path, else the
    terrain's ``chen1999``).
    """

    hf: HeightField | None = None
    texture: np.ndarray | None = None
    terrain_spec: str = ""
    texture_spec: str = ""
    objects: ObjectSet | None = None
    lightfields: tuple[LightField, ...] = ()
    home: CameraHome | None = None
    paths: Callable[[str, int | None], CameraPath] | None = field(default=None, repr=False)
    view: ViewSection | None = None
    terrain_mode: str | None = None
    terrain_options: dict[str, Any] = field(default_factory=dict)
    mode: str = "sprite"
    label: str = ""
    source: Path | None = None
    path_name: str | None = None

    @property
    def layers(self) -> tuple[str, ...]:
        """The layers the scene holds, among ``terrain``, ``objects``, ``lightfield``."""
        return tuple(name for name, have in (("terrain", self.hf is not None),
                                             ("objects", self.objects is not None),
                                             ("lightfield", bool(self.lightfields)))
                     if have)

    @property
    def lightfield(self) -> str | None:
        """The first light field's folder (what a lumigraph technique draws), or None."""
        return str(self.lightfields[0].source) if self.lightfields else None

    @property
    def default_path(self) -> str | None:
        """The path a run plays when none is named: a scene file's ``[view]`` path, or
        the scene's own :attr:`path_name` (None: neither)."""
        return self.path_name if self.view is None else self.view.path

    @property
    def name(self) -> str:
        return self.label or self.terrain_spec or self.lightfield or "scene"

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
    return Scene(hf, scene_texture(terrain, texture, hf) if textured else None, terrain,
                 texture)


#: A terrain store's imagery is draped from its finest level of at most this many texels
#: a side (one texture over the whole extent, mipmapped).
IMAGERY_SIDE = 4096


def store_imagery(terrain: str) -> bool:
    """Whether ``terrain`` names a terrain store that holds imagery (its header read)."""
    from lodsprite.terrain.store import is_store

    if not terrain or not is_store(terrain):
        return False
    from lodsprite.terrain.store_format import open_read_only, read_header

    try:
        return read_header(open_read_only(terrain)).imagery is not None
    except Exception:  # noqa: BLE001 - not a readable store: opening it says why
        return False


def scene_attribution(scene: Scene) -> str:
    """The licence and attribution line of the imagery a scene's terrain drapes ("" for
    none): a terrain store's, kept from ``--attribution`` or its sources' metadata."""
    spec = scene.terrain_spec
    if not store_imagery(spec):
        return ""
    from lodsprite.terrain.store_format import open_read_only, read_header

    try:
        return read_header(open_read_only(spec)).imagery.attribution
    except Exception:  # noqa: BLE001 - unreadable now: the renderers say why
        return ""


def scene_texture(terrain: str, texture: str, hf) -> np.ndarray:
    """The terrain's texture: ``texture`` (:func:`~lodsprite.terrain.textures.
    make_texture`), except on a terrain store tiled with imagery, where the default
    ``terrain`` and ``imagery`` are its imagery draped (:func:`~lodsprite.terrain.
    textures.drape`) and ``imagery+hillshade`` that with a hillshade over it."""
    from lodsprite.terrain.store import TerrainStore
    from lodsprite.terrain.textures import IMAGERY_SPECS, drape

    name = texture.strip().lower() if isinstance(texture, str) else texture
    if name not in ("terrain", *IMAGERY_SPECS) or not store_imagery(terrain):
        return make_texture(texture, hf)
    store = TerrainStore(terrain)
    return drape(store.imagery_texture(IMAGERY_SIDE), hf, name == "imagery+hillshade")
