"""The hold on a LOD server (Swan et al. 2002, §3.3): one client at a time, on a lease.

The paper's server serves one client.  Here any client may connect, so the server is held
by one of them at a time: the first ``load`` takes the hold (:meth:`Hold.take`), and the
holder renews it with every message it sends (:meth:`Hold.touch`: control, viewpoint and
acknowledgement alike).  The hold lapses ``lease_s`` seconds after the holder's last
message, or when it sends ``release`` (:meth:`Hold.drop`); a lapse is noticed the next time
anyone asks who holds the server (:meth:`Hold.current`), and calls ``on_lapse`` (the server
stops rendering for the client that is gone).

Clients are named by the id they send (random hex); an empty id is a holder all the same,
but its keyframes cannot be addressed.  The clock is replaceable (tests).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger("lodsprite.server")

LEASE_S = 10.0
"""Seconds without a message from the holding client after which its hold lapses."""


class Hold:
    """Which client holds the server, and since when it was last heard from (thread-safe).

    ``now``: the clock (seconds; replaceable).  ``on_lapse``: called, under the hold's
    lock, when an expired hold lapses."""

    def __init__(self, lease_s: float = LEASE_S,
                 now: Callable[[], float] = time.perf_counter,
                 on_lapse: Callable[[], None] | None = None) -> None:
        self.lease_s = float(lease_s)
        self.now = now
        self._on_lapse = on_lapse
        self._lock = threading.Lock()
        self._holder: str | None = None
        self._seen = 0.0

    def current(self) -> str | None:
        """The id of the client holding the server, or None; lapses an expired hold."""
        with self._lock:
            if self._holder is not None and self.now() - self._seen > self.lease_s:
                log.info("the hold of client %s lapsed after %.0f s without a message",
                         self._holder or "(anonymous)", self.lease_s)
                self._holder = None
                if self._on_lapse is not None:
                    self._on_lapse()
            return self._holder

    def touch(self, client: str) -> bool:
        """Note a message from ``client``; whether it holds the server (renewing the hold)."""
        with self._lock:
            if self._holder is not None and client == self._holder:
                self._seen = self.now()
                return True
            return False

    def take(self, client: str) -> bool:
        """Give the hold to ``client`` (renewed); whether the holder changed."""
        with self._lock:
            changed = client != self._holder
            self._holder, self._seen = client, self.now()
            return changed

    def drop(self) -> None:
        """End the hold (the holder's ``release``)."""
        with self._lock:
            self._holder = None
