"""A daemon thread that loads, one at a time, what a wish list asks for: the base of the
lumigraph's node loader and the terrain's tile loader (work that must never block a
frame)."""

from __future__ import annotations

import logging
import threading

log = logging.getLogger(__name__)


class BackgroundLoader:
    """Subclasses set up their state, then call ``super().__init__(name)``; they give
    :meth:`_next` (the next item, or None; called holding ``self._cv``) and :meth:`_load`
    (called without it)."""

    def __init__(self, name: str) -> None:
        self._cv = getattr(self, "_cv", None) or threading.Condition()
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _next(self):
        raise NotImplementedError

    def _load(self, item):
        raise NotImplementedError

    def _run(self) -> None:
        while True:
            with self._cv:
                item = None
                while not self._stop and (item := self._next()) is None:
                    self._cv.wait()
                if self._stop:
                    return
            try:
                self._load(item)
            except Exception:  # the thread outlives a bad item; the item stays unloaded
                log.exception("%s: loading %r failed", self._thread.name, item)

    def close(self) -> None:
        """Stop the thread (it finishes the item in hand)."""
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._thread.join(timeout=5.0)
