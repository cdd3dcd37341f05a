"""Tile updates that keep the view-dependent proxy frozen until it is stale (issue 32,
must-have 3), free of GL.

With a view-dependent proxy (:mod:`lodsprite.techniques.sprite_proxy`: the adaptive mesh
at ``proxy_sse`` pixels, selected at a keyframe's eye, culled by its key frustum widened
``WIDEN`` times) a tile update used to select and freeze the proxy again, and every tile's
``C'`` was cast onto a proxy of its own: a tile update cost about a whole adaptive frame.
Now the proxy frozen at one update is kept by the next ones, their tiles' ``C'`` cast onto
it from their own eyes (the spriteframe draws that one proxy under every tile), until it
is **stale** at the update's viewpoint.  The rule (:meth:`HeldProxy.stale`), either of:

* **region**: a coarse square centre (the uniform metric's ``n x n`` centres, heights of
  the coarse level) in the update's key view (guard band included) lies off the held
  proxy's footprint (:meth:`~lodsprite.sprite.proxy_surface.ProxySurface.node_at` is -1):
  the eye turned or moved beyond the region the proxy was selected and culled for, and
  the spriteframe would show sky there;
* **error**: the proxy's own error bound at the update's eye passes its tolerance.  A
  node of level ``k > 0`` was selected (not split) where the eye stood at least its
  split range ``R_k`` (:func:`~lodsprite.terrain.quadtree.ranges` at ``proxy_sse``) from
  its bounding box; its screen error scales with ``R_k / d`` (``d`` the eye's distance to
  the box), at most ``proxy_sse`` where ``R_k / d <= 1``.  The bound is ``ρ(eye) = max_n
  R_k / d_n`` (:func:`split_ratio`); stale when ``ρ`` passes ``STALE_GROWTH`` times
  ``max(1, ρ at the frozen eye)`` (a node whose children were not resident when frozen
  already stood over 1): the proxy's error bound has doubled past its tolerance, or past
  what it was when frozen.

Otherwise the proxy is fresh and kept.  The first update freezes it; a stale one freezes
it again at its own viewpoint.  Cost of the test: ``N`` box distances (``N`` the held
nodes, hundreds) and a raster lookup of the centres in view; the proxy's heights
(:class:`~lodsprite.sprite.proxy_surface.ProxyNodes`) are made once a freeze.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.sprite.proxy_surface import ProxyNodes, ProxySurface

STALE_GROWTH = 2.0  # the proxy's error bound may grow this many times before a refreeze
REGION, ERROR = "region", "error"  # why a held proxy is stale


def split_ratio(lo: np.ndarray, hi: np.ndarray, split_m: np.ndarray,
                eye: np.ndarray) -> float:
    """``max_n split_m[n] / d_n`` over nodes with ``split_m > 0``: ``lo, hi (N, 3)`` their
    bounding boxes (metres), ``split_m (N,)`` each one's split range (0: level 0, never
    split), ``d_n`` the distance from ``eye (3,)`` to box ``n`` (floored at 1 mm); 0 when
    no node splits."""
    on = np.asarray(split_m, np.float64) > 0
    if not on.any():
        return 0.0
    eye = np.asarray(eye, np.float64)
    d = np.linalg.norm(np.clip(eye, lo[on], hi[on]) - eye, axis=1)
    return float(np.max(split_m[on] / np.maximum(d, 1e-3)))


@dataclass
class HeldProxy:
    """The proxy frozen at ``eye (3,)``: ``nodes`` (its heights as drawn, the metric's
    source), ``lo, hi (N, 3)`` bounding boxes and ``split_m (N,)`` split ranges of its
    nodes, ``surface`` its locator; ``ratio0`` is :func:`split_ratio` at ``eye``."""

    eye: np.ndarray
    nodes: ProxyNodes
    lo: np.ndarray
    hi: np.ndarray
    split_m: np.ndarray
    surface: ProxySurface
    ratio0: float

    @classmethod
    def make(cls, eye: np.ndarray, nodes: ProxyNodes, lo: np.ndarray, hi: np.ndarray,
             split_m: np.ndarray) -> HeldProxy:
        eye = np.asarray(eye, np.float64)
        lo = np.asarray(lo, np.float64).reshape(-1, 3)
        hi = np.asarray(hi, np.float64).reshape(-1, 3)
        split_m = np.asarray(split_m, np.float64)
        return cls(eye, nodes, lo, hi, split_m, ProxySurface(nodes),
                   split_ratio(lo, hi, split_m, eye))

    def stale(self, eye: np.ndarray, centres: np.ndarray) -> str | None:
        """Why the held proxy is stale at ``eye (3,)`` whose key view holds the coarse
        square ``centres (K, 3)`` (:data:`REGION`, :data:`ERROR`), None while fresh
        (module docstring for the rule)."""
        c = np.asarray(centres, np.float64).reshape(-1, 3)
        off = len(c) and np.any(self.surface.node_at(c[:, 0], c[:, 1]) < 0)
        if len(self.nodes) == 0 or off:
            return REGION
        limit = STALE_GROWTH * max(1.0, self.ratio0)
        if split_ratio(self.lo, self.hi, self.split_m, eye) > limit:
            return ERROR
        return None


class ProxyHold:
    """The tiled engine's side of a held proxy over ``source`` (an
    :class:`~lodsprite.techniques.sprite_proxy.AdaptiveProxySource`: ``nodes(eye,
    view_proj)``, ``last``, ``r``, ``terrain.tree.bounds``) and ``coarse`` (the uniform
    metric whose centres the region test takes).

    :meth:`nodes` is the proxy metric's source: while :attr:`held` it gives the held
    proxy's nodes whatever the eye; :meth:`stale` tells the engine whether a tile update
    must freeze again, :meth:`frozen` takes the proxy just frozen.  :attr:`reasons` logs,
    per freeze, why (``"first"``, :data:`REGION`, :data:`ERROR`)."""

    def __init__(self, source, coarse) -> None:
        self.source, self.coarse = source, coarse
        self.held = False
        self.proxy: HeldProxy | None = None
        self.reasons: list[str] = []
        self._last: tuple[np.ndarray, ProxyNodes] | None = None  # (eye, nodes) last made

    def nodes(self, eye: np.ndarray, view_proj: np.ndarray | None) -> ProxyNodes:
        if self.held and self.proxy is not None:
            return self.proxy.nodes
        out = self.source.nodes(eye, view_proj)
        self._last = (np.asarray(eye, np.float64).copy(), out)
        return out

    def stale(self, viewpoint, key_projection) -> str | None:
        """Why a tile update at ``viewpoint`` through ``key_projection`` must freeze the
        proxy again (``"first"`` before any freeze), None to keep it."""
        if self.proxy is None:
            return "first"
        mask = self.coarse.in_view_mask(viewpoint, key_projection)
        return self.proxy.stale(viewpoint.o, self.coarse.squares.centres[mask])

    def frozen(self, eye: np.ndarray, reason: str) -> None:
        """The proxy was frozen at ``eye (3,)`` (the selection ``source.last``)."""
        self.reasons.append(reason)
        nodes, _ = self.source.last
        eye = np.asarray(eye, np.float64)
        if self._last is None or not np.array_equal(self._last[0], eye) or not nodes:
            self.proxy = None  # its heights were not made here: the next update freezes
            return
        tree = self.source.terrain.tree
        boxes = [tree.bounds(n) for n in nodes]
        split = np.array([self.source.r[n.k] if n.k > 0 else 0.0 for n in nodes])
        self.proxy = HeldProxy.make(eye, self._last[1], [b[0] for b in boxes],
                                    [b[1] for b in boxes], split)
