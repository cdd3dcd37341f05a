"""Objects to capture and their two-plane capture (Sloan, Cohen & Gortler 1997, §2.2).

:class:`ColorMesh` is a triangle mesh with per-vertex colours and normals.
:func:`still_life` is the built-in object: coloured, patterned spheres at different depths
(parallax) in front of a patterned backdrop plate.  :func:`textured_plane` is a flat
patterned square, which a lumigraph whose uv plane contains it reconstructs exactly.
:func:`capture` renders every st node's uv image: a pinhole image from the node with the
off-axis frustum whose image plane is the uv square
(:func:`~lodsprite.lumigraph.geometry.node_frustum`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lodsprite.lumigraph.geometry import Slab, node_frustum, node_view
from lodsprite.meshes import uv_sphere


@dataclass(frozen=True)
class ColorMesh:
    """``vertices (N, 3)`` metres, ``faces (F, 3) int32``, ``colors (N, 3)`` in [0, 1],
    ``normals (N, 3)`` unit."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    normals: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return (lo + hi) / 2

    @property
    def radius(self) -> float:
        return float(np.linalg.norm(self.vertices - self.centre, axis=1).max())


def _pattern(p: np.ndarray, base: np.ndarray, freq: float) -> np.ndarray:
    """Colour ``base (3,)`` modulated by a 3D checker of ``freq`` cells per metre."""
    cells = np.floor(p * freq).astype(np.int64).sum(axis=1) % 2
    stripes = 0.5 + 0.5 * np.sin(p[:, 2] * freq * 2.1)
    return np.clip(base[None, :] * (0.55 + 0.3 * cells[:, None] + 0.15 * stripes[:, None]),
                   0, 1)


def merge(parts: list[ColorMesh]) -> ColorMesh:
    """One mesh of several (faces re-indexed)."""
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    return ColorMesh(np.concatenate([p.vertices for p in parts]),
                     np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)])
                     .astype(np.int32),
                     np.concatenate([p.colors for p in parts]),
                     np.concatenate([p.normals for p in parts]))


def sphere(centre, radius: float, base, bands: int = 32, freq: float = 6.0) -> ColorMesh:
    """A patterned sphere."""
    v, f = uv_sphere(bands, 1.0)
    p = np.asarray(centre, dtype=np.float64) + radius * v
    return ColorMesh(p, f.astype(np.int32), _pattern(p, np.asarray(base, float), freq / radius),
                     v.copy())


def textured_plane(size: float = 2.0, cells: int = 48, z: float = 0.0,
                   freq: float = 5.0) -> ColorMesh:
    """A flat patterned square ``size`` metres wide in the plane ``z``, facing +z."""
    g = np.linspace(-size / 2, size / 2, cells + 1)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    p = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], axis=1)
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    a = (i * (cells + 1) + j).ravel()
    faces = np.concatenate([np.stack([a, a + cells + 1, a + cells + 2], 1),
                            np.stack([a, a + cells + 2, a + 1], 1)]).astype(np.int32)
    normals = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    return ColorMesh(p, faces, _pattern(p, np.array([0.9, 0.75, 0.35]), freq), normals)


def still_life() -> ColorMesh:
    """The built-in lumigraph object: five patterned spheres at depths from -0.6 to +0.5 m
    in front of a backdrop plate, about 1 m across."""
    parts = [sphere((0.0, 0.0, 0.0), 0.32, (0.9, 0.25, 0.2)),
             sphere((-0.45, 0.3, 0.35), 0.16, (0.2, 0.7, 0.3)),
             sphere((0.42, -0.28, 0.5), 0.14, (0.25, 0.4, 0.95)),
             sphere((0.4, 0.38, -0.25), 0.2, (0.95, 0.8, 0.2)),
             sphere((-0.38, -0.36, -0.1), 0.18, (0.75, 0.3, 0.85)),
             textured_plane(1.6, 32, -0.6, 4.0)]
    return merge(parts)


def capture(mesh_renderer, slab: Slab, render_target, near: float, far: float,
            progress: Callable[[int, int], None] | None = None
            ) -> dict[tuple[int, int], np.ndarray]:
    """Every node's uv image, ``{(i, j): (n_uv, n_uv, 3) uint8}`` (row 0 at the top: v
    down).  ``mesh_renderer`` draws the object (``render(view_proj, fbo)``);
    ``render_target`` is an ``n_uv x n_uv`` :class:`~lodsprite.gl.target.RenderTarget`;
    ``near``/``far`` bound the object along the slab's axis from the st plane."""
    nodes = slab.node_local()
    images = {}
    total = slab.n_st ** 2
    for i in range(slab.n_st):
        for j in range(slab.n_st):
            proj = node_frustum(nodes[i, j], slab.uv_size, near, far)
            mesh_renderer.render(proj @ node_view(slab, i, j), render_target.fbo)
            images[(i, j)] = render_target.read_color()
            if progress:
                progress(i * slab.n_st + j + 1, total)
    return images
