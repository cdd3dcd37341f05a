"""The adaptive terrain renderer (:mod:`lodsprite.techniques.adaptive_terrain`) as techniques:
``adaptive`` draws every frame with it; ``sprite-adaptive`` is LOD-sprite whose keyframes
it draws (``--key-sse``), streaming between keyframes.  Both fly a store of any size
(the scene's terrain spec names the store) or the scene's in-memory height field.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.techniques.base import Frame, Technique
from lodsprite.techniques.terrain import SpriteTechnique
from lodsprite.workers import peak_rss_mb

if TYPE_CHECKING:
    from lodsprite.api import Renderer
    from lodsprite.camera import Viewpoint


def scene_pyramid(scene):
    """What the adaptive renderer draws for ``scene``: the store itself when its terrain
    spec names one, else its height field as an in-memory pyramid (the field full
    resolution draws)."""
    from lodsprite.terrain.pyramid import MemoryPyramid
    from lodsprite.terrain.store import TerrainStore, is_store

    if is_store(scene.terrain_spec):
        return TerrainStore(Path(scene.terrain_spec).expanduser(),
                            float(scene.hf.meta.get("exaggeration", 1.0)))
    return MemoryPyramid.from_heightfield(scene.hf)


def make_adaptive(renderer: Renderer, sse: float, gpu_mb: float, host_mb: float):
    """An :class:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain` on ``renderer``'s context
    and target, coloured with the scene's texture."""
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain

    pr = renderer.paths
    return AdaptiveTerrain(pr.ctx, scene_pyramid(renderer.scene), pr.renderer.target,
                           renderer.fov_y_deg, sse, gpu_mb=gpu_mb, host_mb=host_mb,
                           color=pr.geometry.color_tex)


def tile_status(terrain) -> str:
    """The HUD's line of tiles: resident on the GPU, loaded so far, in flight."""
    loader = terrain.loader
    return (f"tiles: {len(terrain.slots.slots)} resident, {loader.loaded} loaded, "
            f"{getattr(loader, 'in_flight_tiles', 0)} in flight")


def reader_mb(terrain) -> float:
    """The tile reader process's peak resident memory, MB (0 without one)."""
    return getattr(terrain.loader, "reader_peak_mb", lambda: 0.0)()


def reader_restarts(terrain) -> int:
    """How many times the tile reader process was started again after dying (0 without
    a reader process)."""
    worker = getattr(terrain.loader, "worker", None)
    return 0 if worker is None else min(int(worker.deaths), int(worker.restarts))


def process_age_s() -> float:
    """Seconds since this process started (``/proc/self/stat`` starttime against
    ``/proc/uptime``, clock-tick resolution); NaN where ``/proc`` cannot be read."""
    import os

    try:
        with open("/proc/self/stat") as f:
            start = int(f.read().rpartition(")")[2].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")
    return uptime - start / os.sysconf("SC_CLK_TCK")


def tile_summary(terrain) -> dict[str, Any]:
    """Peak memory (with the tile reader process's), the tile caches' counts, tiles that
    could not be read and the reader's restarts."""
    reader = reader_mb(terrain)
    return {"peak_rss_mb": peak_rss_mb() + reader, "peak_rss_mb_reader": reader,
            "reader_restarts": reader_restarts(terrain),
            "tiles_resident": len(terrain.slots.slots), "tiles_loaded": terrain.loader.loaded,
            "tiles_evicted": terrain.slots.evicted, "tiles_bad": len(terrain.loader.bad),
            "gpu_cache_tiles": terrain.slots.capacity, "levels": terrain.tree.levels,
            "gpu_cache_mb": terrain.slots.capacity * (terrain.tree.g + 1) ** 2 * 4 / 2 ** 20}


class AdaptiveTechnique(Technique):
    """Every frame by the adaptive renderer at ``sse`` pixels of screen-space error,
    tiles through caches of ``gpu_mb`` and ``host_mb``.  No warm-up beyond the roots (the
    first frame's time, from the process's start, is ``first_frame_s``; from the
    technique's making ``first_frame_s_technique``).  Records each
    frame's selection; its replay reads those tiles and draws the same selection."""

    name = "adaptive"

    def __init__(self, renderer: Renderer, sse: float = 1.0, gpu_mb: float = 256.0,
                 host_mb: float = 512.0) -> None:
        super().__init__(renderer)
        self._t0 = time.perf_counter()
        self.terrain = make_adaptive(renderer, sse, gpu_mb, host_mb)
        self.first_frame_s = self.first_frame_s_technique = float("nan")

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Nothing: streaming from the roots is part of the measured run."""

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self.terrain.frame(viewpoint)
        if self.first_frame_s_technique != self.first_frame_s_technique:  # NaN: first
            self.first_frame_s_technique = time.perf_counter() - self._t0
            self.first_frame_s = process_age_s()
        return Frame("adaptive", f.ms, f.triangles, extra={
            "nodes": f.nodes, "uploaded": f.uploaded, "resident": f.resident,
            "loaded": f.loaded, "evicted": f.evicted})

    def decision(self) -> dict[str, Any]:
        return {"draw": tuple(self.terrain.last_draw), "morphed": self.terrain.last_morphed}

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        self.terrain.redraw(viewpoint, decision["draw"], decision["morphed"])
        return self.read_image()

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {"sse": self.terrain.sse, "first_frame_s": self.first_frame_s,
                "first_frame_s_technique": self.first_frame_s_technique,
                **tile_summary(self.terrain)}

    def status(self) -> str:
        return f"sse {self.terrain.sse:g} px; {tile_status(self.terrain)}"

    def outside_mb(self) -> float:
        return reader_mb(self.terrain)

    def release(self) -> None:
        self.terrain.release()


class SpriteAdaptiveTechnique(SpriteTechnique):
    """LOD-sprite with keyframes drawn by the adaptive renderer at ``key_sse`` pixels
    (inline keyframes); it streams between keyframes.  Over a store the coarse proxy,
    ribbons and error metric come from the store's level 0.  Each keyframe's selection is
    recorded; the replay draws it again with the same nodes (their tiles read then)."""

    name = "sprite-adaptive"

    def __init__(self, renderer: Renderer, lod: int = 16, epsilon: float = 1.0,
                 key_sse: float = 1.0, gpu_mb: float = 256.0, host_mb: float = 512.0,
                 visibility: str | None = None, guard_px: int | None = None,
                 border: bool = True) -> None:
        from lodsprite.terrain.store import TerrainStore
        from lodsprite.terrain.storefield import store_field

        self.adaptive = make_adaptive(renderer, key_sse, gpu_mb, host_mb)
        try:
            if isinstance(self.adaptive.tree.p, TerrainStore):
                renderer.paths.geometry.set_full(store_field(self.adaptive.tree.p))
            super().__init__(renderer, lod, epsilon, False, visibility, guard_px, border)
        except BaseException:
            self.adaptive.release()
            raise
        self.sprite.sprite.keyframe_drawer = self.adaptive.render_into
        self.engine.between_keyframes = self.adaptive.prefetch
        self._selections: dict[int, tuple] = {}  # keyframe -> (nodes drawn, morphed)
        self.first_frame_s = float("nan")  # from the process's start

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = super().frame(viewpoint)
        if self.first_frame_s != self.first_frame_s:  # NaN: the first frame
            self.first_frame_s = process_age_s()
        return f

    def decision(self) -> dict[str, Any]:
        """The keyframe shown; for a new one, the selection it was drawn with (recorded
        here, after the frame's clock stopped: nothing draws between the two)."""
        d = super().decision()
        if d["keyframe"] not in self._selections:
            self._selections[d["keyframe"]] = (tuple(self.adaptive.last_draw),
                                               self.adaptive.last_morphed)
        return d

    def replay(self, viewpoint: Viewpoint, decision: dict[str, Any]) -> np.ndarray:
        draw, morphed = self._selections[decision["keyframe"]]
        s = self.sprite.sprite

        def again(vp, projection, target):
            from lodsprite.gl.terrain import FrameStats

            self.adaptive.redraw(vp, draw, morphed, projection, target)
            return FrameStats(0, len(draw), projection)

        s.keyframe_drawer = again
        try:
            return super().replay(viewpoint, decision)
        finally:
            s.keyframe_drawer = self.adaptive.render_into

    def summary(self, frames: list[Frame]) -> dict[str, Any]:
        return {**super().summary(frames), "key_sse": self.adaptive.sse,
                "first_frame_s": self.first_frame_s,
                **tile_summary(self.adaptive)}

    def status(self) -> str:
        return f"keyframes: adaptive, sse {self.adaptive.sse:g} px; {tile_status(self.adaptive)}"

    def outside_mb(self) -> float:
        return reader_mb(self.adaptive)

    def release(self) -> None:
        super().release()
        self.adaptive.release()
