"""The LODManager of Gumbau, Ripolles & Chover (§4), GL-free.

* :func:`slot_of` - the snapshot slot of a LOD factor, ``trunc(g(lod) · N_T)`` with ``g``
  the identity (§4, linear snapshots) or a user distribution (§4.3, Figure 4).
* :func:`similar` - Eq. 1: two LOD factors are similar when they fall in the same slot.
* :func:`desired_lod` - §4.2: linear in camera distance between ``range_near`` (1) and
  ``range_far`` (0), clamped, then bent to ``lod ** p`` by the frame-rate feedback
  (:class:`Feedback`: ``p > 1`` is the paper's ``lod^n``, coarser, ``p < 1`` its
  ``lod^(1/n)``, finer).
* :func:`active_list` - §4.2: the ``N_a`` objects whose desired and current LOD differ
  most, objects outside the frustum penalised.
* :class:`LodManager` - §4.1 steps 1-2(d) over the active list: discard similar changes;
  look up ``D_T[slot(dlod)]``; borrow that LOD's index buffer if it is similar, or extract
  a new one into the object's own buffer and register it.  With ``share=False`` it is
  baseline (a): the same buckets, active list and feedback, but every change extracts.

Index buffers are numbered; the manager decides, its caller extracts (real work) and
uploads.  ``D_T`` holds LODs (index buffers) rather than objects: an object that extracts
while others borrow its own buffer takes a fresh buffer of its own, so that a borrower's
geometry never changes under it (the paper's rule that an object "must update its own
index buffer, not the borrowed one", applied to the lender too), and the old LOD stays in
``D_T`` for later borrowers while it is drawn.  Step 2(d) ii. (an object that borrows
leaves ``D_T``) keeps the paper's intent, no entry for a LOD nobody shows: an object's own
LOD leaves ``D_T`` when the object borrows another and no other object draws it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lodsprite.errors import InputError

Distribution = Callable[[np.ndarray], np.ndarray]


def linear(lod: np.ndarray) -> np.ndarray:
    """The linear snapshot distribution (§4)."""
    return lod


def finer_near(lod: np.ndarray) -> np.ndarray:
    """A non-linear distribution (§4.3): slots get narrower towards LOD 1 (close
    objects), ``g(x) = x²``."""
    return np.asarray(lod, dtype=np.float64) ** 2


def slot_of(lod, n_slots: int, dist: Distribution = linear) -> np.ndarray:
    """``trunc(g(lod) · N_T)``, clamped to ``N_T - 1`` so that LOD 1 has a slot; ``lod``
    scalar or array in [0, 1]."""
    g = np.clip(np.asarray(dist(np.clip(np.asarray(lod, np.float64), 0.0, 1.0))), 0.0, 1.0)
    return np.minimum((g * n_slots).astype(np.int64), n_slots - 1)


def similar(lod_a, lod_b, n_slots: int, dist: Distribution = linear) -> np.ndarray:
    """Eq. 1 (with the distribution of §4.3)."""
    return slot_of(lod_a, n_slots, dist) == slot_of(lod_b, n_slots, dist)


def desired_lod(distance: np.ndarray, range_near: float, range_far: float,
                exponent: float = 1.0) -> np.ndarray:
    """§4.2: ``1 - (d - near) / (far - near)`` clamped to [0, 1], to the power
    ``exponent`` (the feedback's bend)."""
    lod = 1.0 - (np.asarray(distance, np.float64) - range_near) / (range_far - range_near)
    return np.clip(lod, 0.0, 1.0) ** exponent


@dataclass
class Feedback:
    """Frame-rate feedback on the LOD exponent: under the target frame rate the exponent
    grows (``lod^n``, coarser), over it it shrinks (``lod^(1/n)``, finer); each frame moves
    ``log p`` by ``gain · log(frame_ms / target_ms)``, within ``[1/n_max, n_max]``."""

    target_fps: float | None = None
    gain: float = 0.15
    n_max: float = 8.0
    exponent: float = 1.0

    def __post_init__(self) -> None:
        if self.target_fps is not None and not (self.target_fps > 0):
            raise InputError(f"--target-fps must be > 0, got {self.target_fps}")

    def observe(self, frame_ms: float) -> float:
        """One frame's time (ms); returns the new exponent."""
        if self.target_fps is None or not (frame_ms > 0):
            return self.exponent
        log_p = np.log(self.exponent) + self.gain * np.log(frame_ms * self.target_fps / 1e3)
        self.exponent = float(np.exp(np.clip(log_p, -np.log(self.n_max), np.log(self.n_max))))
        return self.exponent


def active_list(desired: np.ndarray, current: np.ndarray, visible: np.ndarray, n_active: int,
                n_slots: int, penalty: float = 0.25, dist: Distribution = linear
                ) -> np.ndarray:
    """§4.2's active list A: the (at most) ``n_active`` objects whose desired LOD is not
    similar to their current one, by ``|desired - current|`` (times ``penalty`` outside the
    frustum), largest first."""
    need = slot_of(desired, n_slots, dist) != slot_of(current, n_slots, dist)
    value = np.abs(np.asarray(desired) - np.asarray(current)) * np.where(visible, 1.0, penalty)
    cand = np.flatnonzero(need)
    if len(cand) > n_active:
        cand = cand[np.argpartition(-value[cand], n_active - 1)[:n_active]]
    return cand[np.argsort(-value[cand], kind="stable")]


@dataclass(frozen=True)
class Extraction:
    """An order to the caller: extract ``type_index``'s LOD at factor ``lod`` into index
    buffer ``buffer`` (for object ``obj``)."""

    obj: int
    type_index: int
    lod: float
    buffer: int


@dataclass
class LodManager:
    """§4.1 over objects of ``n_types`` types (``types (N,) int``), ``n_slots`` snapshots a
    type.  Every object starts on its type's base buffer (buffers ``0..n_types-1``, the
    LOD ``base_lod``, extracted by the caller once); :meth:`update` returns the extractions
    to perform."""

    types: np.ndarray
    n_types: int
    n_slots: int
    base_lod: float = 0.0
    share: bool = True
    dist: Distribution = linear
    lod: np.ndarray = field(init=False)        # lodf(V_i): the LOD each object shows
    using: np.ndarray = field(init=False)      # the index buffer each object draws
    own: np.ndarray = field(init=False)        # each object's own buffer (-1: none yet)
    slots: np.ndarray = field(init=False)      # D_T: (n_types, n_slots) buffer or -1

    def __post_init__(self) -> None:
        if self.n_slots < 1:
            raise InputError(f"--slots must be at least 1, got {self.n_slots}")
        self.types = np.asarray(self.types, dtype=np.int64)
        n = len(self.types)
        self.lod = np.full(n, float(self.base_lod))
        self.using = self.types.copy()
        self.own = np.full(n, -1, dtype=np.int64)
        self.slots = np.full((self.n_types, self.n_slots), -1, dtype=np.int64)
        self.buffer_lod = [float(self.base_lod)] * self.n_types  # by buffer id
        self.buffer_type = list(range(self.n_types))
        self.users = [int(np.count_nonzero(self.types == t)) for t in range(self.n_types)]
        self.free: list[int] = []
        self.extractions = 0
        self.borrows = 0
        for t in range(self.n_types):
            self.slots[t, self.slot(self.base_lod)] = t

    def slot(self, lod: float) -> int:
        return int(slot_of(lod, self.n_slots, self.dist))

    def update(self, active: np.ndarray, desired: np.ndarray) -> list[Extraction]:
        """§4.1 steps 1-2(d) for the objects in ``active`` (their desired LOD factors in
        ``desired``, indexed by object)."""
        orders = []
        for i in (int(x) for x in active):
            d = float(desired[i])
            s = self.slot(d)
            if s == self.slot(self.lod[i]):                     # 1. similar: no change
                continue
            t = int(self.types[i])
            f = int(self.slots[t, s])                            # 2(a) F_T
            if self.share and f >= 0 and self.slot(self.buffer_lod[f]) == s:  # 2(b)
                self._use(i, f)                                  # 2(d) i. borrow
                self.lod[i] = self.buffer_lod[f]
                b = int(self.own[i])
                if b >= 0 and b != f and self.users[b] == 0:     # 2(d) ii.
                    self._unregister(b)
                self.borrows += 1
                continue
            b = self._own_buffer(i)                              # 2(c) i. extract
            self.lod[i] = d                                      # 2(c) ii.
            self.buffer_lod[b] = d
            self._use(i, b)
            if self.share:
                self.slots[t, s] = b                             # 2(c) iii.
            self.extractions += 1
            orders.append(Extraction(i, t, d, b))
        return orders

    def _own_buffer(self, i: int) -> int:
        """Object ``i``'s own buffer to extract into: a new one if it has none, or if
        others draw it (they keep it)."""
        b = int(self.own[i])
        others = self.users[b] - (1 if b >= 0 and self.using[i] == b else 0) if b >= 0 else 0
        if b < 0 or others > 0:
            # borrowed: the old LOD stays (and stays in D_T) for the objects drawing it
            b = self.free.pop() if self.free else len(self.buffer_lod)
            if b == len(self.buffer_lod):
                self.buffer_lod.append(0.0)
                self.buffer_type.append(int(self.types[i]))
                self.users.append(0)
            self.buffer_type[b] = int(self.types[i])
            self.own[i] = b
        else:
            self._unregister(b)  # its old LOD is gone from D_T
        return b

    def _use(self, i: int, b: int) -> None:
        old = int(self.using[i])
        if old == b:
            return
        self.users[old] -= 1
        self.users[b] += 1
        self.using[i] = b
        if self.users[old] == 0 and old >= self.n_types and old not in self.own:
            self._unregister(old)
            self.free.append(old)

    def _unregister(self, b: int) -> None:
        t = self.buffer_type[b]
        self.slots[t][self.slots[t] == b] = -1

    def buffers_in_use(self) -> np.ndarray:
        """The distinct buffers drawn."""
        return np.unique(self.using)
