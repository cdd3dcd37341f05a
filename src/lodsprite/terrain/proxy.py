"""The proxy mesh of LOD-sprite: a coarse level plus ribbons along the terrain's border.

Chen, Swan & Kaufman (1999, §3.1) texture the coarse level with the keyframe.  The
coarse level's border is a straight line between its vertices, while the
full-resolution border zig-zags above and below it.  Seen obliquely, much of the
terrain's outline is its border (the near edge against the sky below, the far
edge against the sky above), so wherever the two differ a coarse image shows sky
where the full image shows terrain, or the reverse.  On the real Jacksboro DEM
(512², 16² level, the chen1999 path) 83 % of the LOD-sprite image's sky/terrain
mismatch lay on border squares.

A ribbon closes that gap.  For every kept full-resolution border sample ``i`` it
has one vertex on the coarse border line and one on the full profile, both in the
border's vertical plane; consecutive samples make a quad.  Textured from a
keyframe, a ribbon carries the keyframe's picture of the real outline: terrain
where the full profile stands out beyond the coarse line, the keyframe's sky where
the coarse surface stands out beyond the full one.  The profile is first simplified
(Douglas-Peucker, as scikit-image's ``approximate_polygon``) within each coarse segment,
so every coarse vertex stays and the ribbon meets the coarse surface exactly.

All arrays are world metres (x east, y north, z up) and terrain texture
coordinates ``(col, row) / (N)``, matching the GPU terrain shaders.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.errors import InputError
from lodsprite.terrain.heightfield import HeightField
from lodsprite.terrain.lod import level_indices, level_step

DEFAULT_TOLERANCE = 0.25  # Douglas-Peucker tolerance, in grid spacings


@dataclass(frozen=True)
class ProxyMesh:
    """``positions (V, 3) float32`` (metres), ``uv (V, 2) float32`` terrain texture
    coordinates and ``tris (T, 3) uint32`` vertex indices.  ``level_triangles`` of the
    triangles are the coarse level's; the rest are border ribbon (draw without culling)."""

    level_quads: int
    positions: np.ndarray
    uv: np.ndarray
    tris: np.ndarray
    level_triangles: int

    @property
    def triangles(self) -> int:
        return len(self.tris)


def _uv(hf: HeightField, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    return np.stack([cols / (hf.cols - 1), rows / (hf.rows - 1)], axis=-1)


def level_mesh(hf: HeightField, level_quads: int) -> ProxyMesh:
    """The uniform level ``level_quads`` as one mesh, split like the renderer's grid
    (``(nw, sw, se)`` and ``(nw, se, ne)``, counter-clockwise from above)."""
    idx = level_indices(hf, level_quads)
    rows, cols = np.meshgrid(idx, idx, indexing="ij")
    pos = hf.points(rows, cols).reshape(-1, 3)
    n = level_quads + 1
    v = np.arange(n * n, dtype=np.uint32).reshape(n, n)
    nw, ne, sw, se = v[:-1, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, :-1].ravel(), v[1:, 1:].ravel()
    tris = np.concatenate([np.stack([nw, sw, se], 1), np.stack([nw, se, ne], 1)])
    return ProxyMesh(level_quads, pos.astype(np.float32),
                     _uv(hf, rows, cols).reshape(-1, 2).astype(np.float32), tris, len(tris))


def _edges(hf: HeightField) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(rows, cols, spacing in metres) of the north, south, west and east borders."""
    i = np.arange(hf.quads + 1)
    zero, last = np.zeros_like(i), np.full_like(i, hf.quads)
    return [(zero, i, hf.dx), (last, i, hf.dx), (i, zero, hf.dy), (i, last, hf.dy)]


def _kept_samples(full: np.ndarray, step: int, spacing: float, tol: float) -> np.ndarray:
    """Indices of a border profile ``full (m,)`` (metres) kept by Douglas-Peucker
    simplification of each coarse segment on its own, so every coarse vertex is kept."""
    if tol == 0:
        return np.arange(len(full))
    keep = [np.arange(0, len(full), step)]
    for a in range(0, len(full) - 1, step):
        pts = np.stack([np.arange(step + 1) * spacing, full[a:a + step + 1]], axis=1)
        keep.append(a + douglas_peucker(pts, tol))
    return np.unique(np.concatenate(keep))


def border_ribbon(hf: HeightField, level_quads: int,
                  tolerance_m: float | None = None) -> ProxyMesh:
    """Ribbons joining level ``level_quads``'s border lines to the full-resolution border
    profile, simplified to within ``tolerance_m`` metres (default a quarter of the grid
    spacing; 0 keeps every sample).  Quads where profile and line coincide are left out."""
    step = level_step(hf.quads, level_quads)
    if tolerance_m is None:
        tolerance_m = DEFAULT_TOLERANCE * min(hf.dx, hf.dy)
    if not tolerance_m >= 0:
        raise InputError(f"border tolerance must be >= 0 metres, got {tolerance_m}")
    positions, uvs, tris = [], [], []
    base = 0
    for rows, cols, spacing in _edges(hf):
        full = hf.heights[rows, cols].astype(np.float64)
        k = _kept_samples(full, step, spacing, tolerance_m)
        rows, cols, full = rows[k], cols[k], full[k]
        vertex = k % step == 0                         # the coarse level's vertices
        line = np.interp(k, k[vertex], full[vertex])
        off = full != line
        quads = np.flatnonzero(off[:-1] | off[1:])     # (i, i+1) with any height
        if len(quads) == 0:
            continue
        x, y = hf.world_xy(rows, cols)
        m = len(full)
        positions.append(np.concatenate([np.stack([x, y, line], 1), np.stack([x, y, full], 1)]))
        uv = _uv(hf, rows, cols)
        uvs.append(np.concatenate([uv, uv]))
        b0, b1 = base + quads, base + quads + 1        # on the coarse line
        t0, t1 = b0 + m, b1 + m                        # on the full profile
        tris.append(np.concatenate([np.stack([b0, b1, t1], 1), np.stack([b0, t1, t0], 1)]))
        base += 2 * m
    if not tris:
        return ProxyMesh(level_quads, np.zeros((0, 3), np.float32), np.zeros((0, 2), np.float32),
                         np.zeros((0, 3), np.uint32), 0)
    return ProxyMesh(level_quads, np.concatenate(positions).astype(np.float32),
                     np.concatenate(uvs).astype(np.float32),
                     np.concatenate(tris).astype(np.uint32), 0)


def proxy_mesh(hf: HeightField, level_quads: int, border: bool = True,
               tolerance_m: float | None = None) -> ProxyMesh:
    """Level ``level_quads`` plus (``border``) its border ribbon, as one mesh."""
    level = level_mesh(hf, level_quads)
    if not border:
        return level
    rib = border_ribbon(hf, level_quads, tolerance_m)
    return ProxyMesh(level_quads, np.concatenate([level.positions, rib.positions]),
                     np.concatenate([level.uv, rib.uv]),
                     np.concatenate([level.tris, rib.tris + len(level.positions)]).astype(
                         np.uint32), level.level_triangles)


def douglas_peucker(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices ``(k,) intp`` (ascending, the first and last included) of the points
    ``(m, 2) float64`` a Douglas-Peucker simplification within ``tolerance`` (the points'
    unit) keeps: scikit-image's ``skimage.measure.approximate_polygon``, the same
    arithmetic and the same points kept, without importing ``skimage.measure`` (it pulls
    in ``scipy.signal`` and ``scipy.stats``: about 1 s at the start of every process that
    draws a proxy: the CLI's renders, a distributed client and server, keyframe workers).
    A point's distance is to the segment's line where it projects inside the segment,
    else to the nearer end."""
    pts = np.asarray(points, np.float64)
    m = len(pts)
    if tolerance <= 0 or m < 3:
        return np.arange(m)
    chain = np.zeros(m, bool)
    chain[0] = chain[-1] = True
    stack = [(0, m - 1)]
    while stack:
        start, end = stack.pop()
        (r0, c0), (r1, c1) = pts[start], pts[end]
        dr, dc = r1 - r0, c1 - c0
        angle = -np.arctan2(dr, dc)
        line = c0 * np.sin(angle) + r0 * np.cos(angle)
        seg = pts[start + 1:end]
        dr0, dc0 = seg[:, 0] - r0, seg[:, 1] - c0
        dr1, dc1 = seg[:, 0] - r1, seg[:, 1] - c1
        perp = (dr0 * dr + dc0 * dc > 0) & (-dr1 * dr - dc1 * dc > 0)
        dist = np.where(perp, np.abs(seg[:, 0] * np.cos(angle) + seg[:, 1] * np.sin(angle)
                                     - line),
                        np.minimum(np.sqrt(dc0 ** 2 + dr0 ** 2), np.sqrt(dc1 ** 2 + dr1 ** 2)))
        if np.any(dist > tolerance):
            split = start + int(np.argmax(dist)) + 1
            stack += [(split, end), (start, split)]
            chain[split] = True
    return np.flatnonzero(chain)
