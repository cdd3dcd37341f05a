"""Level-of-detail chains by quadric-error simplification, and their geometric error.

Scoggins, Machiraju & Moorhead (2000), "Enabling LOD matching", §4.2–4.3 build
their LOD models with Garland's QSlim (Garland & Heckbert 1997, quadric error
metrics).  Here the simplifier is ``fast-simplification`` (a vectorised wrapper
of Sp4cerat's Fast-Quadric-Mesh-Simplification, the same Garland–Heckbert
quadrics with iterative edge collapse) because it is maintained, ships binary
wheels for Linux, macOS and Windows, takes and returns plain numpy arrays,
targets a face count or a reduction ratio, and is several times faster than the
alternatives on meshes of 100k+ faces (its authors report 4-5x over VTK's
``vtkQuadricDecimation`` and about 4x over MeshLab).  Unlike QSlim it collapses
edges under a rising error threshold instead of a strict priority queue, which
trades a little quality for that speed.  It hits a face-count target exactly on
closed meshes.  It keeps its state in module globals, so it must not be called
from several threads at once.

A :class:`LodChain` orders its levels coarsest first; the last level is always
the full-resolution model.  :func:`geometric_errors` measures each level's
approximate symmetric Hausdorff distance to the full model, for a geometric
screen-space-error LOD selection next to the paper's image-based profiles.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lodsprite.errors import MeshError
from lodsprite.meshes import Mesh, compact_mesh

#: Default reduction ratios of :func:`build_chain` (fraction of the full face count).
DEFAULT_RATIOS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


def simplify(vertices: np.ndarray, faces: np.ndarray, target_faces: int,
             preserve_border: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Quadric-error simplification of ``vertices (N,3)``, ``faces (F,3)`` to ``target_faces``.

    Returns ``(vertices (n,3) float32, faces (m,3) int32)`` in the input's units,
    without unreferenced or duplicate vertices; ``m`` is ``target_faces`` or
    within a face or two of it.  ``target_faces >= F`` returns a copy of the
    input; ``target_faces < 1`` raises :class:`MeshError`.

    On open meshes (terrain pieces) the quadrics alone let the border erode
    inwards.  With ``preserve_border`` the border vertices are first kept fixed
    (the role of QSlim's boundary constraint planes); if the target cannot be
    reached that way (a long border leaves too many fixed vertices), a second
    pass without that constraint finishes the reduction.  Closed meshes are
    unaffected.
    """
    import fast_simplification

    # Fresh writeable copies: the extension refuses read-only arrays (Mesh's are).
    v = np.array(vertices, dtype=np.float64, order="C", copy=True)
    f = np.array(faces, dtype=np.int64, order="C", copy=True)
    target = int(target_faces)
    if target < 1:
        raise MeshError(f"target face count must be at least 1, got {target_faces}")
    if target >= f.shape[0]:
        return v.astype(np.float32), f.astype(np.int32)
    points, triangles = fast_simplification.simplify(v, f, target_count=target,
                                                     preserve_border=bool(preserve_border))
    if preserve_border and triangles.shape[0] > target:
        points, triangles = fast_simplification.simplify(
            np.array(points, dtype=np.float64), np.array(triangles, dtype=np.int64),
            target_count=target)
    points, triangles = compact_mesh(np.asarray(points, dtype=np.float64), triangles)
    return points.astype(np.float32), triangles.astype(np.int32)


@dataclass(frozen=True, eq=False)
class LodChain:
    """LOD models of one object: ``levels`` coarsest first, the last the full model.

    Every level is a :class:`Mesh` in the same object units; face counts must
    increase strictly along the chain (:class:`MeshError` otherwise).
    """

    name: str
    levels: tuple[Mesh, ...]

    def __post_init__(self) -> None:
        levels = tuple(self.levels)
        if not levels:
            raise MeshError(f"LOD chain {self.name} has no levels")
        if not all(isinstance(m, Mesh) for m in levels):
            raise MeshError(f"LOD chain {self.name}: every level must be a Mesh")
        counts = [m.n_faces for m in levels]
        if any(b <= a for a, b in zip(counts, counts[1:], strict=False)):
            raise MeshError(f"LOD chain {self.name}: face counts must increase strictly "
                            f"(coarsest first), got {counts}")
        object.__setattr__(self, "levels", levels)

    @property
    def faces(self) -> list[int]:
        """Face count of each level, coarsest first."""
        return [m.n_faces for m in self.levels]

    @property
    def full(self) -> Mesh:
        """The full-resolution model (the last level)."""
        return self.levels[-1]

    @property
    def digests(self) -> list[str]:
        """SHA-256 digest of each level (see :attr:`Mesh.digest`)."""
        return [m.digest for m in self.levels]

    def __len__(self) -> int:
        return len(self.levels)

    def __repr__(self) -> str:
        return f"LodChain({self.name!r}, faces={self.faces})"


def _targets(n_full: int, face_counts: Sequence[int] | None,
             ratios: Sequence[float] | None) -> list[int]:
    """Sorted distinct target face counts strictly below ``n_full``."""
    if face_counts is not None and ratios is not None:
        raise MeshError("give either face counts or ratios for the LOD chain, not both")
    if face_counts is not None:
        counts = [int(c) for c in face_counts]
        bad = [c for c in counts if c < 1]
        if bad:
            raise MeshError(f"LOD face counts must be positive, got {bad[0]}")
    else:
        rs = [float(r) for r in (DEFAULT_RATIOS if ratios is None else ratios)]
        bad_r = [r for r in rs if not 0.0 < r < 1.0]
        if bad_r:
            raise MeshError(f"LOD ratios must lie in (0, 1), got {bad_r[0]}")
        counts = [max(1, int(round(r * n_full))) for r in rs]
    return sorted({c for c in counts if c < n_full})


def build_chain(mesh: Mesh, face_counts: Sequence[int] | None = None,
                ratios: Sequence[float] | None = None) -> LodChain:
    """Simplify ``mesh`` to a chain of LODs, coarsest first, ``mesh`` itself last.

    Give at most one of ``face_counts`` (target face counts; those not below the
    full count are ignored) and ``ratios`` (fractions of the full face count in
    ``(0, 1)``); with neither, :data:`DEFAULT_RATIOS` are used.  Each level is
    simplified from the full model; a level whose face count does not exceed the
    previous one's (duplicate after simplification) is dropped.  The chain and
    its levels are named ``mesh.name``, levels ``NAME@FACES``.
    """
    n_full = mesh.n_faces
    levels: list[Mesh] = []
    for target in _targets(n_full, face_counts, ratios):
        v, f = simplify(mesh.vertices, mesh.faces, target)
        if f.shape[0] == 0 or f.shape[0] >= n_full:
            continue
        if levels and f.shape[0] <= levels[-1].n_faces:
            continue
        levels.append(Mesh(v, f, f"{mesh.name}@{f.shape[0]}"))
    levels.append(mesh)
    return LodChain(mesh.name, tuple(levels))


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _segment_d2(e: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Squared distance of points ``a + w`` to segments ``a .. a + e`` (component-major)."""
    ee = _dot(e, e)
    t = np.clip(_dot(w, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
    d = w - t * e
    return _dot(d, d)


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray,
                            c: np.ndarray) -> np.ndarray:
    """Euclidean distance ``(M,) float64`` from points ``p (M,3)`` to triangles ``a, b, c (M,3)``.

    Pairwise (row ``i`` of each); the plane distance when ``p``'s projection
    falls inside the triangle, else the distance to the nearest edge.
    Degenerate triangles reduce to their edges.  Units of the input.
    """
    P, A, B, C = (np.asarray(x, dtype=np.float64).T for x in (p, a, b, c))  # (3, M) views
    ab, bc, ca = B - A, C - B, A - C
    ap, bp, cp = P - A, P - B, P - C
    n = _cross(ab, bc)
    nn = _dot(n, n)
    inside = ((nn > 0) & (_dot(_cross(ab, ap), n) >= 0) & (_dot(_cross(bc, bp), n) >= 0)
              & (_dot(_cross(ca, cp), n) >= 0))
    edge = np.minimum(np.minimum(_segment_d2(ab, ap), _segment_d2(bc, bp)),
                      _segment_d2(ca, cp))
    plane = _dot(ap, n) ** 2 / np.where(nn > 0, nn, 1.0)
    return np.sqrt(np.where(inside, plane, edge))


class _TriangleIndex:
    """Triangles ``(F, 3, 3) float64`` with a ``cKDTree`` of their centroids.

    ``r_max`` is the largest centroid-to-vertex distance: a triangle whose
    centroid is ``s`` away from a point is at least ``s - r_max`` away.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        self.tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
        centroids = self.tri.mean(axis=1)
        self.r_max = float(np.sqrt(((self.tri - centroids[:, None, :]) ** 2).sum(axis=2).max()))
        self.tree = cKDTree(centroids)

    def distances(self, p: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Distances of points ``p (M,3)`` to triangles ``cand (M,)`` → ``(M,) float64``."""
        t = self.tri[cand]
        return point_triangle_distance(p, t[:, 0], t[:, 1], t[:, 2])

    def bounds(self, p: np.ndarray, k: int, chunk: int = 8192) -> tuple[np.ndarray, np.ndarray]:
        """Upper and lower bounds ``(P,)`` of each point's distance, from ``k`` candidates."""
        k = int(max(1, min(k, self.tri.shape[0])))
        upper = np.zeros(len(p))
        lower = np.zeros(len(p))
        for start in range(0, len(p), chunk):
            q = p[start:start + chunk]
            dk, idx = self.tree.query(q, k=k, workers=-1)
            dk, idx = np.asarray(dk).reshape(len(q), k), np.asarray(idx).reshape(len(q), k)
            d = self.distances(np.repeat(q, k, axis=0), idx.reshape(-1)).reshape(len(q), k)
            upper[start:start + chunk] = d.min(axis=1)
            if k == self.tri.shape[0]:                  # every triangle was a candidate
                lower[start:start + chunk] = upper[start:start + chunk]
            else:
                lower[start:start + chunk] = np.clip(dk[:, -1] - self.r_max, 0.0,
                                                     upper[start:start + chunk])
        return upper, lower

    def exact(self, p: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Exact distances of ``p (M,3)`` given upper bounds ``upper (M,)``."""
        balls = self.tree.query_ball_point(p, upper * (1 + 1e-9) + self.r_max + 1e-12,
                                           workers=-1)
        sizes = np.array([len(b) for b in balls], dtype=np.int64)
        owner = np.repeat(np.arange(len(p)), sizes)
        cand = np.concatenate([np.asarray(b, dtype=np.int64) for b in balls])
        out = np.array(upper, dtype=np.float64)
        np.minimum.at(out, owner, self.distances(p[owner], cand))
        return out


def surface_distances(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                      k: int = 8) -> np.ndarray:
    """Distance from each of ``points (P,3)`` to the triangle mesh ``vertices``, ``faces``.

    The exact point-triangle distance (:func:`point_triangle_distance`) to the
    ``k`` triangles whose centroids are nearest (scipy ``cKDTree``), minimised:
    an upper bound that exceeds the true distance by at most the largest
    centroid-to-vertex distance of the mesh (thin slivers such as a UV sphere's
    polar triangles are where it can).  Returns ``(P,) float64`` in mesh units.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return _TriangleIndex(vertices, faces).bounds(p, k)[0]


def max_surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                         k: int = 8, chunk: int = 64) -> float:
    """Exact ``max_i dist(points[i], mesh)`` for ``points (P,3)`` and a triangle mesh.

    Bounds every point's distance from its ``k`` nearest-centroid triangles
    (see :func:`surface_distances`; a triangle whose centroid is ``s`` away is
    at least ``s - R_max`` away), then computes exact distances (all triangles
    with centroids within ``upper + R_max``) only for points whose upper bound
    beats the best lower bound, largest first, in chunks of ``chunk`` points,
    pruning as the maximum rises.  Units of the mesh; 0.0 for no points.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return _max_distance(_TriangleIndex(vertices, faces), p, k, chunk)


def _max_distance(index: _TriangleIndex, p: np.ndarray, k: int = 8, chunk: int = 64) -> float:
    if len(p) == 0:
        return 0.0
    upper, lower = index.bounds(p, k)
    best = float(lower.max())
    order = np.argsort(-upper)
    order = order[upper[order] > best]
    while order.size:
        head, order = order[:chunk], order[chunk:]
        best = max(best, float(index.exact(p[head], upper[head]).max()))
        order = order[upper[order] > best]
    return best


def geometric_errors(chain: LodChain, samples: int = 20000, seed: int = 0) -> np.ndarray:
    """Approximate symmetric Hausdorff distance of each level to the full model.

    For each level, ``samples`` points are drawn uniformly by area on it and on
    the full model (``trimesh.sample.sample_surface`` seeded from ``seed``); the
    exact distance of each sample to the *other* surface is found by
    :func:`max_surface_distance` (candidate triangles from a centroid
    ``cKDTree``, then exact point-triangle distances), and the larger of the
    two maxima is the error.  Only the sampling is approximate: the maximum is
    taken over samples about ``sqrt(area / samples)`` apart, so a narrow
    feature between samples can be missed and the value may underestimate the
    true Hausdorff distance (for smooth differences, by a small fraction).  Returns
    ``(L,) float64`` in object units, coarsest level first; the last (full)
    entry is exactly 0.
    """
    import trimesh

    if samples < 1:
        raise MeshError(f"samples must be at least 1, got {samples}")
    full = chain.full.to_trimesh()
    full_index = _TriangleIndex(full.vertices, full.faces)
    rng = np.random.default_rng(seed)
    full_pts, _ = trimesh.sample.sample_surface(full, samples, seed=rng)
    errors = np.zeros(len(chain), dtype=np.float64)
    for i, level in enumerate(chain.levels[:-1]):
        lod = level.to_trimesh()
        lod_pts, _ = trimesh.sample.sample_surface(lod, samples, seed=rng)
        errors[i] = max(_max_distance(full_index, np.asarray(lod_pts, dtype=np.float64)),
                        max_surface_distance(full_pts, lod.vertices, lod.faces))
    return errors
