"""A scene file's scene, and its object sets over time: the :class:`World` (GL-free).

:func:`load_scene_file` turns a scene file (:mod:`lodsprite.scene.file`) into a
:class:`~lodsprite.scene.model.Scene` of every layer it names: it reads and validates the
file, loads the terrain (:func:`lodsprite.scene.load_scene`), checks that every point
and position lies on the terrain, loads the meshes (:mod:`lodsprite.scene.objects`),
places the instances (:mod:`lodsprite.scene.placement`) and places the light fields
(:class:`~lodsprite.scene.model.LightField`).  Every user error is one
:class:`~lodsprite.errors.SceneFileError` line naming the field, raised before anything
is drawn or written.

The scene's object set is a :class:`World`: the types, their instances and the ground
they stand on, nothing else (no scene: the scene holds the world, never the reverse).
:meth:`World.poses` gives every instance's ``x, y, z, yaw`` at a time: walkers
(:mod:`lodsprite.scene.walk`) move, and all stand on the ground.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError, SceneFileError
from lodsprite.scene.file import (
    MAX_INSTANCES,
    ObjectSection,
    SceneFile,
    builtin_meshes,
    read_scene_file,
)
from lodsprite.scene.model import LightField, Scene, load_scene
from lodsprite.scene.objects import Group, ObjectType, builtin_type, load_group
from lodsprite.scene.placement import (
    check_inside,
    expand,
    extent,
    ground,
    group_radius,
    headings,
    read_points,
    scatter,
)
from lodsprite.scene.walk import walk

if TYPE_CHECKING:
    from lodsprite.terrain import HeightField

__all__ = ["Instances", "ObjectType", "World", "load_scene_file", "read_scene_file",
           "summary"]


@dataclass
class Instances:
    """The instances of one type: ``xy (k, 2) float64`` world metres (the terrain's world),
    ``yaw (k,) float64`` radians about ``+z`` (their headings when they walk), ``walk_mps``
    (0: static), the section's ``seed`` and ``area`` ``(x0, y0, x1, y1)`` metres, the
    rectangle its walkers stay in (None: the terrain)."""

    type_index: int
    xy: np.ndarray
    yaw: np.ndarray
    walk_mps: float = 0.0
    seed: int = 0
    area: tuple[float, float, float, float] | None = None

    def __len__(self) -> int:
        return len(self.xy)


@dataclass
class World:
    """A scene file's object sets: ``types`` and ``instances`` (each naming its type by
    index), standing on ``ground`` (the scene's terrain height field, metres).  It holds no
    scene (the scene holds it, as :attr:`Scene.objects <lodsprite.scene.model.Scene>`)."""

    types: list[ObjectType]
    instances: list[Instances]
    ground_field: HeightField

    @property
    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """The terrain's horizontal extent ``lo (2,)``, ``hi (2,)`` in world metres."""
        return extent(self.ground_field)

    @property
    def count(self) -> int:
        """Instances in all."""
        return sum(len(i) for i in self.instances)

    def __len__(self) -> int:
        return self.count

    def ground(self, xy: np.ndarray) -> np.ndarray:
        """Ground heights ``(k,) float64`` metres under ``xy (k, 2)`` world metres."""
        return ground(self.ground_field, xy)

    def type_indices(self) -> np.ndarray:
        """``(count,) intp``: each instance's type (an index into :attr:`types`), in
        :attr:`instances` order."""
        return np.concatenate([np.full(len(i), i.type_index, np.intp) for i in self.instances]
                              or [np.zeros(0, np.intp)])

    def moving(self) -> np.ndarray:
        """``(count,) bool``: which instances walk, in :attr:`instances` order."""
        return np.concatenate([np.full(len(i), i.walk_mps > 0) for i in self.instances]
                              or [np.zeros(0, bool)])

    def poses(self, t: float) -> np.ndarray:
        """``(count, 4) float32`` ``x, y, z, yaw`` (metres, radians) of every instance at
        time ``t`` seconds, in :attr:`instances` order: walkers moved along their headings
        (reflected at the terrain's edge), every instance standing on the ground."""
        if not self.instances:
            return np.zeros((0, 4), np.float32)
        xy0 = np.concatenate([i.xy for i in self.instances])
        yaw0 = np.concatenate([i.yaw for i in self.instances])
        speed = np.concatenate([np.full(len(i), i.walk_mps) for i in self.instances])
        lo, hi = self.walk_bounds()
        xy, yaw = walk(xy0, yaw0, speed, t, lo, hi)
        out = np.empty((len(xy), 4), np.float32)
        out[:, :2] = xy
        out[:, 2] = self.ground(xy)
        out[:, 3] = yaw
        return out

    def walk_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Each instance's walking rectangle ``lo, hi (count, 2)`` (or the terrain's
        ``(2,)`` when no section has an area)."""
        lo, hi = self.extent
        if all(i.area is None for i in self.instances):
            return lo, hi
        boxes = [np.tile(np.r_[lo, hi] if i.area is None else i.area, (len(i), 1))
                 for i in self.instances]
        box = np.concatenate(boxes).astype(np.float64)
        return box[:, :2], box[:, 2:]


def summary(scene: Scene) -> list[str]:
    """One line per layer of a scene file's scene: terrain, objects (types, instances),
    light fields, and the ``[view]`` path."""
    hf = scene.hf
    lo, hi = extent(hf)
    world = scene.objects if isinstance(scene.objects, World) else None
    types = [] if world is None else world.types
    count = 0 if world is None else world.count
    walkers = 0 if world is None else int(world.moving().sum())
    return [f"terrain: {scene.terrain_spec} ({hf.cols}x{hf.rows} samples, "
            f"{hi[0] - lo[0]:g} x {hi[1] - lo[1]:g} m, z {hf.heights.min():.0f}.."
            f"{hf.heights.max():.0f} m)",
            f"objects: {len(types)} types, {count} instances ({walkers} "
            f"walking), {sum(len(t.faces) for t in types):,} triangles in the types",
            _lightfields_line(scene.lightfields),
            f"view: path {scene.default_path}"]


def _lightfields_line(lights: tuple[LightField, ...]) -> str:
    each = "; ".join(f"{lf.source.name} at ({lf.position[0]:g}, {lf.position[1]:g}), "
                     f"{lf.height_m:g} m" for lf in lights if lf.position is not None)
    return f"lightfields: {len(lights)}" + (f" ({each})" if lights else "")


def load_scene_file(path: str | os.PathLike, root: str | os.PathLike | None = None,
                    **scene_options: Any) -> Scene:
    """Read the scene file at ``path`` and build its scene: the terrain, the object set
    (a :class:`World`, empty without ``[[objects]]``), the light fields, the ``[view]``
    section; the ``scene`` technique to start with.

    ``scene_options`` go to :func:`~lodsprite.scene.load_scene` over the file's
    ``[terrain]`` values (``grid``, ``exaggeration``, ``texture``, ``light``,
    ``textured``).  ``root``: every file the scene names must lie inside it
    (:func:`~lodsprite.scene.file.read_scene_file`).  Raises
    :class:`~lodsprite.errors.SceneFileError`.
    """
    label = os.fspath(path)
    sf = read_scene_file(path, root)
    t = sf.terrain
    options = {"texture": t.texture, "grid": t.grid, "exaggeration": t.exaggeration,
               **scene_options}
    try:
        scene = load_scene(t.source, **options)
    except InputError as exc:
        raise SceneFileError(f"{label}: terrain: {exc}") from None
    lo, hi = extent(scene.hf)
    anchors = [_anchors(o, f"{label}: objects[{i}]", lo, hi) for i, o in enumerate(sf.objects)]
    lights = []
    for i, lf in enumerate(sf.lightfields):
        check_inside(np.array([lf.position]), lo, hi, f"{label}: lightfields[{i}].position")
        lights.append(LightField(Path(lf.source), lf.position, lf.height_m))
    _check_path(scene, sf, label)
    types, instances = _place(sf, label, lo, hi, anchors)
    return replace(scene, objects=World(types, instances, scene.hf),
                   lightfields=tuple(lights), view=sf.view, terrain_mode=t.mode,
                   terrain_options=dict(t.options), mode="scene", label=label,
                   source=Path(path))


def _place(sf: SceneFile, label: str, lo: np.ndarray, hi: np.ndarray, anchors: list
           ) -> tuple[list[ObjectType], list[Instances]]:
    """Every section's types and instances.  Sections of the same mesh, height, LOD kind
    and up axis share their types (one mesh, one set of LODs)."""
    types: list[ObjectType] = []
    instances: list[Instances] = []
    loaded: dict[tuple, tuple[Group, int]] = {}
    for i, (o, (xy, yaw, where)) in enumerate(zip(sf.objects, anchors, strict=True)):
        at = f"{label}: objects[{i}]"
        key = (o.mesh, o.height_m, o.lod, o.up)
        if key not in loaded:
            loaded[key] = (_group(o, f"{at}.mesh"), len(types))
            types.extend(loaded[key][0].types)
        group, first = loaded[key]
        a_lo, a_hi = _area(o, lo, hi)
        region = "the terrain" if o.area is None else "its area"
        total = sum(len(n) for n in instances)
        if total + len(group.member_type) * (o.count or len(xy)) > MAX_INSTANCES:
            raise SceneFileError(f"{at}: more than {MAX_INSTANCES} instances in all")
        if o.count is not None:  # scattered here, once: a group's members stay inside
            inset = min(group_radius(group), 0.49 * float(np.min(a_hi - a_lo)))
            xy, yaw = scatter(o.count, o.seed, a_lo, a_hi, inset)
        for k, (mxy, myaw, index) in enumerate(expand(group, xy, yaw)):
            check_inside(mxy, a_lo, a_hi, f"{at}.{'mesh' if o.points is None else 'points'}",
                         None if where is None else [where[a] for a in index], region)
            instances.append(Instances(first + k, mxy, myaw, o.walk_mps, o.seed, o.area))
    return types, instances


def _area(o: ObjectSection, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A section's rectangle ``lo, hi (2,)``: its ``area`` or the terrain's extent."""
    if o.area is None:
        return lo, hi
    return np.array(o.area[:2], np.float64), np.array(o.area[2:], np.float64)


def _anchors(o: ObjectSection, at: str, lo: np.ndarray, hi: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """A section's anchors ``xy (a, 2)``, headings ``(a,)`` and, for a points file, each
    anchor's ``"line N"`` (inside the section's area, itself on the terrain); no count
    nor points: one anchor at the origin; a count: none yet (:func:`_place` scatters)."""
    if o.area is not None:
        check_inside(np.reshape(o.area, (2, 2)), lo, hi, f"{at}.area")
        lo, hi = _area(o, lo, hi)
    if o.count is not None:  # scattered by _place, which knows the group's radius
        return np.zeros((0, 2)), np.zeros(0), None
    if o.points is None:
        return np.zeros((1, 2)), np.zeros(1), ["the origin"]
    xy, yaw, lines = read_points(o.points, f"{at}.points")
    where = [f"line {n}" for n in lines]
    check_inside(xy, lo, hi, f"{at}.points", where,
                 "the terrain" if o.area is None else "its area")
    return xy, np.where(np.isnan(yaw), headings(len(xy), o.seed), yaw), where


def _group(o: ObjectSection, field: str) -> Group:
    if o.mesh in builtin_meshes():
        t = builtin_type(o.mesh, o.height_m, o.lod, o.lod_floor)
        return Group([t], np.zeros(1, np.intp), np.zeros((1, 2)), np.zeros(1))
    group = load_group(o.mesh, o.height_m, o.lod, o.up, field)
    for t in group.types:
        t.lod_floor = o.lod_floor
    return group


def _check_path(scene: Scene, sf: SceneFile, label: str) -> None:
    """The ``[view]`` path must be one the terrain can fly (built cheaply, 2 frames)."""
    try:
        scene.path(sf.view.path, 2)
    except InputError as exc:
        raise SceneFileError(f"{label}: view.path: {exc}") from None
