"""A scene's object types: built-in models, mesh files and glTF groups, normalised.

Every type is a mesh in its own frame (:class:`ObjectType`): ``+z`` up, its base at
``z = 0``, centred on ``x, y = 0``, in metres.  The axis rule: glTF (``.glb``/``.gltf``)
is ``+y`` up by its specification and is turned ``+y -> +z`` (a rotation of +90° about
``x``: ``(x, y, z) -> (x, -z, y)``); every other format is taken as ``+z`` up, as the crowd's
``--mesh`` takes it; a section's ``up = "y" | "z"`` overrides either.

A glTF scene with several nodes (its scene graph, ``trimesh.load(..., force="scene")``)
is a *group*: one type per mesh (and per distinct tilt or scale its nodes give it), with
one member at each node, at the node's transformed position and yaw (:class:`Group`).
The group keeps the file's units (glTF: metres); ``height_m`` scales it uniformly so
that its tallest type is that tall.  Any other file (or a glTF of one node) is one type
scaled to ``height_m``; a built-in keeps its own height unless ``height_m`` is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np

from lodsprite.errors import SceneFileError

#: Colour of a mesh that has none (grey-green, linear 0..1).
DEFAULT_COLOUR = (0.55, 0.6, 0.5)
GLTF = (".glb", ".gltf")
_Y_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # +y up -> +z up


@dataclass
class ObjectType:
    """One mesh type in its own frame: z up, base at z = 0, centred on x, y = 0.

    ``vertices (n, 3) float32`` metres (already scaled so the height is ``height_m``),
    ``faces (m, 3) int32``, ``colours (n, 3) float32`` in 0..1; ``lod`` ``"profile"`` or
    ``"linear"``; ``source`` the mesh file (None for a built-in, whose ``name`` is the
    built-in's); ``model`` the built-in's own LOD model (a
    :class:`~lodsprite.manager.models.LodModel`, scaled) or None; ``lod_floor`` the
    fraction of the triangles its coarsest LOD keeps.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray
    height_m: float
    lod: str = "linear"
    source: Path | None = None
    model: Any = None
    lod_floor: float = 0.1


@dataclass
class Group:
    """The types of one ``[[objects]]`` section and where each stands in the group's frame:
    member ``j`` is a copy of ``types[member_type[j]]`` at ``offsets[j] (2,)`` metres turned
    by ``yaws[j]`` radians (a plain mesh: one member at the origin)."""

    types: list[ObjectType]
    member_type: np.ndarray
    offsets: np.ndarray
    yaws: np.ndarray


def builtin_type(name: str, height_m: float | None, lod: str, lod_floor: float = 0.1
                 ) -> ObjectType:
    """The built-in ``name`` (e.g. ``ogre`` or ``tree``), scaled to ``height_m`` if given,
    its coarsest LOD ``lod_floor`` of its triangles."""
    from lodsprite.scene.file import MESH_GROUP, builtin_meshes

    found = [ep for ep in entry_points(group=MESH_GROUP) if ep.name == name]
    if not found:
        raise SceneFileError(f"no built-in model {name!r} (built-ins: "
                             f"{', '.join(builtin_meshes()) or 'none installed'})")
    model = found[0].load()(min_fraction=lod_floor)
    faces = np.asarray(model.extract(1.0), dtype=np.int64).reshape(-1, 3)
    v = np.asarray(model.vertices, dtype=np.float64)
    used = np.unique(faces)
    lo, hi = v[used].min(0), v[used].max(0)
    native = float(hi[2] - lo[2])
    scale = 1.0 if height_m is None else height_m / native
    model.vertices = (v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]) * scale
    return model_type(name, model, lod, lod_floor)  # the model in the type's frame


def model_type(name: str, model: Any, lod: str, lod_floor: float) -> ObjectType:
    """The type of an LOD ``model`` (a :class:`~lodsprite.manager.models.LodModel`)
    already in a type's frame (base at z = 0): the vertices its finest level uses and
    its faces over them, its height their z-range (metres), the model kept for its
    LODs."""
    faces = np.asarray(model.extract(1.0), dtype=np.int64).reshape(-1, 3)
    used, inverse = np.unique(faces, return_inverse=True)
    v = np.asarray(model.vertices, dtype=np.float64)[used]
    return ObjectType(name, v.astype(np.float32), inverse.reshape(-1, 3).astype(np.int32),
                      np.asarray(model.colors, np.float32)[used],
                      float(v[:, 2].max() - v[:, 2].min()), lod, None, model, lod_floor)


def load_group(path: str, height_m: float | None, lod: str, up: str | None,
               field: str) -> Group:
    """The types and members of a mesh file (see the module doc); errors name ``field``."""
    p = Path(path)
    gltf = p.suffix.lower() in GLTF
    turn = _Y_UP if (up or ("y" if gltf else "z")) == "y" else np.eye(3)
    parts = _gltf_parts(p, field) if gltf else [_whole_mesh(p, field)]
    faces = sum(len(f) for _, _, f, _, _ in parts)
    from lodsprite.scene.file import MAX_MESH_FACES

    if faces > MAX_MESH_FACES:
        raise SceneFileError(f"{field}: {p.name} has {faces} triangles, over {MAX_MESH_FACES}")
    keyed: dict[tuple, int] = {}
    types, member_type, offsets, yaws = [], [], [], []
    for name, transform, v, f, c in parts:
        world = transform.copy()
        world[:3] = turn @ world[:3]
        linear = world[:3, :3]
        yaw = _yaw(linear) if len(parts) > 1 else 0.0    # one mesh keeps its own turn
        placed = v @ linear.T + world[:3, 3]
        local = placed @ _rz(-yaw).T                      # the node's yaw taken out
        lo, hi = local.min(0), local.max(0)
        centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
        key = (name, *np.round(_rz(-yaw) @ linear, 6).ravel())
        if key not in keyed:
            keyed[key] = len(types)
            types.append(ObjectType(f"{p.name}:{name}" if len(parts) > 1 else p.name,
                                    (local - centre).astype(np.float32), f.astype(np.int32),
                                    c, float(hi[2] - lo[2]), lod, p))
        member_type.append(keyed[key])
        offsets.append((_rz(yaw) @ centre)[:2])
        yaws.append(yaw)
    tallest = max(t.height_m for t in types)
    if not tallest > 0:
        raise SceneFileError(f"{field}: {p.name} has no height (flat along z; try up = "
                             f"\"{'z' if (up or 'y') == 'y' else 'y'}\")")
    scale = 1.0 if height_m is None else height_m / tallest
    for t in types:
        t.vertices = (t.vertices * np.float32(scale)).astype(np.float32)
        t.height_m *= scale
    offsets_a = np.asarray(offsets, np.float64).reshape(-1, 2) * scale
    if len(parts) == 1:
        offsets_a[:] = 0.0                                # one mesh: centred on its place
    return Group(types, np.asarray(member_type, np.intp), offsets_a,
                 np.asarray(yaws, np.float64))


def _yaw(linear: np.ndarray) -> float:
    """The turn about +z of a 3x3 transform: the angle of its image of +x in the plane."""
    x, y = linear[0, 0], linear[1, 0]
    return float(np.arctan2(y, x)) if np.hypot(x, y) > 1e-9 else 0.0


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _colours(tm: Any, n: int) -> np.ndarray:
    from lodsprite.meshes import vertex_colors

    c = vertex_colors(tm)
    return (np.tile(DEFAULT_COLOUR, (n, 1)) if c is None else c).astype(np.float32)


def _whole_mesh(p: Path, field: str) -> tuple:
    """One part: the whole file as one mesh (trimesh, ``force="mesh"``), read once."""
    from lodsprite.meshes import MESH_EXTENSIONS

    if p.suffix.lower() not in MESH_EXTENSIONS:
        raise SceneFileError(f"{field}: unsupported mesh format {p.suffix or '(none)'} for "
                             f"{p.name} (supported: {', '.join(MESH_EXTENSIONS)})")
    tm = _trimesh_load(p, field, "mesh")
    v, f = _arrays(tm)
    if len(f) == 0:
        raise SceneFileError(f"{field}: {p.name} has no triangles")
    _check_part(v, f, p, p.stem, field)
    return p.stem, np.eye(4), v, f, _colours(tm, len(v))


def _trimesh_load(p: Path, field: str, force: str) -> Any:
    """``trimesh.load(p, force=force, process=False)``; anything wrong is one line."""
    import trimesh

    try:
        return trimesh.load(str(p), force=force, process=False)
    except Exception as exc:  # trimesh raises anything from ValueError to KeyError
        raise SceneFileError(f"{field}: could not read {p.name}: "
                             f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
                             ) from None


def _arrays(tm: Any) -> tuple[np.ndarray, np.ndarray]:
    """A trimesh geometry's ``vertices (n, 3) float64`` and ``faces (m, 3) int64``."""
    v = np.asarray(getattr(tm, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    f = np.asarray(getattr(tm, "faces", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    return v, f


def _check_part(v: np.ndarray, f: np.ndarray, p: Path, name: str, field: str) -> None:
    if not np.isfinite(v).all() or f.min() < 0 or f.max() >= len(v):
        raise SceneFileError(f"{field}: {p.name}: mesh {name!r} is malformed")


def _gltf_parts(p: Path, field: str) -> list[tuple]:
    """Every node with a mesh: ``(mesh name, 4x4 world transform, vertices, faces,
    colours)``, sorted by node name.  The node count (``MAX_GLTF_NODES``) and the faces
    summed over the nodes (``MAX_MESH_FACES``) are checked before anything is copied."""
    from lodsprite.scene.file import MAX_GLTF_NODES, MAX_MESH_FACES

    scene = _trimesh_load(p, field, "scene")
    nodes = scene.graph.nodes_geometry
    if len(nodes) > MAX_GLTF_NODES:
        raise SceneFileError(f"{field}: {p.name} has {len(nodes)} mesh nodes, over "
                             f"{MAX_GLTF_NODES}")
    parts, faces = [], 0
    for node in sorted(nodes):
        transform, name = scene.graph[node]
        tm = scene.geometry[name]
        v, f = _arrays(tm)
        if len(f) == 0:
            continue  # a point cloud or path: nothing to draw
        faces += len(f)
        if faces > MAX_MESH_FACES:
            raise SceneFileError(f"{field}: {p.name} has over {MAX_MESH_FACES} triangles "
                                 "(its nodes' meshes summed)")
        _check_part(v, f, p, name, field)
        parts.append((name, np.asarray(transform, np.float64), v, f, _colours(tm, len(v))))
    if not parts:
        raise SceneFileError(f"{field}: {p.name} has no triangles")
    return parts
