"""Tiled keyframes from a worker process: Qu, Wan, Qin & Kaufman (2000)'s part of the
image re-rendered, with Swan et al. (2002)'s split, the parts rendered beside the
drawing loop (:class:`~lodsprite.sprite.keyframe_worker.KeyframeWorker` with
:attr:`~lodsprite.sprite.worker_settings.WorkerSettings.tiles`).

Per frame, in the drawing loop (never waiting after the first update):

1. the error of every tile at the current viewpoint (Chen et al. 1999 Eq. 1-2 per tile,
   :func:`~lodsprite.sprite.tiled.tile_errors`);
2. the tiles the worker finished, if any, each adopted when its error at the current
   viewpoint (the update's tiles all put in, :func:`adopted`) is below the error of the
   render it replaces; the others are discarded;
3. a request, when none is on its way, for every tile at or over ``request_fraction``
   ε, placed ahead by the measured request-to-delivery latency as whole keyframes are
   (:mod:`lodsprite.sprite.worker_engine`): the fewer tiles stale, the smaller and
   sooner the update;
4. the tiled spriteframe, and ``finish()``.

The worker renders a tile update as the inline tiled engine renders one (each tile
scissored, culled by its sub-frustum, the update's ``C'`` reprojected for those tiles'
sub-frustum) and answers each tile's depth, colour and coarse z-buffer; the drawing side
writes them into its mosaic (:meth:`~lodsprite.gl.sprite_tiles.TiledSpriteDrawer.
upload_tile`).  Every adopted update is logged as the inline engine
logs its own (:attr:`~lodsprite.sprite.tiled_engine.TiledSpriteEngine.updates`,
``mosaic``), so the untimed replay renders each tile again from the viewpoint it was
rendered from.  The first update (every tile) is waited for.

Over a terrain store (``store``: the worker's own adaptive renderer draws each tile,
:mod:`lodsprite.techniques.adaptive_worker`) each tile comes with what it lacks (the
tiles its tolerance needs that had not arrived, pixels), added to its error at every
frame so that it is asked for again while they stream, and with the selection it was
drawn with (:attr:`WorkerTiledEngine.selections`), which the replay draws again.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import LodspriteError
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.record import Frame
from lodsprite.sprite.engine import sprite_frame
from lodsprite.sprite.keyframe_worker import KeyframeWorker, TileUpdate
from lodsprite.sprite.policy import KEYFRAME, SPRITE, KeyChoice, resampling_metric
from lodsprite.sprite.tiled import TILES, combined_error, tile_errors
from lodsprite.sprite.tiled_engine import TiledSpriteEngine
from lodsprite.sprite.worker_engine import DEFAULT_REQUEST_FRACTION
from lodsprite.sprite.worker_settings import StoreKeys, WorkerSettings

if TYPE_CHECKING:  # the scene is passed in
    from lodsprite.scene import Scene


def adopted(current: np.ndarray, candidate: np.ndarray, tiles: Sequence[int]) -> np.ndarray:
    """The tiles of an update to adopt: those of ``tiles`` whose ``candidate (T,)`` error
    (px, the update put in) is below their ``current (T,)`` one (a tile never rendered,
    ``inf``, always); ``(k,) intp``."""
    tiles = np.asarray(tiles, np.intp)
    return tiles[(candidate[tiles] < current[tiles]) | ~np.isfinite(current[tiles])]


class WorkerTiledEngine(TiledSpriteEngine):
    """LOD-sprite with ``tiles x tiles`` tiles rendered by a keyframe worker (module
    docstring).  ``scene``, ``fov_y_deg``, ``predictor`` and ``make_worker`` as
    :class:`~lodsprite.sprite.worker_engine.WorkerLodSpriteEngine`'s; :attr:`last_tiles`
    lists the tiles adopted in the last frame, :attr:`discarded` counts tiles delivered
    and not adopted."""

    def __init__(self, sprite: SpriteDrawer, scene: Scene, fov_y_deg: float, epsilon_px: float,
                 tiles: int, request_fraction: float = DEFAULT_REQUEST_FRACTION,
                 predictor: str = "linear", metric: str = "warp", store: StoreKeys | None = None,
                 make_worker=None) -> None:
        super().__init__(sprite, epsilon_px, tiles, 0.0, metric)
        self.request_fraction = float(request_fraction)
        self.discarded = 0
        # what each tile's render lacks (pixels, over a store), added to its error
        self.deficits = np.zeros(self.tiled.count)
        self.selections: dict[tuple[int, int], tuple] = {}  # (update, tile) -> selection
        try:
            self.worker = (make_worker or KeyframeWorker)(scene, WorkerSettings(
                sprite.target.size, fov_y_deg, sprite.coarse_quads, sprite.visibility,
                sprite.border, sprite.guard_px, predictor,
                resampling=resampling_metric(metric), store=store, tiles=tiles,
                key_scale=sprite.key_scale))
        except BaseException:
            self.tiled.release()
            raise

    def _errors(self, viewpoint: Viewpoint, c_primes: list, key_vps: np.ndarray,
                deficits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(errors (T,) px, served (T,))`` at ``viewpoint`` of tiles showing renders
        with these ``C'``, key view-projections and deficits (px, added)."""
        s = self.sprite
        projection = s.terrain.projection(viewpoint)
        key = s.key_projection(projection)
        errors, served = tile_errors(
            self.metric, c_primes, key_vps, self.tiled.ndc, viewpoint.o,
            projection.matrix() @ viewpoint.view_matrix(),
            key.matrix() @ viewpoint.view_matrix(),
            projection.pixel_angle_rad(s.target.height), s.target.size)
        return errors + deficits, served

    def errors(self, viewpoint: Viewpoint) -> tuple[np.ndarray, np.ndarray]:
        """The tiles' errors at ``viewpoint``, what each render lacks included."""
        return self._errors(viewpoint, self.c_primes, self.tiled.view_projs, self.deficits)

    def _candidate_errors(self, update: TileUpdate, viewpoint: Viewpoint
                          ) -> tuple[np.ndarray, np.ndarray]:
        """The tiles' ``(errors, served)`` at ``viewpoint`` with ``update``'s tiles put
        in."""
        c_primes, key_vps = list(self.c_primes), self.tiled.view_projs.copy()
        deficits = self.deficits.copy()
        key_vp = update.projection.matrix() @ update.viewpoint.view_matrix()
        for k, i in enumerate(update.tiles):
            c_primes[i], key_vps[i] = update.c_prime, key_vp
            deficits[i] = update.deficits[k] if update.deficits else 0.0
        return self._errors(viewpoint, c_primes, key_vps, deficits)

    def _adopt(self, update: TileUpdate, take: np.ndarray) -> None:
        """Write the tiles ``take`` of ``update`` into the mosaic, then log the update
        (an upload that raises logs nothing)."""
        u = len(self.updates)
        at = {t: k for k, t in enumerate(update.tiles)}
        for i in take:
            k = at[int(i)]
            self.tiled.upload_tile(int(i), update.viewpoint, update.projection,
                                   update.depth[k], update.color[k], update.coarse[k])
        self.updates.append(KeyChoice(update.viewpoint, update.frame_projection,
                                      update.predicted))
        self.frozen_for.append(u)
        self.proxy_selections.append(None)
        for i in take:
            k = at[int(i)]
            self.c_primes[i] = update.c_prime
            self.deficits[i] = update.deficits[k] if update.deficits else 0.0
            if update.selections:
                self.selections[(u, int(i))] = update.selections[k]
        self.mosaic[take] = self.newest[take] = u

    @staticmethod
    def _checked(update) -> TileUpdate:
        """``update`` if it carries tiles; a whole keyframe answered to a tile request
        raises :class:`~lodsprite.errors.LodspriteError`."""
        if not isinstance(update, TileUpdate):
            raise LodspriteError("the keyframe worker answered a whole keyframe to a tile "
                                 "request")
        return update

    def _take(self, viewpoint: Viewpoint, both: list, t0: float) -> np.ndarray:
        """The tiles adopted from a finished update (none if none arrived); ``both``,
        the tiles' ``[errors, served]`` at ``viewpoint``, updated in place."""
        update = self.worker.poll()
        if update is None:
            return np.empty(0, np.intp)
        self.worker.measure_lead(self._checked(update).requested_at, t0)
        candidate = self._candidate_errors(update, viewpoint)
        take = adopted(both[0], candidate[0], update.tiles)
        self.discarded += len(update.tiles) - len(take)
        if len(take):
            self._adopt(update, take)
            both[:] = candidate if len(take) == len(update.tiles) else self.errors(viewpoint)
        return take

    def frame(self, viewpoint: Viewpoint) -> Frame:
        """Draw the frame for ``viewpoint``; returns once the GL work has finished."""
        t0 = time.perf_counter()
        if self.worker.error is not None:
            raise LodspriteError(f"the keyframe worker stopped: {self.worker.error}")
        self.worker.observe(t0, viewpoint)
        if not self.updates:  # start-up: every tile, waited for
            self.worker.request(tuple(range(self.tiled.count)))
            update = self._checked(self.worker.wait())
            self._adopt(update, np.asarray(update.tiles, np.intp))
            take, kind = np.asarray(update.tiles, np.intp), KEYFRAME
            errors, served = self.errors(viewpoint)
        else:
            both = list(self.errors(viewpoint))
            take = self._take(viewpoint, both, t0)
            errors, served = both
            kind = TILES if len(take) else SPRITE
        stale = np.flatnonzero(~(errors < self.request_fraction * self.epsilon_px))
        if len(stale):
            self.worker.request(tuple(int(i) for i in stale))
        self.last_tiles = tuple(int(i) for i in take)
        self._shows_keyframe = False
        tris = self.tiled.render_spriteframe(viewpoint).triangles
        self.sprite.terrain.ctx.finish()
        shown = combined_error(errors, served)
        return sprite_frame(kind, (time.perf_counter() - t0) * 1e3, tris, shown,
                            len(self.updates) - 1, shown)

    def release(self) -> None:
        """End the worker process, then release the tiled drawer."""
        self.worker.close()
        super().release()
