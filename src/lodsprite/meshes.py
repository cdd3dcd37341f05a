"""Indexed triangle meshes: mesh-file loading, the UV sphere and mesh checks.

Shared by LOD error profiling (:mod:`lodsprite.profiles`), the crowd's mesh types
(:mod:`lodsprite.manager`) and the lumigraph's approximate geometry
(:mod:`lodsprite.lumigraph`), so it sits below all three and imports nothing of
lodsprite but :mod:`lodsprite.errors`.  :class:`Mesh` is their common currency:
vertices ``(N, 3) float32`` in the model's own (object) units and faces
``(F, 3) int32`` indexing them.  :func:`load_mesh` reads OBJ, PLY, OFF, STL and
glTF (GLB/GLTF) files through trimesh; any error a user can cause (missing file,
unknown format, unparsable content, no triangles, non-finite coordinates) is a
:class:`~lodsprite.errors.MeshError` with a one-line message.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.errors import MeshError

if TYPE_CHECKING:
    import trimesh

#: File extensions :func:`load_mesh` accepts (lower case, with the dot).
MESH_EXTENSIONS = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


def check_mesh_arrays(vertices: np.ndarray, faces: np.ndarray,
                      name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert mesh arrays; returns new ``(N,3) float32`` and ``(F,3) int32`` arrays.

    ``vertices`` must be real ``(N, 3)`` and finite, ``faces`` integer ``(F, 3)``
    with ``F >= 1`` and every index in ``[0, N)``.  Raises :class:`MeshError`
    naming ``name`` otherwise.  The results are fresh, C-contiguous copies.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (N, 3), got {v.shape}")
    if not (np.issubdtype(v.dtype, np.integer) or np.issubdtype(v.dtype, np.floating)):
        raise MeshError(f"{name}: vertices must be real numbers, got {v.dtype}")
    v = np.array(v, dtype=np.float32, order="C", copy=True)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"{name}: vertices contain NaN or infinite coordinates")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"{name}: faces must have shape (F, 3), got {f.shape}")
    if f.shape[0] == 0:
        raise MeshError(f"{name} has no triangles")
    if not np.issubdtype(f.dtype, np.integer):
        raise MeshError(f"{name}: face indices must be integers, got {f.dtype}")
    lo, hi = int(f.min()), int(f.max())
    if lo < 0 or hi >= v.shape[0]:
        raise MeshError(f"{name}: face index out of range [0, {v.shape[0]}): "
                        f"min {lo}, max {hi}")
    return v, np.array(f, dtype=np.int32, order="C", copy=True)


def compact_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge identical vertices, drop degenerate faces and unreferenced vertices.

    ``vertices (N, 3)`` (any real dtype, kept) and ``faces (F, 3)`` integer.
    Vertices with bit-identical coordinates are merged (STL files store a
    triangle soup), faces that then repeat a vertex are dropped, and vertices no
    face uses are removed.  Vertex order is kept (first occurrence).  Returns
    ``(vertices (n, 3), faces (m, 3) int64)``; ``m`` may be 0.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if v.shape[0] == 0 or f.shape[0] == 0:
        return v[:0].reshape(0, 3), f[:0]
    # "+ 0.0" turns -0.0 into 0.0 so that both merge.
    _, first, inverse = np.unique(v + 0.0, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first)
    rank = np.zeros(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    v = v[first[order]]
    f = rank[inverse][f]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    used, f_new = np.unique(f, return_inverse=True)
    return v[used], f_new.reshape(-1, 3).astype(np.int64)


def bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Sphere around ``vertices (N, 3)``: centre ``(3,) float64`` and radius (same units).

    The centre is the centre of the axis-aligned bounding box and the radius the
    largest vertex distance from it (not the minimal sphere, but at most
    ``sqrt(3)/2`` of the box diagonal and cheap).
    """
    v = np.asarray(vertices, dtype=np.float64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.sqrt(np.max(np.sum((v - centre) ** 2, axis=1))))
    return centre, radius


def mesh_digest(vertices: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 hex digest of ``(N,3) float32`` vertices and ``(F,3) int32`` faces.

    Hashes the two counts (int64) followed by the raw little-endian bytes, so
    that equal meshes, and only those, share a digest.
    """
    v = np.ascontiguousarray(vertices, dtype="<f4")
    f = np.ascontiguousarray(faces, dtype="<i4")
    h = hashlib.sha256(np.array([v.shape[0], f.shape[0]], dtype="<i8").tobytes())
    h.update(v.tobytes())
    h.update(f.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class Mesh:
    """Indexed triangle mesh: ``vertices (N,3) float32`` object units, ``faces (F,3) int32``.

    Validated on construction (finite vertices, indices in range, at least one
    face; :class:`MeshError` otherwise); the arrays are private read-only copies.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise MeshError(f"mesh name must be a string, got {type(self.name).__name__}")
        v, f = check_mesh_arrays(self.vertices, self.faces, self.name)
        v.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @cached_property
    def _sphere(self) -> tuple[np.ndarray, float]:
        centre, radius = bounding_sphere(self.vertices)
        centre.setflags(write=False)
        return centre, radius

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre ``(3,) float64`` (bounding-box centre) and radius in object units; cached."""
        return self._sphere

    @cached_property
    def digest(self) -> str:
        """SHA-256 hex digest of the vertex and face arrays (see :func:`mesh_digest`)."""
        return mesh_digest(self.vertices, self.faces)

    def to_trimesh(self) -> trimesh.Trimesh:
        """This mesh as an unprocessed :class:`trimesh.Trimesh` (float64 vertices, same faces)."""
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices.astype(np.float64),
                               faces=self.faces.astype(np.int64), process=False)

    def __repr__(self) -> str:
        return f"Mesh({self.name!r}, {self.n_vertices} vertices, {self.n_faces} faces)"


def uv_sphere(m: int, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Latitude/longitude sphere with ``m`` latitude bands and ``2m`` longitude segments.

    Centred at the origin; returns shared vertices ``(2 + 2m(m-1), 3) float64``
    (north pole first, rings north to south, south pole last) and faces
    ``(4m(m-1), 3) int64``, counter-clockwise seen from outside.  ``m >= 2``.
    """
    if m < 2:
        raise MeshError(f"a UV sphere needs at least 2 latitude bands, got {m}")
    n = 2 * m
    theta = np.pi * np.arange(1, m) / m                       # polar angle of rings
    phi = np.pi * np.arange(n) / m                            # azimuth of segments
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack([st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (m - 1, n))],
                    axis=-1).reshape(-1, 3)
    vertices = radius * np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    south = 1 + (m - 1) * n
    j = np.arange(n)
    j1 = (j + 1) % n
    north_cap = np.stack([np.zeros(n, np.int64), 1 + j, 1 + j1], axis=1)
    last = 1 + (m - 2) * n
    south_cap = np.stack([last + j, np.full(n, south), last + j1], axis=1)
    i = np.arange(m - 2)[:, None]
    a = 1 + i * n + j                                         # upper ring, this segment
    b = 1 + i * n + j1                                        # upper ring, next segment
    c, d = a + n, b + n                                       # lower ring
    band = np.stack([np.stack([a, c, d], -1), np.stack([a, d, b], -1)], axis=2)
    faces = np.concatenate([north_cap, band.reshape(-1, 3), south_cap]).astype(np.int64)
    return vertices, faces


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Load a triangle mesh from an OBJ, PLY, OFF, STL, GLB or GLTF file.

    Uses ``trimesh.load(path, force="mesh", process=False)``: scenes with several
    geometries are concatenated (with their transforms applied) and polygons
    are triangulated.  Identical vertices are then merged, degenerate faces and
    unreferenced vertices dropped (:func:`compact_mesh`).  Normals, colours and
    texture coordinates are ignored.  The mesh is named after the file's stem.

    Raises :class:`MeshError` for a missing file, an unsupported extension, a
    file trimesh cannot parse, a mesh without triangles or with non-finite
    coordinates.
    """
    p = Path(path)
    if not p.exists():
        raise MeshError(f"no such mesh file: {p}")
    if not p.is_file():
        raise MeshError(f"mesh path {p} is not a file")
    ext = p.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise MeshError(f"unsupported mesh format {ext or '(none)'} for {p} "
                        f"(supported: {', '.join(MESH_EXTENSIONS)})")
    import trimesh

    try:
        loaded = trimesh.load(str(p), force="mesh", process=False)
        v_attr = getattr(loaded, "vertices", None)
        f_attr = getattr(loaded, "faces", None)
        raw_vertices = np.asarray([] if v_attr is None else v_attr,
                                  dtype=np.float64).reshape(-1, 3)
        raw_faces = np.asarray([] if f_attr is None else f_attr, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # trimesh raises anything from ValueError to KeyError
        raise MeshError(f"could not read mesh file {p}: {_one_line(exc)}") from exc
    if raw_faces.shape[0] == 0:
        raise MeshError(f"mesh file {p} has no triangles")
    if raw_faces.min() < 0 or raw_faces.max() >= raw_vertices.shape[0]:
        raise MeshError(f"mesh file {p} has face indices out of range")
    if not np.all(np.isfinite(raw_vertices[np.unique(raw_faces)])):
        raise MeshError(f"mesh file {p} has NaN or infinite vertex coordinates")
    vertices, faces = compact_mesh(raw_vertices, raw_faces)
    if faces.shape[0] == 0:
        raise MeshError(f"mesh file {p} has only degenerate triangles")
    if not np.all(np.isfinite(vertices.astype(np.float32))):
        raise MeshError(f"mesh file {p} has coordinates too large for float32")
    return Mesh(vertices, faces, p.stem)


def vertex_colors(tm) -> np.ndarray | None:
    """A trimesh's colours per vertex in [0, 1], ``(N, 3)``, or None when it has none."""
    vis = getattr(tm, "visual", None)
    kind = getattr(vis, "kind", None)
    try:
        if kind == "texture":
            vis = vis.to_color()
            kind = "vertex"
        if kind in ("vertex", "face"):
            c = np.asarray(vis.vertex_colors, dtype=np.float64)[:, :3] / 255.0
            if c.shape == (len(tm.vertices), 3) and np.isfinite(c).all():
                return c
    except (ValueError, IndexError, AttributeError):  # a texture trimesh cannot sample
        return None
    return None
