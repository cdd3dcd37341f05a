"""Imagery finer than one texture: a clipmap around the eye (Tanner, Migdal & Jones 1998,
"The Clipmap: A Virtual Mipmap"), streamed from a terrain store (GL-free: what to hold;
:mod:`lodsprite.gl.clipmap` holds it on the GPU).

The whole imagery is one mipmapped texture of at most :data:`~lodsprite.scene.model.
IMAGERY_SIDE` texels a side (its level ``J``).  Every finer level ``j < J`` is *clipped*:
only a window of ``side x side`` texels of it is held, around the point of the ground
under the eye, chunk-aligned.  A window's texels live in one layer of a texture array
addressed toroidally (chunk ``(cr, cc)`` of level ``j`` in slot ``(cr mod n, cc mod n)``,
``n = side / chunk``), so moving the window replaces only the chunks that enter it; a
table per layer records which chunk each slot holds, so a fragment samples a level only
where the chunks its bilinear footprint touches are resident, and a coarser one (in the
end the whole texture) elsewhere.  The level is chosen per fragment from the texels'
screen size, not from the geometry's level: flat ground near the eye keeps level 0's
texels.

Chunks are read by the terrain store's reader process (:mod:`lodsprite.terrain.reader`,
never a thread: moderngl holds the GIL through the draws); :meth:`Clipmap.pump` collects
what arrived without waiting and sends the next wishes (coarse levels first, nearest the
window's centre first), at most ``in_flight`` at a time.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.terrain.store_format import level_shape


def premultiplied(block: np.ndarray) -> np.ndarray:
    """``(h, w, 4) uint8`` RGBA with its colour multiplied by its alpha (so that bilinear
    filtering across a coverage edge does not darken it: the shader blends ``rgb + base *
    (1 - a)``)."""
    a = block[..., 3:4].astype(np.uint16)
    out = block.copy()
    out[..., :3] = (block[..., :3].astype(np.uint16) * a + 127) // 255
    return out


CLIP_SIDE = 1024  # texels a side of a clip level's window (a multiple of the chunk)
IN_FLIGHT = 8


class Clipmap:
    """The clip levels of ``store``'s imagery finer than ``whole_side`` texels a side.

    ``levels``: the imagery levels clipped, finest first; ``side``: texels a window side;
    ``chunk``: the store's chunk side; ``origins``: per clip level the window's first
    texel ``(row, col)`` of its level."""

    def __init__(self, store, whole_side: int, side: int = CLIP_SIDE,
                 in_flight: int = IN_FLIGHT, worker=None) -> None:
        im = store.imagery
        self.chunk = int(store.chunk)
        self.side = max(self.chunk, side // self.chunk * self.chunk)
        self.slots = self.side // self.chunk
        self.rows, self.cols = im.rows, im.cols
        from lodsprite.terrain.store_imagery import level_for

        self.levels = list(range(level_for(store.header, whole_side)))  # finer than it
        self.shapes = [level_shape(im.rows, im.cols, j) for j in self.levels]
        self.origins = [(0, 0)] * len(self.levels)
        # per clip level, slot (sr, sc) -> the chunk (cr, cc) it holds
        self.held: list[dict[tuple[int, int], tuple[int, int]]] = [{} for _ in self.levels]
        self.wishes: list[tuple[int, int, int]] = []  # (clip level, cr, cc)
        self.failed: set[tuple[int, int, int]] = set()  # unreadable: never asked again
        if worker is None and self.levels:
            from lodsprite.terrain.reader import reader_worker

            worker = reader_worker(store.path, store.exaggeration, in_flight)
        self.worker = worker

    def __len__(self) -> int:
        return len(self.levels)

    def centre(self, row0: float, col0: float) -> None:
        """Centre every window on level 0's texel ``(row0, col0)`` (the ground under the
        eye) and make the wish list: the window's chunks not held, coarse levels first,
        nearest the centre first."""
        wishes = []
        for li, (j, (rows, cols)) in enumerate(zip(self.levels, self.shapes, strict=True)):
            n_r, n_c = -(-rows // self.chunk), -(-cols // self.chunk)
            cr_c, cc_c = row0 / (1 << j) / self.chunk, col0 / (1 << j) / self.chunk
            cr0 = int(min(max(0, round(cr_c - self.slots / 2)), max(0, n_r - self.slots)))
            cc0 = int(min(max(0, round(cc_c - self.slots / 2)), max(0, n_c - self.slots)))
            self.origins[li] = (cr0 * self.chunk, cc0 * self.chunk)
            held = self.held[li]
            for cr in range(cr0, min(n_r, cr0 + self.slots)):
                for cc in range(cc0, min(n_c, cc0 + self.slots)):
                    if (held.get((cr % self.slots, cc % self.slots)) != (cr, cc)
                            and (li, cr, cc) not in self.failed):
                        d = math.hypot(cr + 0.5 - cr_c, cc + 0.5 - cc_c)
                        wishes.append((-li, d, li, cr, cc))
        wishes.sort()
        self.wishes = [(li, cr, cc) for _, _, li, cr, cc in wishes]

    def pump(self) -> list[tuple[int, int, int, np.ndarray]]:
        """What arrived since the last call, ``(clip level, slot row, slot col, (h, w, 4)
        uint8)`` each, premultiplied (recorded as held: upload them before drawing), and
        the next wishes sent; a chunk the reader cannot read is never asked again.  Never
        waits."""
        from lodsprite.terrain.reader import imagery_answer, imagery_request

        if self.worker is None:
            return []
        out = []
        for (li, cr, cc), answer in self.worker.poll():
            block = imagery_answer(answer)
            if isinstance(block, str):  # the coarser levels stand in for it
                self.failed.add((li, cr, cc))
                continue
            slot = (cr % self.slots, cc % self.slots)
            self.held[li][slot] = (cr, cc)
            out.append((li, *slot, premultiplied(block)))
        pending = set(self.worker.pending)
        while self.wishes and not self.worker.full:
            li, cr, cc = self.wishes.pop(0)
            if (li, cr, cc) in pending:
                continue
            rows, cols = self.shapes[li]
            r0, c0 = cr * self.chunk, cc * self.chunk
            self.worker.submit((li, cr, cc), imagery_request(
                self.levels[li], r0, min(rows, r0 + self.chunk), c0, min(cols, c0 + self.chunk)))
        return out

    @property
    def bad(self) -> int:
        """Chunks the reader could not read (drawn from coarser levels)."""
        return len(self.failed)

    def idle(self) -> bool:
        """Nothing wished for and nothing in flight."""
        return not self.wishes and (self.worker is None or not self.worker.pending)

    def tables(self) -> np.ndarray:
        """``(levels, slots, slots) int32``: per slot the chunk it holds, ``cr * 65536 +
        cc + 1`` (0: none), for the shader's residency test."""
        t = np.zeros((len(self.levels), self.slots, self.slots), np.int32)
        for li, held in enumerate(self.held):
            for (sr, sc), (cr, cc) in held.items():
                t[li, sr, sc] = cr * 65536 + cc + 1
        return t

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
            self.worker = None
