"""The crowd's built-in models and user meshes (Gumbau et al., §5.3).

* :func:`ogre` - a standing figure of about 2,000 triangles (the paper's Ogre had 1,960):
  body, head with horns, arms and legs, coloured by part; a progressive mesh.
* :func:`tree` - a procedural tree of about 97,000 triangles (the paper's olive tree had
  97,133): a trunk with branches (cylinders) and about 47,000 quad leaves in clusters
  round the branch tips; leaf collapse down to 10 %.
* :func:`mesh_model` - any mesh file trimesh reads, centred on its base, scaled to a
  height, as a progressive mesh (its colours kept when it has them).

Models stand on ``z = 0`` with ``+z`` up, about the origin.
"""

from __future__ import annotations

import numpy as np

from lodsprite.errors import InputError
from lodsprite.manager.models import MIN_FRACTION, LeafCollapseTree, ProgressiveMesh

OGRE_HEIGHT_M = 2.2
TREE_HEIGHT_M = 9.0


def _part(mesh, color, transform=None):
    if transform is not None:
        mesh.apply_transform(transform)
    return mesh.vertices, mesh.faces, np.tile(color, (len(mesh.vertices), 1))


def _merge(parts):
    vs, fs, cs, off = [], [], [], 0
    for v, f, c in parts:
        vs.append(v)
        fs.append(f + off)
        cs.append(c)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(cs)


def ogre(min_fraction: float = MIN_FRACTION) -> ProgressiveMesh:
    """The built-in crowd member (about 2,000 triangles; its coarsest LOD ``min_fraction``
    of them)."""
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    skin, cloth, horn = (0.42, 0.62, 0.3), (0.55, 0.32, 0.2), (0.92, 0.88, 0.75)
    cap = trimesh.creation.capsule
    parts = [
        _part(cap(height=0.7, radius=0.32, count=[14, 10]), cloth,
              translation_matrix([0, 0, 1.15])),                       # body
        _part(trimesh.creation.icosphere(3, radius=0.26), skin,
              translation_matrix([0, 0, 1.86])),                       # head
    ]
    for side in (-1, 1):
        arm = rotation_matrix(side * 0.35, [1, 0, 0])
        parts.append(_part(cap(height=0.62, radius=0.1, count=[10, 8]), skin,
                           translation_matrix([0, side * 0.44, 1.22]) @ arm))
        parts.append(_part(cap(height=0.7, radius=0.13, count=[10, 8]), cloth,
                           translation_matrix([0, side * 0.16, 0.45])))
        parts.append(_part(trimesh.creation.cone(0.06, 0.22, sections=10), horn,
                           translation_matrix([0, side * 0.16, 2.05])
                           @ rotation_matrix(side * 0.5, [1, 0, 0])))
    v, f, c = _merge(parts)
    v[:, 2] -= v[:, 2].min()
    return ProgressiveMesh("ogre", v, f, c, min_fraction)


def tree(leaves: int = 47_000, seed: int = 7, min_fraction: float = MIN_FRACTION
         ) -> LeafCollapseTree:
    """The built-in tree (about 97,000 triangles at full detail; its coarsest LOD keeps
    ``min_fraction`` of the leaves)."""
    rng = np.random.default_rng(seed)
    tv, tf, tips = _trunk(rng)
    per = leaves // len(tips)
    centres = np.repeat(tips, per, axis=0) + rng.normal(0, 0.7, (per * len(tips), 3))
    n = len(centres)
    size = rng.uniform(0.10, 0.16, n)
    a = rng.normal(size=(n, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(a, rng.normal(size=(n, 3)))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    c = np.cross(a, b)
    half = (size / 2)[:, None]
    quads = np.stack([centres - a * half - c * half, centres + a * half - c * half,
                      centres + a * half + c * half, centres - a * half + c * half], axis=1)
    green = np.array([0.22, 0.5, 0.16]) * rng.uniform(0.7, 1.25, (n, 1))
    return LeafCollapseTree("tree", quads, np.clip(green, 0, 1), (tv, tf, np.tile(
        [0.4, 0.28, 0.18], (len(tv), 1))), min_fraction)


def _trunk(rng):
    """Trunk and branches as cylinders; returns vertices, faces and the branch tips."""
    import trimesh

    parts, tips = [], []
    h = TREE_HEIGHT_M * 0.45
    parts.append(_part(trimesh.creation.cylinder(0.25, h, sections=24),
                       (0, 0, 0), trimesh.transformations.translation_matrix([0, 0, h / 2])))
    for k in range(12):
        yaw = 2 * np.pi * k / 12 + rng.uniform(-0.2, 0.2)
        up = rng.uniform(0.5, 1.0)
        d = np.array([np.cos(yaw) * np.cos(up), np.sin(yaw) * np.cos(up), np.sin(up)])
        length = rng.uniform(2.2, 3.2)
        start = np.array([0, 0, h * rng.uniform(0.7, 1.0)])
        seg = trimesh.creation.cylinder(0.08, length, sections=12,
                                        segment=[start, start + d * length])
        parts.append(_part(seg, (0, 0, 0)))
        tips.append(start + d * length)
    v, f, _ = _merge(parts)
    return v, f, np.array(tips)


def mesh_model(path: str, height_m: float = OGRE_HEIGHT_M) -> ProgressiveMesh:
    """A user's mesh (``--mesh FILE``) as a progressive mesh, standing on ``z = 0`` and
    scaled to ``height_m``; an empty, malformed or faceless file is an :class:`InputError`."""
    import trimesh

    from lodsprite.meshes import MeshError, load_mesh, vertex_colors

    try:
        load_mesh(path)  # validation: one clear line for anything wrong
        tm = trimesh.load(str(path), force="mesh", process=False)
    except MeshError as exc:
        raise InputError(str(exc)) from exc
    v = np.asarray(tm.vertices, dtype=np.float64)
    f = np.asarray(tm.faces, dtype=np.int64)
    colors = vertex_colors(tm)
    lo, hi = v.min(0), v.max(0)
    extent = float((hi - lo).max())
    if not extent > 0:
        raise InputError(f"mesh file {path} has no extent")
    v = (v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]) * (height_m / extent)
    return ProgressiveMesh(str(path), v, f, colors)
