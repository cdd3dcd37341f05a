"""LOD-sprite with keyframes from a worker process: the drawing loop only draws
spriteframes (Chen et al. 1999 §3.1 step 3, as the 2002 client does) and never waits for
a keyframe after the first; the keyframes come from a
:class:`~lodsprite.sprite.keyframe_worker.KeyframeWorker` (the 2002 LOD server, as a
process with its own GL context).

Per frame, in the drawing loop:

1. take the worker's newest keyframe, if one arrived, and adopt it when its error at the
   current viewpoint (Eq. 2, pixels) is below the shown keyframe's (the ``--adopt better``
   rule of the distributed client); a worse one is discarded;
2. measure the shown keyframe's error here; at ``request_fraction`` ε or more, ask the
   worker for the next keyframe, placed ahead by the measured request-to-adoption latency;
3. draw the spriteframe and ``finish()``.

Over a terrain store (``store``, keyframes drawn by the worker's own adaptive renderer,
:mod:`lodsprite.techniques.adaptive_worker`) a keyframe's error adds what it lacks
(:attr:`~lodsprite.sprite.keyframe_worker.KeyframeImage.deficit_px`, pixels: the tiles its
tolerance needs that had not arrived when it was drawn), at every frame it is shown, so
the next one is asked for while tiles stream and a held view sharpens as they arrive;
each adopted keyframe's adaptive selection is kept (:attr:`WorkerLodSpriteEngine.
selections`) for the untimed replay.

The bound ε is kept only as well as the worker keeps up: while a keyframe is on its way,
the error of the frames shown can exceed ε (reported per frame), but the frame rate does
not drop.  :class:`~lodsprite.sprite.engine.LodSpriteEngine` is the inline alternative.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError, LodspriteError
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.record import Frame
from lodsprite.sprite.adoption import AdoptionRule
from lodsprite.sprite.depth_metric import DepthReprojection
from lodsprite.sprite.engine import sprite_frame
from lodsprite.sprite.keyframe_worker import KeyframeImage, KeyframeWorker
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import (
    DEFAULT_EPSILON_PX,
    FIRST_SPRITE,
    KEYFRAME,
    SPRITE,
    KeyChoice,
    keyframe_error_px,
    resampling_metric,
)
from lodsprite.sprite.worker_settings import StoreKeys, WorkerSettings

if TYPE_CHECKING:  # the scene is passed in
    from lodsprite.scene import Scene

DEFAULT_REQUEST_FRACTION = 0.5
#: A worker keyframe replaces the shown one when its error at the viewpoint shown is lower
#: (a late one, aimed where the viewer was going, can be worse).
ADOPT_BETTER = AdoptionRule("better")


class WorkerLodSpriteEngine:
    """LOD-sprite frame by frame with a :class:`~lodsprite.sprite.keyframe_worker.KeyframeWorker`.

    ``sprite`` draws the spriteframes on the caller's context; ``scene`` is what the worker
    process loads on its own context (its height field and texture); ``fov_y_deg`` must be
    the renderer's; ``store``: keyframes over a terrain store, drawn adaptively by the
    worker (None: in-memory terrain at full resolution).  A worker that cannot start raises
    :class:`~lodsprite.procs.WorkerUnavailable` here; one that dies makes the next
    :meth:`frame` raise :class:`~lodsprite.errors.LodspriteError`.
    """

    def __init__(self, sprite: SpriteDrawer, scene: Scene, fov_y_deg: float,
                 epsilon_px: float = DEFAULT_EPSILON_PX,
                 request_fraction: float = DEFAULT_REQUEST_FRACTION,
                 predictor: str = "linear", metric: str = "warp",
                 store: StoreKeys | None = None, make_worker=None) -> None:
        self.sprite = sprite
        self.epsilon_px = float(epsilon_px)
        self.request_fraction = float(request_fraction)
        resampling = resampling_metric(metric)
        self.depth = None  # (stride, key scale) when the estimate on keyframe depth decides
        if metric == "depth":  # refused before the worker process starts
            if sprite.depth_mesh is None:
                raise InputError("the depth metric judges the keyframe's own depth mesh: "
                                 "it needs --proxy depth")
            self.depth = (sprite.depth_mesh.stride, sprite.key_scale)
        hf = sprite.terrain.geometry.full  # the terrain, or a store's level 0
        self.metric = ErrorMetric.for_level(hf, sprite.coarse_quads, resampling)
        # make_worker(scene, settings): another client end (a scene's); default the terrain's
        self.worker = (make_worker or KeyframeWorker)(scene, WorkerSettings(
            sprite.target.size, fov_y_deg, sprite.coarse_quads, sprite.visibility,
            sprite.border, sprite.guard_px, predictor, resampling=resampling, store=store,
            key_scale=sprite.key_scale, depth=sprite.depth_mesh is not None,
            estimate_stride=None if self.depth is None else self.depth[0]))
        self.keyframes: list[KeyChoice] = []
        # per adopted keyframe, over a store: the adaptive selection it was drawn with
        self.selections: list[tuple | None] = []
        self.deficit_px = 0.0  # what the shown keyframe lacks (pixels)
        self.discarded = 0
        self._c_prime: np.ndarray | None = None

    def error_px(self, viewpoint: Viewpoint, projection) -> float:
        """Error (pixels) of the shown keyframe at ``viewpoint`` (inf before the first):
        the metric's, plus what the keyframe lacks (its ``C'``'s ``deficit_px``)."""
        if self._c_prime is None:
            return float("inf")
        return keyframe_error_px(self.metric, self._c_prime, viewpoint, projection,
                                 self.sprite.target.height)

    def judged(self, key: KeyframeImage) -> KeyframeImage:
        """``key`` with its ``C'`` the estimate on its own (shipped) depth, weighted by
        its colour's contrast, when that decides (:mod:`lodsprite.sprite.depth_metric`;
        built by the worker and shipped with the keyframe)."""
        if self.depth is None or key.zbuffer != "full":
            return key
        if key.estimate is None:
            raise LodspriteError("the keyframe worker shipped no depth estimate")
        c_prime = DepthReprojection(key.c_prime)
        c_prime.estimate = key.estimate  # built by the worker, off this loop's clock
        c_prime.deficit_px = getattr(key.c_prime, "deficit_px", 0.0)
        return replace(key, c_prime=c_prime)

    def _adopt(self, key: KeyframeImage, now: float) -> None:
        self.sprite.upload_keyframe(key.viewpoint, key.projection, key.color, key.depth, now,
                                    key.zbuffer)
        self._c_prime, self.deficit_px = key.c_prime, key.deficit_px
        self.keyframes.append(KeyChoice(key.viewpoint, key.frame_projection, key.predicted))
        self.selections.append(key.selection)

    def frame(self, viewpoint: Viewpoint) -> Frame:
        """Draw the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        if self.worker.error is not None:  # no keyframe will ever come: say so
            raise LodspriteError(f"the keyframe worker stopped: {self.worker.error}")
        self.worker.observe(t0, viewpoint)
        projection = self.sprite.terrain.projection(viewpoint)
        kind = SPRITE
        if self._c_prime is None:  # start-up: the first keyframe is waited for
            self.worker.request()
            self._adopt(self.judged(self.worker.wait()), t0)
            kind = KEYFRAME
        error = self.error_px(viewpoint, projection)
        new = None if kind == KEYFRAME else self.worker.poll()
        if new is not None:
            new = self.judged(new)
            self.worker.measure_lead(new.requested_at, t0)
            new_error = keyframe_error_px(self.metric, new.c_prime, viewpoint, projection,
                                          self.sprite.target.height)
            if ADOPT_BETTER.adopt(lambda: error, lambda: new_error):
                self._adopt(new, t0)
                kind, error = FIRST_SPRITE, new_error
            else:
                self.discarded += 1
        if not error < self.request_fraction * self.epsilon_px:
            self.worker.request()
        stats = self.sprite.render_spriteframe(viewpoint, projection)
        self.sprite.terrain.ctx.finish()
        return sprite_frame(kind, (time.perf_counter() - t0) * 1e3, stats.triangles, error,
                            len(self.keyframes) - 1, error)

    def read_image(self) -> np.ndarray:
        """The last frame, ``(H, W, 3) uint8``, row 0 at the top (always a spriteframe)."""
        return self.sprite.target.read_color()

    def close(self) -> None:
        """End the worker process (its context and GL objects go with it)."""
        self.worker.close()
