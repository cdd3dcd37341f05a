"""The surface a keyframe shows, for the LOD-sprite error metric's ``C`` (Chen, Swan &
Kaufman 1999, §3.2, Eq. 1-2) when keyframes are drawn by the adaptive renderer.

The metric's ``C`` is the full-resolution point whose colour a keyframe pixel carries.
With keyframes drawn adaptively at ``--key-sse``, the surface in that image *is* the
adaptive renderer's selection at the keyframe's eye and view: each drawn node's samples,
triangulated as the GPU draws them (squares split along the north-west/south-east
diagonal) and geomorphed towards the parent at the keyframe eye
(:func:`~lodsprite.techniques.sprite_proxy.drawn_heights`: the surface of
:func:`~lodsprite.techniques.sprite_proxy.frozen_nodes` at stride 1, evaluated at the
metric's points alone: building every drawn node's morphed samples took 250 ms a 4k²
keyframe).  Its tiles are resident (host
cache, else a read-back of their GPU slot), so taking ``C`` there reads no storage: over
a 16k² store, reading ``C`` from level 0 took thousands of chunk decodes at setup and
2560 chunks per proxy keyframe (issue 22, must-have 6).

:meth:`DrawnSurface.heights` makes the selection the keyframe's draw makes next (same eye,
frustum, ranges and resident set: nothing is uploaded between the metric's ``reproject``
and the keyframe's draw).  A point outside the selection (outside the keyframe's frustum)
takes the finest resident node covering it, unmorphed; none (no root resident): NaN,
which the callers replace by their own estimate.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lodsprite.camera import frustum_planes
from lodsprite.sprite.proxy_surface import ProxySurface
from lodsprite.techniques.sprite_proxy import drawn_heights, frozen_nodes
from lodsprite.terrain.quadtree import Node

#: ``(x (K,), y (K,)) -> z (K,) float64`` metres: a keyframe's drawn surface.
Heights = Callable[[np.ndarray, np.ndarray], np.ndarray]


class DrawnSurface:
    """The surface ``terrain`` (an :class:`~lodsprite.techniques.adaptive_terrain.
    AdaptiveTerrain`) draws for a keyframe; ``heights(eye, view_proj)`` is the metric's
    source of ``C`` (:attr:`lodsprite.sprite.metric.ErrorMetric.surface`)."""

    def __init__(self, terrain) -> None:
        self.terrain = terrain
        self.last: tuple = ()  # the nodes of the last selection made (tests compare)

    def selection(self, eye: np.ndarray, view_proj: np.ndarray | None
                  ) -> tuple[list[Node], frozenset]:
        """The nodes the keyframe's draw selects at ``eye (3,)`` through ``view_proj
        (4, 4)`` (None: not culled), and those that morph (parent resident)."""
        t = self.terrain
        planes = (np.array([[0.0, 0.0, 0.0, 1.0]] * 6) if view_proj is None
                  else frustum_planes(np.asarray(view_proj, np.float64)))
        nodes, _ = t.tree.select(np.asarray(eye, np.float64), planes, t.r,
                                 t.slots.__contains__)
        morphed = frozenset(n for n in nodes if n.k < t.tree.top and n.parent() in t.slots)
        return nodes, morphed

    def heights(self, eye: np.ndarray, view_proj: np.ndarray | None) -> Heights:
        """The drawn surface's height function for a keyframe at ``eye`` through
        ``view_proj`` (module docstring)."""
        eye = np.asarray(eye, np.float64)
        nodes, morphed = self.selection(eye, view_proj)
        self.last = tuple(nodes)
        t = self.terrain
        drawn = drawn_heights(t, nodes, morphed, eye, t.r) if nodes else None

        def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            x = np.asarray(x, np.float64).ravel()
            y = np.asarray(y, np.float64).ravel()
            z = np.full(x.shape, np.nan) if drawn is None else drawn(x, y)
            off = np.isnan(z)
            if off.any():
                z[off] = self.resident(x[off], y[off], eye)
            return z

        return height

    def points(self, eye: np.ndarray, view_proj: np.ndarray | None) -> Callable:
        """``points(rows, cols) -> (K, 3) float64`` metres: level-0 sample indices on the
        drawn surface of the keyframe at ``eye`` through ``view_proj`` (the proxy metric's
        :data:`~lodsprite.sprite.proxy_metric.PointSource`)."""
        height = self.heights(eye, view_proj)
        tree = self.terrain.tree

        def at(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
            x, y = tree.world_xy(0, np.asarray(rows, np.float64), np.asarray(cols, np.float64))
            x, y = np.broadcast_arrays(x, y)
            return np.stack([x, y, height(x, y).reshape(x.shape)], axis=-1)

        return at

    def resident(self, x: np.ndarray, y: np.ndarray, eye: np.ndarray) -> np.ndarray:
        """Heights ``(K,)`` at ``(x, y)`` on the finest resident node covering each point
        (unmorphed; NaN where none is)."""
        t = self.terrain
        tree, g = t.tree, t.tree.g
        col = np.clip(x / tree.p.dx + (tree.cols0 - 1) / 2.0, 0, tree.cols0 - 1)
        row = np.clip((tree.rows0 - 1) / 2.0 - y / tree.p.dy, 0, tree.rows0 - 1)
        z = np.full(x.shape, np.nan)
        todo = np.ones(x.shape, bool)
        resident: dict[int, list[Node]] = {}
        for n in t.slots.slots:  # the GPU cache's nodes, by level
            resident.setdefault(n.k, []).append(n)
        for k in range(tree.levels):  # finest first
            if not todo.any():
                break
            br, bc = tree.blocks(k)
            i = np.minimum((row / (g << k)).astype(np.intp), br - 1)
            j = np.minimum((col / (g << k)).astype(np.intp), bc - 1)
            lin = i * bc + j
            level = resident.get(k, [])
            ids = np.array([n.i * bc + n.j for n in level], np.intp)
            used = np.isin(ids, lin[todo])
            if not used.any():
                continue
            have = [n for n, u in zip(level, used, strict=True) if u]
            mine = todo & np.isin(lin, ids[used])
            surface = ProxySurface(frozen_nodes(t, have, frozenset(), eye, 1, t.r))
            z[mine] = surface.height(x[mine], y[mine])
            todo &= ~mine | np.isnan(z)
        return z
