"""Critical-time node selection (Sloan, Cohen & Gortler 1997, §4), GL-free.

* :func:`benefit` - §4.1: ``benefit(i, j) = Dist(s, t) * Path(s, t) * Neighbor(s, t)``,
  each in [0, 1]: ``Dist = c / (d² + c)`` with ``d`` the node's distance from the st
  point of the eye (where the eye's ray to the object's centre crosses the st plane) and
  ``c`` one node spacing squared; ``Path`` the same form over the distance from the
  predicted path of that point (the project's viewpoint predictors); ``Neighbor = 1/2 +
  1/2 * (fraction of the 8 neighbours not drawn)`` (the paper's "fraction of the
  neighbouring nodes currently not in the triangulation", kept above zero so a node whose
  neighbours are all drawn still ranks by distance).
* :class:`CostModel` - §4.2: per-node fetch, decode and upload costs and the raster cost
  ``raster_base + raster_node * nodes``, measured, each frame component with its own
  scale factor rescaled from measured frame times (§5.2: one factor for everything
  caused the paper's spikes; ``per_component=False`` gives that single factor).
* :func:`plan` - §4: nodes sorted by benefit/cost are added until the frame's time budget
  is spent; a node not yet decoded is requested from the loader; when texture memory is
  full the lowest-benefit resident node is evicted for the next in line.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lodsprite.lumigraph.geometry import Slab

DISK, RAM, RESIDENT = 0, 1, 2  # where a node's image is: only on disk, decoded, a texture
FRAME_COMPONENTS = ("upload", "raster", "base")


def st_point(slab: Slab, eye_world: np.ndarray) -> np.ndarray:
    """Where the ray from ``eye_world (3,)`` to the uv plane's centre crosses the st plane,
    ``(2,)`` st metres (the eye's point ``(s, t)`` of Figure 1)."""
    e = (slab.to_local @ np.append(np.asarray(eye_world, float), 1.0))[:3]
    z = e[2] if abs(e[2]) > 1e-9 else 1e-9
    return e[:2] * (slab.st_distance / z)


def _falloff(d2: np.ndarray, c: float) -> np.ndarray:
    return c / (d2 + c)


def neighbour_fraction_missing(drawn: np.ndarray) -> np.ndarray:
    """``drawn (n, n) bool`` -> the fraction of each node's (up to 8) grid neighbours that
    are not drawn, ``(n, n)``."""
    d = np.pad(drawn.astype(np.float64), 1)
    ones = np.pad(np.ones(drawn.shape), 1)
    n = drawn.shape[0]
    count = np.zeros(drawn.shape)
    total = np.zeros(drawn.shape)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == dj == 0:
                continue
            sl = (slice(1 + di, 1 + di + n), slice(1 + dj, 1 + dj + n))
            count += d[sl]
            total += ones[sl]
    return 1.0 - count / total


def benefit(slab: Slab, eye_st: np.ndarray, path_st: np.ndarray, drawn: np.ndarray,
            points: np.ndarray | None = None) -> np.ndarray:
    """§4.1's benefit of every node, ``(n_st * n_st,)`` in [0, 1]: ``eye_st (2,)`` the eye's
    st point, ``path_st (K, 2)`` its predicted future st points (may be empty),
    ``drawn (n_st * n_st,) bool`` the nodes in the current triangulation; ``points``
    the nodes' st coordinates ``(n_st * n_st, 2)`` if already at hand."""
    n = slab.n_st
    pts = slab.node_local()[..., :2].reshape(-1, 2) if points is None else points
    c = (slab.st_size / (n - 1)) ** 2
    dist = _falloff(((pts - eye_st) ** 2).sum(axis=1), c)
    path = np.ones(len(pts))
    path_st = np.asarray(path_st, dtype=np.float64).reshape(-1, 2)
    if len(path_st):
        track = np.concatenate([np.asarray(eye_st, float)[None], path_st])
        path = _falloff(_distance_to_polyline(pts, track) ** 2, c)
    missing = neighbour_fraction_missing(np.asarray(drawn, bool).reshape(n, n)).reshape(-1)
    return dist * path * (0.5 + 0.5 * missing)


def _distance_to_polyline(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each point ``p (N, 2)`` from the polyline ``line (K, 2)``."""
    if len(line) == 1:
        return np.linalg.norm(p - line[0], axis=1)
    a, b = line[:-1], line[1:]                                  # (S, 2)
    ab = b - a
    len2 = np.maximum((ab ** 2).sum(axis=1), 1e-18)
    t = np.clip(((p[:, None, :] - a[None]) * ab[None]).sum(axis=2) / len2, 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - nearest, axis=2).min(axis=1)


@dataclass
class CostModel:
    """Measured costs (ms) and the scale factors that rescale them from frame times.

    ``fetch``, ``decode``: per node, in the loader's process (moving averages of what it
    measures).  ``upload`` per node uploaded, ``raster_base + raster_node * nodes`` per
    frame drawn, ``base`` the rest of a frame: calibrated once, then multiplied by
    :attr:`scale` (one factor per component, or one for all)."""

    upload: float = 0.3
    raster_base: float = 5.0
    raster_node: float = 0.05
    base: float = 0.5
    fetch: float = 0.2
    decode: float = 1.0
    per_component: bool = True
    gain: float = 0.3  # how far each frame moves a factor towards the measured ratio
    scale: dict[str, float] = field(default_factory=lambda: dict.fromkeys(FRAME_COMPONENTS,
                                                                          1.0))

    def predicted(self, uploads: int, nodes: int) -> dict[str, float]:
        """A frame's predicted cost by component (ms), rescaled."""
        raw = {"upload": self.upload * uploads,
               "raster": self.raster_base + self.raster_node * nodes, "base": self.base}
        return {k: v * self.scale[k] for k, v in raw.items()}

    def node_costs(self, where: np.ndarray) -> np.ndarray:
        """The cost of adding each node given where it is (:data:`DISK`, :data:`RAM`,
        :data:`RESIDENT`), ``(N,)`` ms, rescaled: raster, plus upload unless resident,
        plus fetch and decode when only on disk."""
        raster = self.raster_node * self.scale["raster"]
        upload = self.upload * self.scale["upload"]
        cost = np.full(len(where), raster)
        cost[where != RESIDENT] += upload
        cost[where == DISK] += self.fetch + self.decode
        return cost

    def observe(self, uploads: int, nodes: int, measured: dict[str, float]) -> None:
        """Rescale from one frame's measured component times (ms): each factor moves
        towards measured / unscaled prediction (per component), or one factor for all
        towards total measured / total unscaled prediction."""
        raw = {"upload": self.upload * uploads,
               "raster": self.raster_base + self.raster_node * nodes, "base": self.base}
        if self.per_component:
            for k in FRAME_COMPONENTS:
                if raw[k] > 1e-6 and k in measured:
                    self._move(k, measured[k] / raw[k])
        else:
            total = sum(raw.values())
            ratio = sum(measured.get(k, 0.0) for k in FRAME_COMPONENTS) / max(total, 1e-6)
            for k in FRAME_COMPONENTS:
                self._move(k, ratio)

    def _move(self, k: str, ratio: float) -> None:
        ratio = float(np.clip(ratio, 0.05, 50.0))
        self.scale[k] = float(np.exp((1 - self.gain) * np.log(self.scale[k])
                                     + self.gain * np.log(ratio)))

    def loaded(self, fetch_ms: float, decode_ms: float) -> None:
        """A node the loader fetched and decoded: moving averages of both costs."""
        self.fetch += 0.1 * (fetch_ms - self.fetch)
        self.decode += 0.1 * (decode_ms - self.decode)


@dataclass(frozen=True)
class Plan:
    """One frame's decision: ``draw`` the nodes to draw (resident after ``upload``),
    ``upload`` the decoded nodes to make resident first, ``evict`` the resident nodes to
    free for them, ``request`` the nodes the loader should fetch and decode next, best
    first; ``predicted_ms`` the frame's predicted time."""

    draw: np.ndarray
    upload: np.ndarray
    evict: np.ndarray
    request: np.ndarray
    predicted_ms: float


def plan(gain: np.ndarray, where: np.ndarray, costs: CostModel, budget_ms: float,
         capacity: int, requests: int = 16, floor: float = 1e-4) -> Plan:
    """§4's greedy choice: nodes in order of benefit/cost (``gain (N,)`` benefit,
    ``where (N,)`` DISK/RAM/RESIDENT) are added while the predicted frame time stays within
    ``budget_ms``; once ``capacity`` nodes fill texture memory, each next node in line
    replaces the lowest-benefit node chosen if it has more benefit.  Nodes worth drawing
    that are only on disk go to the loader (``requests`` of them, best first).  Resident
    nodes not drawn are evicted lowest benefit first, as many as uploads need room."""
    gain = np.asarray(gain, dtype=np.float64)
    where = np.asarray(where)
    cost = costs.node_costs(where)
    ratio = gain / cost
    # only the best few can matter: enough to fill memory, replace, and feed the loader
    keep = min(len(gain), 3 * capacity + requests + 32)
    top = np.argpartition(-ratio, keep - 1)[:keep] if keep < len(gain) else np.arange(len(gain))
    order = top[np.argsort(-ratio[top], kind="stable")]
    order = order[gain[order] > floor]
    sc = costs.scale
    t = costs.base * sc["base"] + costs.raster_base * sc["raster"]
    raster = costs.raster_node * sc["raster"]
    upload = costs.upload * sc["upload"]
    g, wh = gain.tolist(), where.tolist()
    draw, ups, want = [], [], []
    low = np.inf  # the lowest benefit drawn, once memory is full
    for node in order.tolist():
        w = wh[node]
        if w == DISK:
            if len(want) < requests:
                want.append(node)
            continue
        c = raster + (upload if w != RESIDENT else 0.0)
        if len(draw) >= capacity:
            # texture memory full: the next in line replaces the lowest-benefit node
            if g[node] <= low:
                continue
            k = min(range(len(draw)), key=lambda i: g[draw[i]])
            out = draw[k]
            c_out = raster + (upload if wh[out] != RESIDENT else 0.0)
            if t - c_out + c > budget_ms:
                continue
            draw[k], t = node, t - c_out + c
            if out in ups:
                ups.remove(out)
            low = min(g[d] for d in draw)
        elif t + c > budget_ms and draw:
            continue
        else:
            draw.append(node)
            t += c
            if len(draw) == capacity:
                low = min(g[d] for d in draw)
        if w != RESIDENT:
            ups.append(node)
    draw_a = np.array(draw, dtype=np.int64)
    resident = np.flatnonzero(where == RESIDENT)
    free = capacity - len(resident)
    need = max(0, len(ups) - free)
    spare = resident[~np.isin(resident, draw_a)]
    evict = spare[np.argsort(gain[spare], kind="stable")[:need]]
    return Plan(draw_a, np.array(ups, dtype=np.int64), evict, np.array(want, np.int64), t)
