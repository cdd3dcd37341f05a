"""Built-in models of Scoggins, Machiraju & Moorhead (2000), "Enabling LOD matching".

* §4.2 *sphere snowflakes*: :func:`sphere_family` is the suite of nineteen
  latitude/longitude sphere LODs (the finest with about 394,212 triangles) and
  :func:`sphereflake` the sphere layout of Eric Haines' Standard Procedural
  Database "balls" scene (the sphereflake) whose spheres pick their LOD.
* §4.3 *terrain*: :func:`mountain` cuts a mountain out of a height field by
  region growing from its peak (about 8,538 faces) and simplifies it to seven
  LODs of 1,000..7,000 faces with the quadric-error simplifier.
* :func:`get_model` maps a model spec (``sphere``, ``mountain[:TERRAIN]`` or a
  mesh file path) to its :class:`~lodsprite.profiles.chain.LodChain`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lodsprite.errors import MeshError
from lodsprite.meshes import Mesh, compact_mesh, load_mesh, uv_sphere
from lodsprite.profiles.chain import LodChain, build_chain

SPHERE_RADIUS = 0.5
SPHERE_LEVELS = 19
SPHERE_MAX_FACES = 394_212
MOUNTAIN_FACES = 8538
MOUNTAIN_LOD_FACES = (1000, 2000, 3000, 4000, 5000, 6000, 7000)
BUILTINS = "sphere, mountain, mountain:TERRAIN"


def sphere_bands(levels: int = SPHERE_LEVELS, max_faces: int = SPHERE_MAX_FACES) -> np.ndarray:
    """Band counts ``m`` (``(levels,) int64``, strictly increasing) of :func:`sphere_family`.

    Face counts ``4m(m-1)`` are spaced geometrically from 24 (``m = 3``) to the
    count nearest ``max_faces``.
    """
    if levels < 1:
        raise MeshError(f"sphere family needs at least 1 level, got {levels}")
    if max_faces < 24:
        raise MeshError(f"sphere family needs max_faces >= 24, got {max_faces}")
    m_max = int(round(0.5 * (1.0 + np.sqrt(1.0 + max_faces))))
    m_max = min((m_max - 1, m_max, m_max + 1), key=lambda k: abs(4 * k * (k - 1) - max_faces))
    if levels > m_max - 2:
        raise MeshError(f"cannot make {levels} distinct sphere levels of at most "
                        f"{max_faces} faces (at most {m_max - 2})")
    if levels == 1:
        return np.array([m_max], dtype=np.int64)
    f = 24.0 * (4.0 * m_max * (m_max - 1) / 24.0) ** (np.arange(levels) / (levels - 1))
    m = np.rint(0.5 * (1.0 + np.sqrt(1.0 + f))).astype(np.int64)
    m[0], m[-1] = 3, m_max
    for k in range(1, levels):                                # force strict increase
        m[k] = max(m[k], m[k - 1] + 1)
    for k in range(levels - 2, -1, -1):
        m[k] = min(m[k], m[k + 1] - 1)
    return m


def sphere_family(levels: int = SPHERE_LEVELS, max_faces: int = SPHERE_MAX_FACES) -> LodChain:
    """The §4.2 suite of ``levels`` UV-sphere LODs, radius 0.5 (unit diameter) at the origin.

    Level ``k`` has ``m_k`` latitude bands and ``2 m_k`` longitude segments
    (``4 m_k (m_k - 1)`` faces, see :func:`sphere_bands`): 24 faces up to about
    ``max_faces`` (the default's finest level, ``m = 314``, has 393,128 faces,
    0.3% below the paper's 394,212).  Vertices float32 in object units.
    """
    levels_m = sphere_bands(levels, max_faces)
    meshes = []
    for m in levels_m:
        v, f = uv_sphere(int(m), SPHERE_RADIUS)
        meshes.append(Mesh(v, f, f"sphere@{f.shape[0]}"))
    return LodChain("sphere", tuple(meshes))


def _balls_directions() -> np.ndarray:
    """The 9 unit child directions ``(9, 3) float64`` of SPD balls.c ``create_objset``.

    Six on the equator at azimuths 15° + k·60°, three at elevation
    ``asin(2/sqrt(6))`` ≈ 54.74° at azimuths 45° + k·120°.
    """
    el = np.arcsin(2.0 / np.sqrt(6.0))
    az_eq = np.radians(15.0 + 60.0 * np.arange(6))
    az_up = np.radians(45.0 + 120.0 * np.arange(3))
    eq = np.stack([np.cos(az_eq), np.sin(az_eq), np.zeros(6)], axis=1)
    up = np.stack([np.cos(el) * np.cos(az_up), np.cos(el) * np.sin(az_up),
                   np.full(3, np.sin(el))], axis=1)
    # balls.c order: per 120° set, the upper child then two equator children.
    return np.concatenate([np.stack([up[k], eq[2 * k], eq[2 * k + 1]]) for k in range(3)])


def _rotations_from_z(d: np.ndarray) -> np.ndarray:
    """Rotations ``(K, 3, 3)`` taking +z to unit vectors ``d (K, 3)`` about the axis ``z × d``.

    As balls.c: identity for ``d = +z``, a half turn about y for ``d = -z``.
    """
    k = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)   # z × d, |k| = sin
    c = d[:, 2]
    kx = np.zeros((len(d), 3, 3))
    kx[:, 0, 2], kx[:, 1, 2] = k[:, 1], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    opposite = c < -1.0 + 1e-12
    scale = np.where(opposite, 0.0, 1.0 / np.where(opposite, 1.0, 1.0 + c))
    rot = np.eye(3) + kx + (kx @ kx) * scale[:, None, None]
    rot[opposite] = np.diag([-1.0, 1.0, -1.0])
    return rot


def sphereflake(depth: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Sphere centres ``(K, 3) float64`` and radii ``(K,) float64`` of the SPD sphereflake.

    Eric Haines' Standard Procedural Database ``balls`` scene, unit-diameter
    object units: a root sphere of radius 0.5 at the origin with "up" +z; every
    sphere of generation ``g < depth`` has 9 children of a third its radius
    touching it (centre distance ``r + r/3``): six around its equator at
    azimuths 15° + k·60° and three on its upper side at elevation
    ``asin(2/sqrt(6))`` ≈ 54.74° and azimuths 45° + k·120° (the directions of
    balls.c ``create_objset``).  A child's frame is the parent's rotated by the
    minimal rotation taking +z to the parent→child direction, so its upper side
    points away from the parent.  For a child straight below its parent (from
    depth 2 on) balls.c means a half turn about y; it tests ``direction[Z] <=
    -1`` exactly, so in floating point its own output there depends on
    rounding, while here any direction within 1e-12 of -z takes the half turn.
    Children are 60° or more apart and no two spheres overlap.  Spheres are
    ordered by generation, not depth first as balls.c prints them: the root,
    then its 9 children, then theirs, the children of the ``k``-th sphere of a
    generation being spheres ``9k .. 9k+8`` of the next (see
    :func:`sphereflake_levels`).  ``K = (9**(depth+1) - 1) / 8``: 1, 10, 91, 820.
    """
    if int(depth) != depth or depth < 0 or depth > 7:
        raise MeshError(f"sphereflake depth must be an integer in 0..7, got {depth}")
    dirs9 = _balls_directions()
    centres = [np.zeros((1, 3))]
    radii = [np.array([SPHERE_RADIUS])]
    axes = np.array([[0.0, 0.0, 1.0]])
    for _ in range(int(depth)):
        rot = _rotations_from_z(axes)                           # (K, 3, 3)
        child_dirs = np.einsum("kij,nj->kni", rot, dirs9)       # (K, 9, 3)
        r = radii[-1]
        c = centres[-1][:, None, :] + child_dirs * (r * (4.0 / 3.0))[:, None, None]
        centres.append(c.reshape(-1, 3))
        radii.append(np.repeat(r / 3.0, 9))
        axes = child_dirs.reshape(-1, 3)
    return np.concatenate(centres), np.concatenate(radii)


def sphereflake_levels(depth: int = 2) -> np.ndarray:
    """Generation of each sphere of :func:`sphereflake` ``(K,) int64``: 0 root, 1 its children..."""
    if int(depth) != depth or depth < 0 or depth > 7:
        raise MeshError(f"sphereflake depth must be an integer in 0..7, got {depth}")
    return np.concatenate([np.full(9**g, g, dtype=np.int64) for g in range(int(depth) + 1)])


def peak_region(heights: np.ndarray, target_faces: int = MOUNTAIN_FACES,
                iterations: int = 48) -> tuple[np.ndarray, float]:
    """Grid cells of the mountain around the highest sample of ``heights (rows, cols)``.

    Region growing (``skimage.segmentation.flood`` from the peak, tolerance
    ``t`` metres: the samples connected to the peak that lie at most ``t`` below
    it); a cell belongs to the mountain when all its 4 corners do, and only the
    largest edge-connected piece of cells having the peak as a corner is kept.
    ``t`` is bisected so that the piece has about ``target_faces / 2`` cells
    (two triangles each); the count jumps where the region spills over a
    saddle, so the closest count found is returned, typically within a few
    percent.  Returns ``(cells (rows-1, cols-1) bool, t)``.
    """
    from scipy import ndimage
    from skimage.segmentation import flood

    h = np.asarray(heights, dtype=np.float64)
    seed = np.unravel_index(int(np.argmax(h)), h.shape)
    pr, pc = int(seed[0]), int(seed[1])

    def cells_at(t: float) -> np.ndarray:
        v = flood(h, (pr, pc), tolerance=t)
        cells = v[:-1, :-1] & v[:-1, 1:] & v[1:, :-1] & v[1:, 1:]
        labels, _ = ndimage.label(cells)
        near = labels[max(pr - 1, 0):pr + 1, max(pc - 1, 0):pc + 1]
        ids = np.unique(near[near > 0])
        if ids.size == 0:
            return np.zeros_like(cells)
        sizes = ndimage.sum_labels(np.ones_like(labels), labels, ids)
        return labels == ids[int(np.argmax(sizes))]

    lo, hi = 0.0, float(h.max() - h.min())
    best, best_t = cells_at(hi), hi
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        cells = cells_at(mid)
        n = 2 * int(cells.sum())
        if abs(n - target_faces) < abs(2 * int(best.sum()) - target_faces):
            best, best_t = cells, mid
        if n == target_faces:
            break
        if n < target_faces:
            lo = mid
        else:
            hi = mid
    return best, best_t


def mountain_mesh(terrain: str = "jacksboro", grid: int = 512,
                  full_faces: int = MOUNTAIN_FACES) -> Mesh:
    """The §4.3 mountain of ``terrain`` as a mesh of about ``full_faces`` triangles.

    The height field is loaded with :func:`lodsprite.terrain.load_terrain` at
    ``grid`` quads per side; :func:`peak_region` picks the cells; each cell is
    two triangles, counter-clockwise seen from above (+z normals up).  Vertices
    are metres: x east and y north relative to the centre of the region's
    horizontal bounding box, z the elevation unchanged.  The count is only near
    ``full_faces``: the region grows in jumps where it spills over a saddle
    (jacksboro at grid 512: 7,884 faces for 8,538, the next step is 9,822).
    """
    from lodsprite.terrain import load_terrain

    hf = load_terrain(terrain, grid)
    cells, _ = peak_region(hf.heights, full_faces)
    r, c = np.nonzero(cells)
    cols = hf.cols
    tl, tr = r * cols + c, r * cols + c + 1
    bl, br = tl + cols, tr + cols
    faces = np.concatenate([np.stack([bl, br, tr], 1), np.stack([bl, tr, tl], 1)])
    rr, cc = np.divmod(np.arange(hf.rows * cols), cols)
    x = cc * hf.dx - hf.width / 2.0
    y = hf.depth / 2.0 - rr * hf.dy
    vertices = np.stack([x, y, hf.heights.reshape(-1).astype(np.float64)], axis=1)
    vertices, faces = compact_mesh(vertices, faces)
    centre = 0.5 * (vertices[:, :2].min(axis=0) + vertices[:, :2].max(axis=0))
    vertices[:, :2] -= centre
    return Mesh(vertices, faces, f"mountain:{terrain}")


def mountain(terrain: str = "jacksboro", grid: int = 512, full_faces: int = MOUNTAIN_FACES,
             lod_faces: Sequence[int] = MOUNTAIN_LOD_FACES) -> LodChain:
    """The §4.3 mountain chain: :func:`mountain_mesh` and its quadric-error LODs.

    Levels are simplified to ``lod_faces`` (those below the full count) with
    :func:`~lodsprite.profiles.chain.build_chain`; named ``mountain:TERRAIN``.
    """
    return build_chain(mountain_mesh(terrain, grid, full_faces), face_counts=lod_faces)


def get_model(spec: str, faces: Sequence[int] | None = None,
              ratios: Sequence[float] | None = None) -> LodChain:
    """The LOD chain of a model spec.

    ``sphere`` → :func:`sphere_family`; ``mountain`` / ``mountain:TERRAIN``
    (any terrain spec, e.g. ``jacksboro`` or ``fractal:512:1``) →
    :func:`mountain`, with ``faces`` replacing its LOD face counts if given;
    anything else is a mesh file simplified by
    :func:`~lodsprite.profiles.chain.build_chain` with ``faces`` or ``ratios``.
    Raises :class:`MeshError` for an unknown spec, or ``faces``/``ratios`` given
    where they do not apply (``ratios`` for the mountain, either for the sphere).
    """
    spec = str(spec)
    if spec == "sphere":
        if faces is not None or ratios is not None:
            raise MeshError("the sphere model has fixed levels; face counts and ratios "
                            "apply to mesh files and the mountain")
        return sphere_family()
    if spec == "mountain" or spec.startswith("mountain:"):
        if ratios is not None:
            raise MeshError("the mountain model takes LOD face counts, not ratios")
        terrain = spec.partition(":")[2] or "jacksboro"
        if faces is None:
            return mountain(terrain)
        return mountain(terrain, lod_faces=faces)
    if not Path(spec).exists():
        raise MeshError(f"no such mesh file or built-in model: {spec} (built-ins: {BUILTINS})")
    return build_chain(load_mesh(spec), faces, ratios)
