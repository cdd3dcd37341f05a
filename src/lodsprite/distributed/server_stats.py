"""Statistics and bookkeeping of a LOD server (Swan et al. 2002, §3.3, Figures 11-12).

:class:`ServerStats` holds the per-keyframe timings the paper reports and the counts of
messages the server's edge received, rejected, ignored or refused; the ``stats`` control
request answers :meth:`ServerStats.as_dict`.  :class:`Tally` keeps those counts for the
server's handlers and logs each kind of trouble once.

Nothing here grows with use, however long the server runs and whatever clients send:

* each timing list keeps the most recent :data:`MAX_SAMPLES` samples (a ``stats`` reply
  stays well under the client's ``MAX_REPLY_BYTES``); the keyframes counted since the
  server started (``keyframes_rendered``, ``keyframes_sent``) are exact integers;
* the count tables are keyed by a fixed set of kinds (:data:`RECEIVED`, :data:`REJECTED`,
  :data:`IGNORED`, and the control ops for ``refused``), never by message content; a key
  outside its set is counted as ``other``;
* a line said once is remembered by its kind (``reject:control``, ``refuse:load``...),
  never by the text of the message or the reason; at most :data:`MAX_ONCE_KEYS` of them,
  after which new kinds are logged at DEBUG level instead.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from dataclasses import dataclass, field, fields

from lodsprite.distributed.protocol import CONTROL_OPS

log = logging.getLogger("lodsprite.server")

MAX_SAMPLES = 10_000
"""Samples each timing list keeps (the most recent)."""
MAX_ONCE_KEYS = 256
"""Kinds of log line :meth:`Tally.once` remembers."""
RECEIVED = ("control", "viewpoint", "keyframe")
"""Sockets whose messages are counted as ``received``."""
REJECTED = ("control", "viewpoint", "ack")
"""Kinds of malformed message counted as ``rejected``."""
IGNORED = ("viewpoint_not_holder", "viewpoint_not_newer", "ack_not_holder")
"""Reasons a well-formed message is set aside (``ignored``)."""
OTHER = "other"
TABLES = {"received": RECEIVED, "rejected": REJECTED, "ignored": IGNORED,
          "refused": CONTROL_OPS}


def _samples() -> deque:
    return deque(maxlen=MAX_SAMPLES)


@dataclass
class ServerStats:
    """Per-keyframe timings (ms) of Figures 11-12, the most recent :data:`MAX_SAMPLES`
    each.  ``production_ms`` is the whole Figure 6 loop: ``viewpoint_wait_ms`` (for a first
    viewpoint), ``paced_ms`` (with pace ``needed``, until a keyframe is due), ``render_ms``
    and ``queue_insert_ms``; ``queue_retrieve_ms``, ``transmission_ms`` and ``delta_t_ms``
    are the transmitter's.  ``keyframes_rendered`` and ``keyframes_sent`` count every
    keyframe since the server started.

    ``rejected`` counts malformed messages per socket (``control``, ``viewpoint``,
    ``ack``; ``rejected_messages`` is their sum) of those ``received`` per socket
    (``control``, ``viewpoint``, ``keyframe``); ``ignored`` counts well-formed
    messages set aside (from a client that does not hold the server, or viewpoint
    samples not newer than the last); ``refused`` counts control requests answered
    ``ok: false`` per op.  Updates and :meth:`as_dict` are thread-safe."""

    production_ms: deque = field(default_factory=_samples)
    viewpoint_wait_ms: deque = field(default_factory=_samples)
    paced_ms: deque = field(default_factory=_samples)
    render_ms: deque = field(default_factory=_samples)
    queue_insert_ms: deque = field(default_factory=_samples)
    delta_t_ms: deque = field(default_factory=_samples)
    queue_retrieve_ms: deque = field(default_factory=_samples)
    transmission_ms: deque = field(default_factory=_samples)
    rejected_messages: int = 0
    received: dict = field(default_factory=lambda: dict.fromkeys(RECEIVED, 0))
    rejected: dict = field(default_factory=lambda: dict.fromkeys(REJECTED, 0))
    ignored: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    keyframes_rendered: int = 0
    keyframes_sent: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False,
                                  compare=False)

    def count(self, table: str, key: str) -> None:
        """Add one to ``table[key]`` (``key`` outside the table's kinds: ``other``)."""
        key = key if key in TABLES[table] else OTHER
        with self._lock:
            counts = getattr(self, table)
            counts[key] = counts.get(key, 0) + 1
            if table == "rejected":
                self.rejected_messages += 1

    def rendered(self, viewpoint_wait: float, paced: float, render: float,
                 queue_insert: float, production: float) -> None:
        """Note one keyframe rendered and queued (timings in ms)."""
        with self._lock:
            self.keyframes_rendered += 1
            self.viewpoint_wait_ms.append(viewpoint_wait)
            self.paced_ms.append(paced)
            self.render_ms.append(render)
            self.queue_insert_ms.append(queue_insert)
            self.production_ms.append(production)

    def sent(self, queue_retrieve: float, transmission: float, delta_t: float) -> None:
        """Note one keyframe sent and acknowledged (timings in ms)."""
        with self._lock:
            self.keyframes_sent += 1
            self.queue_retrieve_ms.append(queue_retrieve)
            self.transmission_ms.append(transmission)
            self.delta_t_ms.append(delta_t)

    def as_dict(self) -> dict:
        """A copy, with lists for the timings (what a ``stats`` reply carries)."""
        with self._lock:
            out = {}
            for f in fields(self):
                if f.name.startswith("_"):
                    continue
                v = getattr(self, f.name)
                out[f.name] = (list(v) if isinstance(v, deque | list)
                               else dict(v) if isinstance(v, dict) else v)
            return out


class Tally:
    """The server's handlers' bookkeeping: counts into ``stats``, and log lines said once
    per kind (a flood must not flood the log, nor fill the memory)."""

    def __init__(self, stats: ServerStats) -> None:
        self.stats = stats
        self.said: set[str] = set()  # kinds of line logged once already
        self._lock = threading.Lock()

    def once(self, key: str, level: int, text: str, *args) -> None:
        """Log ``text`` the first time ``key`` (a kind, never message content) comes up."""
        with self._lock:
            if key in self.said:
                return
            remember = len(self.said) < MAX_ONCE_KEYS
            if remember:
                self.said.add(key)
        if remember:
            log.log(level, text + " (said once)", *args)
        else:  # no room to remember another kind: quietly, every time
            log.debug(text, *args)

    def received(self, socket: str) -> None:
        self.stats.count("received", socket)

    def reject(self, kind: str, exc: Exception) -> None:
        """Count a malformed message of ``kind`` (see :data:`REJECTED`)."""
        self.stats.count("rejected", kind)
        self.once(f"reject:{kind}", logging.WARNING, "rejected %s message: %s", kind, exc)

    def ignore(self, why: str) -> None:
        """Count a well-formed message set aside (see :data:`IGNORED`)."""
        self.stats.count("ignored", why)

    def refuse(self, op: str, error: str) -> None:
        """Count a control request ``op`` answered ``ok: false`` because of ``error``."""
        self.stats.count("refused", op)
        self.once(f"refuse:{op if op in CONTROL_OPS else OTHER}", logging.WARNING,
                  "refused %s: %s", op, error)
