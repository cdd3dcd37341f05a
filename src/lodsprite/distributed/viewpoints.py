"""The viewpoint receiver of a LOD server and the VIEWPOINT-PREDICTOR it feeds (Swan et al.
2002, §3.3, Figure 7).

The receiver takes the viewpoint samples published on the viewpoint connection (a SUB
socket), everything queued at a time, oldest first.  Each message is decoded and
validated by :mod:`.protocol` and never raises: a malformed one is rejected and counted,
one from a client that does not hold the server is ignored and counted, and the holder's
renews its hold.

Prediction uses the client's clock: each sample is observed at the client time ``t`` it
carries (a burst of samples arriving at once is not a burst of motion), and samples not
newer than the last by :data:`MIN_SAMPLE_SPACING_S` are ignored and counted.  A keyframe
is aimed ``lead`` plus the time since the newest sample arrived (server clock, at most
:data:`MAX_ELAPSED_S`) after that sample.  A prediction that fails (a client's odd
samples) gives the newest sample itself.

Alongside each sample the client says which keyframe it shows (eye and server slot); the
renderer's pacing reads it.
"""

from __future__ import annotations

import logging
import threading

import zmq

from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.hold import Hold
from lodsprite.distributed.protocol import (
    ProtocolError,
    ViewpointMessage,
    decode_message,
    shown_from_wire,
    viewpoint_from_wire,
)
from lodsprite.distributed.server_stats import Tally
from lodsprite.errors import LodspriteError
from lodsprite.sprite.predictors import PREDICTORS

MAX_ELAPSED_S = 1.0
"""Longest time since the newest viewpoint sample that prediction extrapolates over."""
MIN_SAMPLE_SPACING_S = 1e-4
"""Samples closer than this (client clock) to the previous one are ignored."""
VIEWPOINT_FRAMES = 1
"""Frames of a viewpoint message (a header); the receiver keeps no more of one."""


class ViewpointReceiver:
    """The holder's newest viewpoint sample and its motion (thread-safe); :meth:`run` is
    the receiver thread's body.

    ``have`` is set once a sample was observed (cleared by :meth:`reset`); ``fresh`` is set
    by each sample observed (its waiter clears it).  The server clock is ``hold.now``."""

    def __init__(self, predictor: str, hold: Hold, tally: Tally,
                 stop: threading.Event) -> None:
        self.predictor_name = predictor
        self.hold, self.tally = hold, tally
        self.have = threading.Event()
        self.fresh = threading.Event()
        self._stop = stop
        self._lock = threading.Lock()
        self._predictor = PREDICTORS[predictor]()
        self._last_t: float | None = None  # client clock of the newest sample
        self._last_arrival = 0.0  # server clock when it arrived
        self._last_vp = None
        self._shown = None  # (eye, slot) of the keyframe the client says it shows
        self._client: str | None = None  # whose samples are kept (the holder's, at reset)

    def run(self, sock: zmq.Socket) -> None:
        """Receive until the server stops; closes ``sock``.  An unexpected error is logged
        once per kind and the loop goes on."""
        try:
            while not self._stop.is_set():
                try:
                    self._receive(sock)
                except Exception as exc:  # a bug must not stop the receiver
                    self.tally.once(f"internal:vp-loop:{type(exc).__name__}", logging.ERROR,
                                    "internal error receiving viewpoints: %r", exc)
                    self._stop.wait(0.01)
        finally:
            sock.close(linger=0)

    def _receive(self, sock: zmq.Socket) -> None:
        """Take everything queued on ``sock``, oldest first (waits up to 50 ms for it)."""
        if not sock.poll(50):
            return
        for _ in range(1000):
            try:
                frames = recv_frames(sock, VIEWPOINT_FRAMES)
            except zmq.Again:
                return
            self.take(frames)

    def take(self, frames: list) -> bool:
        """Take one viewpoint message; whether it was observed.  Never raises."""
        self.tally.received("viewpoint")
        try:
            try:
                check_frames(frames)
                msg, _ = decode_message(frames, ViewpointMessage)
                vp = viewpoint_from_wire(msg.viewpoint)
                shown = shown_from_wire(msg.shown)
            except ProtocolError as exc:
                self.tally.reject("viewpoint", exc)
                return False
            if self.hold.current() is None or not self.hold.touch(msg.client):
                self.tally.ignore("viewpoint_not_holder")
                return False
            why = self._observe(msg.client, msg.t, vp, shown)
            if why is not None:
                self.tally.ignore(why)
                return False
            return True
        except Exception as exc:
            self.tally.once(f"internal:vp:{type(exc).__name__}", logging.ERROR,
                            "internal error handling a viewpoint: %r", exc)
            return False

    def _observe(self, client: str, t: float, vp, shown) -> str | None:
        """Keep ``client``'s sample taken at client time ``t``; why not (the reason
        counted as ignored), or None.  The client is checked under the lock against the
        one :meth:`reset` was last called for, so that a sample of the previous holder
        that was in flight during a new client's ``load`` cannot be kept."""
        with self._lock:
            if client != self._client:
                return "viewpoint_not_holder"
            if self._last_t is not None and t < self._last_t + MIN_SAMPLE_SPACING_S:
                return "viewpoint_not_newer"
            self._predictor.observe(t, vp)  # the client's clock, not arrival
            self._last_t, self._last_arrival, self._last_vp = t, self.hold.now(), vp
            self._shown = shown
        self.have.set()
        self.fresh.set()
        return None

    def reset(self, client: str | None = None) -> None:
        """Forget everything and take samples from ``client`` only from now on (a new
        holder: nothing of the previous one's motion is kept)."""
        with self._lock:
            self._client = client
            self._predictor = PREDICTORS[self.predictor_name]()
            self._last_t, self._last_vp, self._shown = None, None, None
            self.have.clear()

    def predict(self, lead: float):
        """The viewpoint ``lead`` seconds plus the time since the newest sample arrived
        (server clock) after that sample, and what the client shows."""
        with self._lock:
            elapsed = min(max(self.hold.now() - self._last_arrival, 0.0), MAX_ELAPSED_S)
            try:
                vp = self._predictor.predict(lead + elapsed)
            except (LodspriteError, ValueError, ArithmeticError):
                vp = self._last_vp
            return vp, self._shown
