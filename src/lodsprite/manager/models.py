"""Continuous-LOD models with a real extraction cost (Gumbau et al., §5.2), GL-free.

Both models keep one vertex buffer for every LOD and extract a LOD as an index buffer
(index-only LODs, as the paper's LodStrips and LodTrees do, and Unity's Mesh LOD):

* :class:`ProgressiveMesh` - a collapse sequence recorded once with fast-simplification
  (quadric edge collapses down to ``min_fraction`` of the triangles); extracting factor
  ``f`` replays the first collapses with fast-simplification's ``replay_simplification``
  and maps the result back onto the original vertices.
* :class:`LeafCollapseTree` - the foliage analogue of LodTrees: leaves are quads; leaves
  are paired bottom-up by proximity and each collapse replaces two leaves by one at their
  area-weighted centre with their summed area (the vertex buffer holds every leaf of the
  hierarchy); extracting factor ``f`` selects the leaves alive after that many collapses.
  The trunk and branches are kept whole.

``f = 1`` is the full model, ``f = 0`` ``min_fraction`` of its triangles (10 %, as the
paper's ogre and tree); the triangle count falls linearly with ``f``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.errors import InputError

MIN_FRACTION = 0.1


@dataclass
class LodModel:
    """What the renderer needs of a model: ``vertices (V, 3)``, ``normals (V, 3)``,
    ``colors (V, 3)`` in [0, 1] (one vertex buffer), its bounding ``radius`` (metres about
    the origin) and ``extract(f)`` -> ``(T * 3,) uint32`` indices."""

    name: str
    vertices: np.ndarray
    normals: np.ndarray
    colors: np.ndarray

    @property
    def radius(self) -> float:
        return float(np.linalg.norm(self.vertices, axis=1).max())

    def triangles(self, f: float) -> int:
        raise NotImplementedError

    def extract(self, f: float) -> np.ndarray:
        raise NotImplementedError


class ProgressiveMesh(LodModel):
    """A progressive mesh over one shared vertex buffer (see module doc)."""

    def __init__(self, name: str, vertices: np.ndarray, faces: np.ndarray,
                 colors: np.ndarray | None = None, min_fraction: float = MIN_FRACTION) -> None:
        import fast_simplification
        import trimesh

        v = np.ascontiguousarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        if len(f) < 4:
            raise InputError(f"{name}: a progressive mesh needs at least 4 triangles")
        normals = trimesh.Trimesh(v, f, process=False).vertex_normals
        c = np.tile([0.75, 0.7, 0.62], (len(v), 1)) if colors is None else np.asarray(colors)
        super().__init__(name, v, np.asarray(normals), c)
        self.faces = f
        _, _, self.collapses = fast_simplification.simplify(
            v, f, target_reduction=1.0 - min_fraction, return_collapses=True)
        self.full = len(f)
        self.least = max(1, self.full - 2 * len(self.collapses))

    def triangles(self, f: float) -> int:
        f = float(np.clip(f, 0.0, 1.0))
        return int(round(self.least + f * (self.full - self.least)))

    def extract(self, f: float) -> np.ndarray:
        """Replay the collapses that take the mesh to :meth:`triangles` ``(f)`` triangles and
        return its index buffer over the original vertices."""
        import fast_simplification

        k = int(np.clip(round((self.full - self.triangles(f)) / 2), 0, len(self.collapses)))
        if k == 0:
            return self.faces.astype(np.uint32).ravel()
        _, faces, mapping = fast_simplification.replay_simplification(
            self.vertices, self.faces, self.collapses[:k])
        rep = np.empty(int(mapping.max()) + 1, dtype=np.int64)
        rep[mapping[::-1]] = np.arange(len(mapping))[::-1]  # the first original vertex
        return rep[faces].astype(np.uint32).ravel()


class LeafCollapseTree(LodModel):
    """Foliage simplified by leaf collapse, over a kept trunk (see module doc).
    ``leaves (L, 4, 3)`` quad corners, ``leaf_colors (L, 3)``, ``trunk`` a
    ``(vertices, faces, colors)`` triple."""

    def __init__(self, name: str, leaves: np.ndarray, leaf_colors: np.ndarray,
                 trunk: tuple[np.ndarray, np.ndarray, np.ndarray],
                 min_fraction: float = MIN_FRACTION) -> None:
        quads, colors, born, dies = collapse_hierarchy(np.asarray(leaves, np.float64),
                                                      np.asarray(leaf_colors, np.float64))
        tv, tf, tc = (np.asarray(a) for a in trunk)
        n_trunk = len(tv)
        normals_q = _quad_normals(quads)
        verts = np.concatenate([tv, quads.reshape(-1, 3)])
        norms = np.concatenate([_mesh_normals(tv, tf), np.repeat(normals_q, 4, axis=0)])
        cols = np.concatenate([tc, np.repeat(colors, 4, axis=0)])
        super().__init__(name, verts, norms, cols)
        self.trunk = tf.astype(np.uint32).ravel()
        self.born, self.dies = born, dies
        self.n_leaves = len(leaves)
        self.base = n_trunk
        self.full = len(tf) + 2 * self.n_leaves
        least = int(np.ceil(min_fraction * self.full))
        self.least_leaves = max(1, (least - len(tf)) // 2)
        if len(tf) + 2 * self.least_leaves > self.full:
            raise InputError(f"{name}: the trunk alone is over {min_fraction:.0%} of the tree")

    def leaves_at(self, f: float) -> int:
        f = float(np.clip(f, 0.0, 1.0))
        return int(round(self.least_leaves + f * (self.n_leaves - self.least_leaves)))

    def triangles(self, f: float) -> int:
        return len(self.trunk) // 3 + 2 * self.leaves_at(f)

    def extract(self, f: float) -> np.ndarray:
        """The trunk plus the leaves alive after ``n_leaves - leaves_at(f)`` collapses."""
        k = self.n_leaves - self.leaves_at(f)
        alive = np.flatnonzero((self.born <= k) & (self.dies > k))
        quad = self.base + 4 * alive[:, None] + np.array([0, 1, 2, 0, 2, 3])[None, :]
        return np.concatenate([self.trunk, quad.astype(np.uint32).ravel()])

    def leaf_area(self, f: float) -> float:
        """Total area of the leaves drawn at ``f`` (m²)."""
        idx = self.extract(f)[len(self.trunk):].reshape(-1, 6)[:, [0, 1, 2, 5]]
        q = self.vertices[idx]
        return float(_quad_areas(q).sum())


def _quad_areas(q: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]), axis=1)


def _quad_normals(q: np.ndarray) -> np.ndarray:
    n = np.cross(q[:, 1] - q[:, 0], q[:, 3] - q[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _mesh_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    import trimesh

    return np.asarray(trimesh.Trimesh(v, f, process=False).vertex_normals)


def collapse_hierarchy(leaves: np.ndarray, colors: np.ndarray):
    """Pair leaves bottom-up (sorted along a Morton curve, neighbours paired, level by
    level) and merge each pair into one leaf: centre and colour area-weighted, area the
    sum (sides scaled by ``sqrt``), orientation the larger leaf's.  Returns every leaf of
    the hierarchy ``(2L - 1, 4, 3)``, their colours, and the collapse step at which each is
    born (0 for the originals) and dies (``inf`` for the root)."""
    n = len(leaves)
    quads, cols = [leaves], [colors]
    born = [np.zeros(n, np.int64)]
    dies = np.full(2 * n - 1, np.iinfo(np.int64).max, dtype=np.int64)
    level = np.arange(n)
    all_q = leaves.copy()
    all_c = colors.copy()
    step, next_id = 0, n
    while len(level) > 1:
        centres = all_q[level].mean(axis=1)
        order = level[np.argsort(_morton(centres), kind="stable")]
        pairs = order[: len(order) // 2 * 2].reshape(-1, 2)
        # closest pairs collapse first
        gap = np.linalg.norm(all_q[pairs[:, 0]].mean(1) - all_q[pairs[:, 1]].mean(1), axis=1)
        pairs = pairs[np.argsort(gap, kind="stable")]
        merged_q, merged_c = _merge(all_q[pairs[:, 0]], all_q[pairs[:, 1]],
                                    all_c[pairs[:, 0]], all_c[pairs[:, 1]])
        ids = np.arange(next_id, next_id + len(pairs))
        steps = step + 1 + np.arange(len(pairs))
        dies[pairs[:, 0]] = steps
        dies[pairs[:, 1]] = steps
        quads.append(merged_q)
        cols.append(merged_c)
        born.append(steps)
        all_q = np.concatenate([all_q, merged_q])
        all_c = np.concatenate([all_c, merged_c])
        step += len(pairs)
        next_id += len(pairs)
        level = np.concatenate([ids, order[len(order) // 2 * 2:]])
    return all_q, all_c, np.concatenate(born), dies


def _merge(a, b, ca, cb):
    wa, wb = _quad_areas(a)[:, None], _quad_areas(b)[:, None]
    total = wa + wb
    centre = (a.mean(1) * wa + b.mean(1) * wb) / total
    big = np.where((wa >= wb)[:, :, None], a, b)
    big_area = np.maximum(wa, wb)
    scale = np.sqrt(total / big_area)[:, :, None]
    q = centre[:, None, :] + (big - big.mean(1, keepdims=True)) * scale
    return q, (ca * wa + cb * wb) / total


def _morton(p: np.ndarray) -> np.ndarray:
    """Morton (Z-order) keys of points ``(N, 3)``, 10 bits an axis."""
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-12) * 1023).astype(np.int64)
    key = np.zeros(len(p), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            key |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return key
