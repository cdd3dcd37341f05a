"""Scene kinds: which spec opens which scene (:func:`open_scene`, one opener for all).

A kind (:class:`SceneKind`) is a name, a test of the spec (``claims``) and an opener
``(spec, **options) -> Scene`` that builds the data model only (no GL).  The scene
package's own kinds are here: a scene file (``*.toml``, :func:`~lodsprite.scene.world.
load_scene_file`) and, claimed by no other kind, a terrain (a DEM, a store,
``fractal:N``, ``jacksboro``: :func:`~lodsprite.scene.model.load_scene`).  Other
packages register theirs through the entry-point group :data:`ENTRY_POINT_GROUP`
(``lodsprite.scenes``; the built-in crowd and lumigraph kinds too, in ``pyproject.toml``),
each entry point naming a :class:`SceneKind`: no module names another by dotted string,
and an out-of-tree package adds a kind by installing one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

from lodsprite.errors import InputError
from lodsprite.scene.model import Scene, load_scene
from lodsprite.terrain import DEFAULT_EXAGGERATION

ENTRY_POINT_GROUP = "lodsprite.scenes"


@dataclass(frozen=True)
class SceneKind:
    """A kind of scene: ``name``, ``claims(spec) -> bool`` and ``open(spec, **options) ->
    Scene`` (options it does not know it ignores; a bad spec is an
    :class:`~lodsprite.errors.InputError`)."""

    name: str
    claims: Callable[[str], bool]
    open: Callable[..., Scene]


def _open_scene_file(spec: str, root: str | None = None, **_: Any) -> Scene:
    """A scene file's scene (its own ``[terrain]`` values; the command's are ignored);
    ``root``: the folder every file it names must lie in (a server's data folder)."""
    from lodsprite.scene.world import load_scene_file

    return load_scene_file(spec, root)


SCENE_FILE = SceneKind("scene-file", lambda spec: spec.lower().endswith(".toml"),
                       _open_scene_file)


def is_scene_file(spec: str) -> bool:
    """Whether ``spec`` names a scene file (what :data:`SCENE_FILE` claims)."""
    return SCENE_FILE.claims(spec)


def scene_kinds() -> tuple[SceneKind, ...]:
    """Every kind, in the order they are asked: the scene file, then the entry points'
    (by name); a terrain is what none claims.  An entry point that does not load, or names
    no :class:`SceneKind`, is an :class:`~lodsprite.errors.InputError` naming it."""
    found = [SCENE_FILE]
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            kind = ep.load()
        except Exception as exc:  # a broken plugin: one line naming it
            raise InputError(f"scene kind {ep.name!r} ({ep.value}) does not load: "
                             f"{type(exc).__name__}: {exc}") from None
        if not isinstance(kind, SceneKind):
            raise InputError(f"scene kind {ep.name!r} ({ep.value}) is not a SceneKind")
        found.append(kind)
    return tuple(found)


def scene_kind(spec: str) -> str | None:
    """The name of the kind that claims ``spec`` (``scene-file``, ``crowd``,
    ``lumigraph``, a plug-in's), or None for a terrain."""
    for kind in scene_kinds():
        if kind.claims(spec):
            return kind.name
    return None


def open_scene(spec: str, texture: str = "terrain", grid: int | None = None,
               exaggeration: float = DEFAULT_EXAGGERATION, light: bool = False,
               **options: Any) -> Scene:
    """The scene ``spec`` names: a scene file, a kind's spec (``crowd[:OBJECTS[:TREES]]``,
    a lumigraph folder...), or a terrain (DEM, store, ``fractal:N``...; ``texture``,
    ``grid``, ``exaggeration`` and ``light`` apply, see
    :func:`~lodsprite.scene.model.load_scene`).  ``options`` go to the kind's opener."""
    for kind in scene_kinds():
        if kind.claims(spec):
            return kind.open(spec, light=light, **options)
    return load_scene(spec, texture, grid, exaggeration, light=light)
