"""A scene's description, for messages: :class:`SceneSpec` (a typed msgspec struct).

What a peer sends to name a scene: the terrain layer's spec (``terrain``: a DEM, a
store, ``fractal:N``, ``jacksboro``, resolved by the receiver against its own data
folder), its ``texture``, working ``grid`` (quads a side, a power of two) and vertical
``exaggeration``.  The caps are those of a scene file's ``[terrain]`` section
(:mod:`lodsprite.scene.file`: :data:`~lodsprite.scene.file.MAX_GRID`, exaggeration
``0 < e <= 1000``) and names at most :data:`MAX_NAME` characters: checked by the
decoder, before anything is read or allocated.  :func:`describe` makes one from a
:class:`~lodsprite.scene.model.Scene`; :func:`open_spec` opens one (through
:func:`~lodsprite.scene.model.load_scene`).  The distributed layer's ``load`` message
carries it (``LoadArgs`` extends it with the client's sprite settings).
"""

from __future__ import annotations

from typing import Annotated

from msgspec import Meta, Struct

from lodsprite.errors import InputError
from lodsprite.scene.file import MAX_GRID
from lodsprite.scene.model import Scene, load_scene

#: The longest terrain or texture name a description carries (characters).
MAX_NAME = 256
#: A scene's name on the wire.
Name = Annotated[str, Meta(min_length=1, max_length=MAX_NAME)]


class SceneSpec(Struct, forbid_unknown_fields=True, omit_defaults=True):
    """A scene named on the wire: its terrain layer (module doc).  Without a terrain
    (a crowd, a light field alone) a scene has no description: the distributed layer
    serves terrain keyframes only."""

    terrain: Name = "jacksboro"
    texture: Name = "terrain"
    grid: Annotated[int, Meta(ge=16, le=MAX_GRID)] | None = None
    exaggeration: Annotated[float, Meta(gt=0.0, le=1000.0)] = 1.0

    def __post_init__(self) -> None:
        if self.grid is not None and self.grid & (self.grid - 1):
            raise ValueError(f"grid {self.grid} is not a power of two")


def describe(scene: Scene) -> SceneSpec:
    """The description of ``scene``'s terrain layer: its specs, its working grid (the
    height field's quads a side) and the exaggeration it was loaded with; raises
    :class:`~lodsprite.errors.InputError` for a scene without terrain."""
    hf = scene.hf
    if hf is None or not scene.terrain_spec:
        raise InputError(f"scene {scene.name!r} has no terrain to describe on the wire")
    return SceneSpec(scene.terrain_spec, scene.texture_spec or "terrain", hf.quads,
                     float(hf.meta.get("exaggeration", 1.0)))


def open_spec(spec: SceneSpec, light: bool = False) -> Scene:
    """The scene ``spec`` describes (its terrain loaded and textured; ``light`` as
    :func:`~lodsprite.scene.model.load_scene` takes it)."""
    return load_scene(spec.terrain, spec.texture, spec.grid, spec.exaggeration, light=light)
