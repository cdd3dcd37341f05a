"""The critical-time lumigraph renderer (Sloan, Cohen & Gortler 1997, §4), frame by frame.

Each frame: the benefit of every node (:func:`~lodsprite.lumigraph.critical.benefit`,
with the eye's st point and its predicted path from the project's motion predictor),
the greedy benefit/cost :func:`~lodsprite.lumigraph.critical.plan` under the frame's time
budget and the texture memory's capacity, evictions and uploads of decoded nodes, the
covering of the chosen nodes (any subset, fictitious corners) and one draw.  Fetching
and decoding happen in the :class:`~lodsprite.lumigraph.loader.NodeLoader`'s process; a
node it has not decoded yet is simply not drawn this frame.  The measured upload, raster and
remaining times rescale their own cost factors (:class:`~lodsprite.lumigraph.critical.
CostModel`), so the predicted frame time follows the machine's load.

The run starts warm: the nodes round the first view are decoded and resident before the
first timed frame, and the cost model is calibrated from those uploads and a draw.
"""

from __future__ import annotations

import time

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.lumigraph.base import FRAME_S, Context, Method, method_frame
from lodsprite.lumigraph.critical import DISK, RAM, RESIDENT, CostModel, benefit, plan, st_point
from lodsprite.lumigraph.subsets import cover_draws, nearest_nodes, subset_cover
from lodsprite.record import Frame

PATH_AHEAD_S = (0.1, 0.2, 0.3, 0.5)  # predicted eye positions that make the Path term


class CriticalMethod(Method):
    """§4 under ``target_fps`` and ``texture_mb`` of texture memory."""

    name = "critical"
    dynamic = False

    def __init__(self, ctx: Context, target_fps: float = 30.0, texture_mb: float = 4.0,
                 per_component: bool = True, level: int = 0, requests: int = 16) -> None:
        if not (0.5 <= target_fps <= 1000):
            raise InputError(f"--target-fps must be 0.5..1000, got {target_fps}")
        slab = ctx.lf.slabs[ctx.slab_index]
        m = max(1, slab.n_uv >> level)
        node_bytes = m * m * 4
        capacity = int(texture_mb * 2 ** 20 // node_bytes)
        if capacity < 1:
            raise InputError(f"--texture-mb {texture_mb} holds no {m}² node image "
                             f"({node_bytes / 2 ** 20:.2f} MB each)")
        super().__init__(ctx, min(capacity, slab.n_st ** 2), level)
        self.target_ms = 1e3 / target_fps
        self.texture_mb = float(texture_mb)
        self.costs = CostModel(per_component=per_component)
        self.requests = int(requests)
        self.drawn = np.zeros(self.n_nodes, dtype=bool)
        self.current = np.zeros(0, dtype=np.int64)
        self.predicted_ms = 0.0
        self.points = self.slab.node_local()[..., :2].reshape(-1, 2)

    def warm_up(self, viewpoint: Viewpoint, projection: np.ndarray) -> None:
        """Untimed: decode and upload the nodes round the first view; calibrate the upload
        and raster costs from them (GL work finished before each clock stops)."""
        gl = self.ctx.gl
        first = np.sort(nearest_nodes(self.slab, self.eye_st(viewpoint),
                                      min(self.rec.capacity, 9)))
        images = {int(n): self.loader.load_now(int(n)) for n in first}
        gl.finish()
        t0 = time.perf_counter()
        for n, img in images.items():
            if img is not None:
                self.rec.upload(n, img)
        gl.finish()
        ups = max(1, sum(img is not None for img in images.values()))
        self.costs.upload = (time.perf_counter() - t0) * 1e3 / ups
        ok = np.array([n for n, img in images.items() if img is not None], dtype=np.int64)
        times = []
        for nodes in (ok[:1], ok):
            if not len(nodes):
                continue
            self.rec.set_draws(cover_draws(subset_cover(self.slab, nodes)))
            self.rec.render(viewpoint.view_matrix(), projection, self.ctx.proxy)
            gl.finish()
            t1 = time.perf_counter()
            self.rec.render(viewpoint.view_matrix(), projection, self.ctx.proxy)
            gl.finish()
            times.append((time.perf_counter() - t1) * 1e3)
        if len(times) == 2 and len(ok) > 1:
            self.costs.raster_node = max(0.0, (times[1] - times[0]) / (len(ok) - 1))
            self.costs.raster_base = max(0.1, times[0] - self.costs.raster_node)
        self.current = ok
        self.drawn[ok] = True

    def where(self) -> np.ndarray:
        w = np.full(self.n_nodes, DISK, dtype=np.int8)
        w[self.loader.holds(self.n_nodes)] = RAM
        w[list(self.rec.slot_of)] = RESIDENT
        return w

    def frame(self, index: int, viewpoint: Viewpoint, projection: np.ndarray,
              count_samples: bool = False) -> Frame:
        gl = self.ctx.gl
        t0 = time.perf_counter()
        now = index * FRAME_S
        self.predictor.observe(now, viewpoint)
        st = self.eye_st(viewpoint)
        # the linear predictor's eye, sampled along its line (one prediction)
        ahead = self.predictor.predict(PATH_AHEAD_S[-1]).o - viewpoint.o
        path = np.array([st_point(self.slab, viewpoint.o + ahead * (dt / PATH_AHEAD_S[-1]))
                         for dt in PATH_AHEAD_S])
        gain = benefit(self.slab, st, path, self.drawn, self.points)
        gain[list(self.loader.bad)] = 0.0
        for _, fetch_ms, decode_ms in self.loader.drain_costs():
            self.costs.loaded(fetch_ms, decode_ms)
        p = plan(gain, self.where(), self.costs, self.target_ms, self.rec.capacity,
                 self.requests)
        self.loader.want(p.request)
        self.predicted_ms = p.predicted_ms
        for n in p.evict:
            self.rec.evict(int(n))
        t_up = time.perf_counter()
        uploaded = 0
        draw = []
        for n in p.draw:
            n = int(n)
            if n not in self.rec.slot_of:
                img = self.loader.get(n)
                if img is None or not self.rec.free_layers:
                    continue  # dropped from the cache meanwhile: drawn without it
                self.rec.upload(n, img)
                uploaded += 1
            draw.append(n)
        gl.finish()
        upload_ms = (time.perf_counter() - t_up) * 1e3
        nodes = np.sort(np.array(draw, dtype=np.int64)) if draw else self.current
        if not np.array_equal(nodes, self.current):
            self.rec.set_draws(cover_draws(subset_cover(self.slab, nodes)))
            self.current = nodes
            self.drawn[:] = False
            self.drawn[nodes] = True
        raster_ms = self.draw(viewpoint, projection, count_samples)
        total = (time.perf_counter() - t0) * 1e3
        self.costs.observe(uploaded, len(nodes), {"upload": upload_ms, "raster": raster_ms,
                                                  "base": total - upload_ms - raster_ms})
        return method_frame(total, upload_ms, raster_ms, len(nodes), uploaded, len(p.evict))
