"""A scene file's technique choice checked against the registry (GL-free): its
``[terrain] mode`` must name a terrain technique and each ``[terrain.options]`` entry an
option that technique declares, its value parsed by that declaration
(:class:`~lodsprite.techniques.options.Option`).  The scene model reads the file and
keeps them raw (it knows no technique); :func:`open_scene` is the scene opener with this
check, what every command, the window, the notebook and the servers open scenes with.
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from lodsprite.errors import InputError, SceneFileError
from lodsprite.techniques.registry import all_options, get, names

if TYPE_CHECKING:
    from lodsprite.scene import Scene

__all__ = ["check_options", "checked", "open_scene"]


def checked(scene: Scene) -> Scene:
    """``scene`` with its scene file's ``[terrain.options]`` parsed by the declarations
    of its ``[terrain] mode`` (:func:`check_options`).  A scene that is not a scene file's
    is returned as it is."""
    if scene.source is None or scene.view is None:  # not a scene file's
        return scene
    label = scene.label or os.fspath(scene.source)
    return replace(scene, terrain_options=check_options(label, scene.terrain_mode,
                                                        scene.terrain_options))


def check_options(label: str, mode: str | None, options: dict[str, Any]) -> dict[str, Any]:
    """A scene file's ``[terrain] mode`` and ``[terrain.options]`` (as read, before
    anything of the scene loads) checked: the mode a terrain technique of the registry,
    each option one it declares (any terrain technique's without a mode), each value
    parsed by that declaration; the parsed options.  Raises
    :class:`~lodsprite.errors.SceneFileError` naming the file (``label``) and the field."""

    def fail(field: str, what: str):
        raise SceneFileError(f"{label}: {field}: {what}")

    modes = names(("terrain",))
    if mode is not None and mode not in modes:
        fail("terrain.mode", f"unknown technique {mode!r}: use one of {', '.join(modes)}")
    declared = ({o.name: o for o in get(mode).options} if mode
                else all_options(("terrain",)))
    parsed: dict[str, Any] = {}
    for name, value in options.items():
        if name not in declared or not declared[name].on_command_line:
            fail(f"terrain.options.{name}", f"{mode or 'no terrain technique'} takes no "
                 "such option")
        try:
            parsed[name] = declared[name].parse(value)
        except InputError as exc:
            fail(f"terrain.options.{name}", str(exc))
    return parsed


def open_scene(spec: str, *args: Any, **options: Any) -> Scene:
    """:func:`lodsprite.scene.open_scene`, a scene file's technique choice checked
    (:func:`checked`)."""
    from lodsprite.scene.kinds import open_scene as open_any

    return checked(open_any(spec, *args, **options))
