"""What a keyframe worker process is told when it starts (GL-free, no process code): the
settings of its keyframes (:class:`WorkerSettings`) and, over a store, of its adaptive
renderer (:class:`StoreKeys`).  Both the client end
(:mod:`lodsprite.sprite.keyframe_worker`) and the process
(:mod:`lodsprite.sprite.keyframe_process`) read them; neither imports the other for them.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DEFAULT_WORKER_NICE", "StoreKeys", "WorkerSettings"]

DEFAULT_WORKER_NICE = 10
"""The nice increment of a keyframe worker process (the display's process keeps its
priority)."""


@dataclass(frozen=True)
class StoreKeys:
    """Keyframes drawn by the adaptive renderer: the process's request handler
    ``factory`` (``"module:function"``, :mod:`lodsprite.workers`), the terrain ``path``
    (a store the worker process opens, as the drawing side opened it; any other terrain
    is drawn from the arrays handed over), the tolerance ``key_sse`` (pixels), the caches
    ``gpu_mb`` and ``host_mb`` and whether the terrain is shaded from its ``heights``
    (else coloured with the texture); ``clip``: the texture is the store's imagery, its
    finer levels streamed as a clipmap (:mod:`lodsprite.terrain.clipmap`)."""

    factory: str
    path: str
    key_sse: float
    gpu_mb: float
    host_mb: float
    heights: bool
    clip: bool = False


@dataclass(frozen=True)
class WorkerSettings:
    """How the worker renders: image size ``(w, h)`` pixels, vertical field of view
    (degrees), coarse level (quads per side), visibility rule, border ribbons, guard band
    (pixels), predictor name, the nice increment of the worker process and whether the
    keyframes' ``C'`` are for the resampling metric (their matrix and size attached);
    ``store``: keyframes over a store by the adaptive renderer (None: in-memory terrain,
    full resolution); ``tiles``: the keyframe split into ``tiles x tiles`` tiles, each
    request naming those to render (1: whole keyframes); ``key_scale``: keyframe texels a
    display pixel side; ``depth``: keyframes ship the full-resolution z-buffer (the
    drawing side draws them on their own depth), else the ``coarse`` rule's coarse one;
    ``estimate_stride``: each keyframe ships the error estimate on its own depth, built
    by the worker with that many texels between samples (None: none)."""

    size: tuple[int, int]
    fov_y_deg: float
    lod: int
    visibility: str
    border: bool
    guard_px: int
    predictor: str = "linear"
    nice: int = DEFAULT_WORKER_NICE
    resampling: bool = False
    store: StoreKeys | None = None
    tiles: int = 1
    key_scale: float = 1.0
    depth: bool = False
    estimate_stride: int | None = None

    @property
    def key_size(self) -> tuple[int, int]:
        """A keyframe's ``(w, h)`` texels: the image plus the guard band on every side,
        times the keyframe scale (as :attr:`lodsprite.gl.sprite.SpriteDrawer.key_size`)."""
        return tuple(int(round(self.key_scale * (n + 2 * self.guard_px))) for n in self.size)

    @property
    def sprite_px(self) -> tuple[int, int]:
        """A keyframe's size in display pixels, guard band included (the error metric's
        keyframe size, :attr:`lodsprite.gl.sprite.SpriteDrawer.key_px`)."""
        return self.size[0] + 2 * self.guard_px, self.size[1] + 2 * self.guard_px

    @property
    def zbuffer(self) -> str:
        """Whose z-buffer a keyframe ships: ``full`` or ``coarse``."""
        return "coarse" if self.visibility == "coarse" and not self.depth else "full"

    @property
    def answer_bytes(self) -> int:
        """A keyframe's depth (float32) and colour (3 bytes a pixel) together; tiles: their
        depth, RGBA8 colour and coarse depth (float32)."""
        w, h = self.key_size
        return w * h * (12 if self.tiles > 1 else 7)
