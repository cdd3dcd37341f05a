"""Keyframe queues (Swan et al. 2002, §3.1): bounded producer/consumer queues.

The SERVER-KEYFRAME-QUEUE and CLIENT-KEYFRAME-QUEUE both hold two keyframes.  The
producer blocks while the queue is full (the paper's "wait until ... not full");
:meth:`KeyframeQueue.drain` gives a consumer the newest keyframe and drops older ones
(the SPRITEFRAME-RENDERER's loop of Figure 5, lines 3-4).
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class Closed(Exception):
    """The queue was closed while waiting."""


class KeyframeQueue(Generic[T]):
    """A thread-safe bounded FIFO with blocking put/get and a non-blocking newest-wins drain."""

    def __init__(self, capacity: int = 2) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = capacity
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)

    def put(self, item: T, timeout: float | None = None) -> bool:
        """Append, waiting while full; False on timeout.  Raises :class:`Closed`."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._closed or len(self._items) < self.capacity,
                                       timeout):
                return False
            if self._closed:
                raise Closed
            self._items.append(item)
            self._cond.notify_all()
            return True

    def get(self, timeout: float | None = None) -> T | None:
        """Oldest item, waiting while empty; None on timeout.  Raises :class:`Closed`."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._closed or self._items, timeout):
                return None
            if not self._items:
                raise Closed
            item = self._items.popleft()
            self._cond.notify_all()
            return item

    def drain(self) -> T | None:
        """The newest item (older ones are dropped), or None if empty; never blocks."""
        with self._cond:
            if not self._items:
                return None
            item = self._items[-1]
            self._items.clear()
            self._cond.notify_all()
            return item

    def close(self) -> None:
        """Wake every waiter; later put/get raise :class:`Closed` (get drains first)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
