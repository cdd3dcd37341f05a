"""The KEYFRAME-TRANSMITTER of a LOD server (Swan et al. 2002, §3.3, Figure 6).

It takes keyframes from the SERVER-KEYFRAME-QUEUE and sends each to the client that holds
the server, on the keyframe connection (a ROUTER: the holder's keyframe socket has the
holder's id as its ZeroMQ identity, so keyframes go to the holder only), then waits for
its acknowledgement.  ``δt = t1 - t0`` runs from the moment the renderer made its
prediction (``t0``, carried in the keyframe) to the acknowledgement (``t1``); prediction
aims that far ahead.

A keyframe the holder cannot take (not connected, not reading) or does not acknowledge
within :data:`ACK_TIMEOUT_S` is dropped.  Anything arriving on the keyframe connection is
taken by :meth:`KeyframeTransmitter.ack`, which never raises: a malformed message (one
with more frames than an acknowledgement included, :mod:`.frames`) is rejected and
counted, an acknowledgement from a client that does not hold the server is ignored and
counted, and the holder's renews its hold.  An unexpected error in the loop is logged
once per kind, and the loop goes on.
"""

from __future__ import annotations

import logging
import threading
import time

import zmq

from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.hold import Hold
from lodsprite.distributed.protocol import (
    Ack,
    Keyframe,
    ProtocolError,
    decode_message,
    encode_keyframe,
)
from lodsprite.distributed.queue import Closed, KeyframeQueue
from lodsprite.distributed.server_stats import Tally

ACK_TIMEOUT_S = 5.0
"""Seconds the holder has to take a keyframe, and then to acknowledge it."""
ACK_FRAMES = 2
"""Frames of a message on the keyframe connection: the sender's identity and an ack
header; the transmitter keeps no more of one."""


class KeyframeTransmitter:
    """Sends the queued keyframes to the holder; :meth:`run` is the thread's body.

    ``delta_t``: the last measured δt in seconds (0.5 until one is measured)."""

    def __init__(self, queue: KeyframeQueue[Keyframe], hold: Hold, tally: Tally,
                 codec: str, stop: threading.Event) -> None:
        self.queue, self.hold, self.tally = queue, hold, tally
        self.codec = codec
        self.delta_t = 0.5
        self._stop = stop

    def run(self, sock: zmq.Socket) -> None:
        """Transmit until the server stops or the queue closes; closes ``sock``.  An
        unexpected error is logged once per kind and the loop goes on."""
        try:
            while not self._stop.is_set():
                try:
                    self._transmit_one(sock)
                except Closed:
                    raise
                except Exception as exc:  # a bug must not stop the transmitter
                    self.tally.once(f"internal:transmit:{type(exc).__name__}", logging.ERROR,
                                    "internal error transmitting keyframes: %r", exc)
                    self._stop.wait(0.01)
        except Closed:
            pass
        finally:
            sock.close(linger=0)

    def _transmit_one(self, sock: zmq.Socket) -> None:
        t_wait = time.perf_counter()
        kf = self.queue.get(timeout=0.05)
        if kf is None:
            self._drain_acks(sock)
            return
        holder = self.hold.current()
        if not holder:
            if holder == "":
                self.tally.once("anonymous", logging.WARNING, "the holding client sent no "
                                "id: its keyframes cannot be addressed")
            return
        t_send = time.perf_counter()
        if not self._send(sock, holder, kf):
            return
        if not self._await_ack(sock, holder, kf.seq):
            self.tally.once("no-ack", logging.WARNING, "no acknowledgement for keyframe %d",
                            kf.seq)
            return
        t1 = time.perf_counter()
        self.delta_t = t1 - kf.t0
        self.tally.stats.sent(queue_retrieve=(t_send - t_wait) * 1e3,
                              transmission=(t1 - t_send) * 1e3, delta_t=self.delta_t * 1e3)

    def _send(self, sock: zmq.Socket, holder: str, kf: Keyframe) -> bool:
        """Send ``kf`` to the holder's keyframe socket; False when it cannot take it
        before the acknowledgement timeout (not connected, or not reading)."""
        frames = [holder.encode(), *encode_keyframe(kf, self.codec)]
        deadline = time.perf_counter() + ACK_TIMEOUT_S
        while not self._stop.is_set() and time.perf_counter() < deadline:
            if self.hold.current() != holder:
                return False
            try:
                sock.send_multipart(frames, flags=zmq.NOBLOCK, copy=False)
                return True
            except zmq.Again:
                pass  # the holder's queue is full
            except zmq.ZMQError as exc:
                if exc.errno != zmq.EHOSTUNREACH:
                    raise
            self._drain_acks(sock, 0.02)  # not connected (yet): wait a little
        return False

    def _drain_acks(self, sock: zmq.Socket, timeout_s: float = 0.0) -> None:
        if sock.poll(int(timeout_s * 1e3)):
            for _ in range(1000):
                try:
                    frames = recv_frames(sock, ACK_FRAMES)
                except zmq.Again:
                    return
                self.ack(frames, None, -1)

    def ack(self, frames: list, holder: str | None, seq: int) -> bool:
        """Take one message from the keyframe socket (``[identity, *message]``); whether it
        is ``holder``'s acknowledgement of keyframe ``seq``.  Never raises."""
        self.tally.received("keyframe")
        try:
            if len(frames) < 2:
                self.tally.reject("ack", ProtocolError("no message after the identity frame"))
                return False
            try:
                check_frames(frames)
                msg, _ = decode_message(frames[1:], Ack)
            except ProtocolError as exc:
                self.tally.reject("ack", exc)
                return False
            identity = bytes(frames[0])
            current = self.hold.current()
            if current is None or identity != current.encode():
                self.tally.ignore("ack_not_holder")
                return False
            self.hold.touch(current)
            return holder == current and msg.seq == seq
        except Exception as exc:
            self.tally.once(f"internal:ack:{type(exc).__name__}", logging.ERROR,
                            "internal error handling an acknowledgement: %r", exc)
            return False

    def _await_ack(self, sock: zmq.Socket, holder: str, seq: int) -> bool:
        deadline = time.perf_counter() + ACK_TIMEOUT_S
        while not self._stop.is_set() and time.perf_counter() < deadline:
            if not sock.poll(50):
                if self.hold.current() != holder:
                    return False
                continue
            try:
                frames = recv_frames(sock, ACK_FRAMES)
            except zmq.Again:
                continue
            if self.ack(frames, holder, seq):
                return True
        return False
