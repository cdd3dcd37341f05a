"""The distributed LOD-sprite client as a viewer technique (Swan et al. 2002).

The viewer's ``distributed`` mode: a :class:`~lodsprite.distributed.client.LodClient`
drawing on the viewer's own GL context, with keyframes from a LOD server
(``lodsprite serve``) that loads the same scene.  Made by :func:`distributed_factory`
with the server's address; the viewer core never imports this layer.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.api import Renderer
from lodsprite.camera import Projection, Viewpoint
from lodsprite.distributed.client import DEFAULT_MAX_ERROR, LodClient
from lodsprite.distributed.render import scene_args
from lodsprite.errors import InputError
from lodsprite.scene.spec import describe
from lodsprite.sprite.engine import DEFAULT_EPSILON_PX
from lodsprite.sprite.policy import keyframe_error_px
from lodsprite.techniques import FALLBACK_TINT, Frame, Param, Technique, TechniqueFactory
from lodsprite.terrain.lod import DEFAULT_COARSE

if TYPE_CHECKING:  # hints only: moderngl is imported under gl/
    import moderngl


class DistributedTechnique(Technique):
    """Spriteframes drawn here from keyframes a LOD server renders."""

    name = "distributed"

    #: Whether :meth:`frame` measures the shown keyframe's error (the viewer's HUD); a
    #: batch run leaves it out of the frame's time.
    measure_error = True
    #: Seconds the warm-up waits for a first keyframe (server start-up is not a frame).
    warmup_s = 10.0

    def __init__(self, renderer: Renderer, server: str, lod: int = DEFAULT_COARSE,
                 epsilon_px: float = DEFAULT_EPSILON_PX,
                 max_error: float | None = DEFAULT_MAX_ERROR) -> None:
        super().__init__(renderer)
        scene = renderer.scene
        self.server, self.servers = server, [server]
        args = scene_args(describe(scene), renderer.size, renderer.fov_y_deg)
        self.client = LodClient(scene, args, [server], renderer.size, lod, epsilon=epsilon_px,
                                adopt="better", max_error=max_error, ctx=renderer.gl)

    @classmethod
    def on_client(cls, client: LodClient, servers: list[str]) -> DistributedTechnique:
        """The technique over a client made elsewhere (``lodsprite client``): batch runs
        only, on the client's own GL state (its renderer wraps it), the error left out of
        the frame's time (measured after the run, :meth:`outputs`)."""
        self = cls.__new__(cls)
        Technique.__init__(self, Renderer.wrap(client.terrain_gl))
        self.client, self.server, self.servers = client, ",".join(servers), list(servers)
        self.measure_error = False
        return self

    #: Recorded frames replay: every keyframe shown (a server's or the client's own) is a
    #: function of its logged viewpoint, and every frame a spriteframe drawn from it.
    replays = True
    _shown = -1  # the keyframe the last frame showed (index in client.shown)
    _replayed: int | None = None  # the keyframe the replay drew last

    def warm_up(self, viewpoint: Viewpoint) -> None:
        """Wait (up to :attr:`warmup_s`) for a first keyframe at ``viewpoint``."""
        deadline = time.perf_counter() + self.warmup_s
        while time.perf_counter() < deadline:
            if self.client.frame(viewpoint).kind == "keyframe":
                return
            time.sleep(0.02)

    def summary(self, frames: list[Frame]) -> dict:
        received = sum(f.kind == "keyframe" for f in frames)
        return {"keyframes_received": received,
                "sprites_per_keyframe": (len(frames) - received) / received if received
                else None,
                "local_frames": sum(f.kind.startswith("local") for f in frames),
                "local_keyframes": sum(f.kind == "local_keyframe" for f in frames),
                "rejected_keyframes": self.client.rejected_keyframes}

    def params(self) -> dict[str, Param]:
        bound = self.client.max_error
        return {} if bound is None else {
            "max_error": Param("max_error", bound, 0.25, 256.0, 1.25, "px")}

    def set_param(self, name: str, value: float) -> None:
        if name != "max_error":
            super().set_param(name, value)
        self.client.max_error = float(value)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        f = self.client.frame(viewpoint)
        self._shown = f.extra["keyframe"]
        error = self.client.shown_error_px(viewpoint) if self.measure_error else float("nan")
        return replace(f, error_px=error,
                       extra={**f.extra, "keyframes": len(self.client.shown)})

    def decision(self) -> dict:
        return {"keyframe": self._shown}

    def _key(self, k: int) -> Viewpoint:
        return Viewpoint.from_dict(self.client.shown[k]["viewpoint"])

    def replay(self, viewpoint: Viewpoint, decision: dict) -> np.ndarray:
        """The frame as the client drew it: a spriteframe at ``viewpoint`` from the
        keyframe it showed, rendered here again from that keyframe's logged viewpoint
        through the same projection the server renders with (no guard band)."""
        k, sprite = decision["keyframe"], self.client.sprite
        if k < 0:
            raise InputError("a frame that showed no keyframe cannot be replayed")
        if k != self._replayed:
            sprite.render_keyframe(self._key(k), 0.0)
            self._replayed = k
        sprite.render_spriteframe(viewpoint)
        return sprite.target.read_color()

    def quality_extra(self, viewpoint: Viewpoint, decision: dict,
                      truth: np.ndarray) -> dict[str, float]:
        """The plain coarse level beside it (:func:`lodsprite.techniques.terrain.
        coarse_baseline`)."""
        from lodsprite.techniques.terrain import coarse_baseline

        return coarse_baseline(self.client.terrain_gl.drawer, viewpoint,
                               self.client.sprite.coarse_quads, truth)

    def replayed_errors(self, viewpoints: list[Viewpoint], decisions: list[dict]) -> np.ndarray:
        """The error metric (Chen, Swan & Kaufman 1999, Eq. 2, pixels) of each recorded
        frame against the keyframe it showed, measured untimed after the run: ``(frames,)
        float64``, NaN where a frame showed none, ``inf`` where nothing was measurable."""
        metric, r = self.client.metric, self.client.terrain_gl.drawer
        c_primes: dict[int, np.ndarray] = {}
        out = np.full(len(decisions), np.nan)
        for i, (vp, d) in enumerate(zip(viewpoints, decisions, strict=True)):
            k = d["keyframe"]
            if k < 0:
                continue
            if k not in c_primes:
                c_primes[k] = metric.reproject(self._key(k).o)
            out[i] = keyframe_error_px(metric, c_primes[k], vp, r.projection(vp),
                                       r.target.height)
        return out

    def outputs(self, result, path) -> dict:
        """After a batch run: each frame's error metric against the keyframe it showed
        (``error_px``, :meth:`replayed_errors`) and its figures in the summary
        (:func:`~lodsprite.distributed.quality.error_summary`); the files:
        ``server_stats.json`` (the servers' own timings) and ``keyframes.json`` (every
        keyframe shown)."""
        from lodsprite.distributed.quality import error_summary

        errors = self.replayed_errors(path.viewpoints[:len(result.decisions)],
                                      result.decisions)
        for row, e in zip(result.rows, errors, strict=True):
            row["error_px"] = float(e)
        figures = error_summary(errors, self.client.epsilon_px)
        del figures["per_frame_error_px"]  # frames.csv's error_px column
        stats = self.client.server_stats()
        result.summary.update(figures, **server_means(stats), interrupted=result.interrupted)
        return {"server_stats.json": {"servers": self.servers, "stats": stats},
                "keyframes.json": {"servers": self.servers, "keyframes": self.client.shown}}

    def draw_to(self, framebuffer: moderngl.Framebuffer | None = None) -> None:
        target = self.client.terrain_gl.drawer.target
        self.renderer.present(target.color, (0.0, 0.0, 1.0, 1.0), framebuffer, target.fbo)

    def read_image(self) -> np.ndarray:
        return self.client.image()

    def key_view(self) -> tuple[Viewpoint, Projection] | None:
        key = self.client.sprite.keyframe
        return None if key is None else (key.viewpoint, key.projection)

    def coarse_level(self) -> int | None:
        return self.client.sprite.coarse_quads

    def set_fallback_tint(self, on: bool) -> None:
        self.client.sprite.fallback_tint = FALLBACK_TINT if on else (*FALLBACK_TINT[:3], 0.0)

    def status(self) -> str:
        alive = self.client.links_alive[0]
        state = {True: "answers", False: "silent", None: "connecting"}[alive]
        return (f"server {self.server}: {state}; own keyframes {self.client.local_keyframes}, "
                f"rejected {self.client.rejected_keyframes}")

    def release(self) -> None:
        self.client.close()


def distributed_factory(server: str, lod: int = DEFAULT_COARSE,
                        epsilon_px: float = DEFAULT_EPSILON_PX,
                        max_error: float | None = DEFAULT_MAX_ERROR) -> TechniqueFactory:
    """A factory of :class:`DistributedTechnique` for the viewer's ``distributed`` mode."""
    return lambda renderer: DistributedTechnique(renderer, server, lod, epsilon_px, max_error)


def create(renderer: Renderer, server: str, lod: int = DEFAULT_COARSE,
           epsilon: float = DEFAULT_EPSILON_PX,
           max_error: float | None = DEFAULT_MAX_ERROR) -> DistributedTechnique:
    """The registry's factory of ``distributed`` (:mod:`lodsprite.techniques.builtin`)."""
    if not server:
        raise InputError("the distributed technique needs a server (HOST:PORT)")
    return DistributedTechnique(renderer, server, lod, epsilon, max_error)


def _mean(values) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def server_means(stats: list[dict]) -> dict:
    """The servers' mean times per stage (ms) from their statistics."""
    server = {k: _mean([v for s in stats for v in s.get(k, [])])
              for k in ("production_ms", "viewpoint_wait_ms", "paced_ms", "render_ms",
                        "queue_insert_ms", "delta_t_ms", "queue_retrieve_ms",
                        "transmission_ms")}
    return {f"{k.removesuffix('_ms')}_ms_mean": v for k, v in server.items()}
