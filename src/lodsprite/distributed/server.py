"""The LOD server (Swan, Arango & Nakshatrala 2002, §3.3, Figures 6-7): renders keyframes.

No user interface: it is driven by messages on three connections, bound to consecutive
ports ``port``, ``port + 1``, ``port + 2`` (the paper's Figure 4):

* control (REP): ``ping``, ``load`` (terrain, texture, grid, exaggeration, size, fov, and
  the client's coarse level, visibility rule, ε and pace), ``start``, ``stop``,
  ``stats``, ``shutdown``;
* viewpoint (SUB, conflated: the newest viewpoint wins);
* keyframe (DEALER): keyframes out, acknowledgements back.

Modules, each a thread: SERVER-CONTROL, the viewpoint receiver feeding the
VIEWPOINT-PREDICTOR, KEYFRAME-RENDERER (owns the GL context), SERVER-KEYFRAME-QUEUE
(capacity 2) and KEYFRAME-TRANSMITTER, which measures ``δt = t1 - t0``.  With pace
``needed`` (default; :mod:`lodsprite.distributed.pacing`) the renderer waits until the
client will need a new keyframe; ``continuous`` renders back to back as in the paper.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import zmq

from lodsprite.distributed.keys import ServerKeys
from lodsprite.distributed.predictors import PREDICTORS
from lodsprite.distributed.protocol import (
    Keyframe,
    ProtocolError,
    decode,
    encode,
    encode_keyframe,
    shown_from_wire,
    viewpoint_from_wire,
)
from lodsprite.distributed.queue import Closed, KeyframeQueue
from lodsprite.distributed.render import KeyframeRenderer, check_load_args
from lodsprite.errors import LodspriteError

log = logging.getLogger("lodsprite.server")

DEFAULT_BIND = "127.0.0.1:5555"
ACK_TIMEOUT_S = 5.0


def endpoints(address: str, bind: bool) -> tuple[str, str, str]:
    """ZeroMQ endpoints of the three connections from ``HOST:PORT`` (consecutive ports)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65534:
        raise LodspriteError(f"address must look like HOST:PORT, got '{address}'")
    p = int(port)
    host = "*" if bind and host in ("0.0.0.0", "*") else host
    return tuple(f"tcp://{host}:{p + i}" for i in range(3))  # type: ignore[return-value]


@dataclass
class ServerStats:
    """Per-keyframe timings (ms) of Figures 11-12.  ``production_ms`` is the whole
    Figure 6 loop: ``viewpoint_wait_ms`` (for a first viewpoint), ``paced_ms`` (with
    pace ``needed``, until a keyframe is due), ``render_ms`` and ``queue_insert_ms``."""

    production_ms: list = field(default_factory=list)
    viewpoint_wait_ms: list = field(default_factory=list)
    paced_ms: list = field(default_factory=list)
    render_ms: list = field(default_factory=list)
    queue_insert_ms: list = field(default_factory=list)
    delta_t_ms: list = field(default_factory=list)
    queue_retrieve_ms: list = field(default_factory=list)
    transmission_ms: list = field(default_factory=list)
    rejected_messages: int = 0

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, list) else v for k, v in self.__dict__.items()}


class LodServer:
    """A keyframe server; :meth:`run` blocks until a ``shutdown`` message."""

    def __init__(self, bind: str = DEFAULT_BIND, predictor: str = "linear",
                 codec: str = "raw", keys: ServerKeys | None = None) -> None:
        self.addresses = endpoints(bind, bind=True)
        self.keys = keys
        self.predictor_name = predictor
        self.codec = codec
        self.stats = ServerStats()
        self.queue: KeyframeQueue[Keyframe] = KeyframeQueue(2)
        self._ctx = zmq.Context()
        self._auth = None
        if keys is not None:
            from zmq.auth.thread import ThreadAuthenticator

            self._auth = ThreadAuthenticator(self._ctx)
            self._auth.start()
            # Only clients whose public key file lies in the keys folder get in.
            self._auth.configure_curve(domain="*", location=str(keys.clients_dir))
        self._stop = threading.Event()
        self._running = threading.Event()
        self._scene_lock = threading.Lock()
        self._scene_request: dict | None = None
        self._loaded = False  # a load request was accepted
        self._latest_lock = threading.Lock()
        self._predictor = PREDICTORS[predictor]()
        self._have_viewpoint = threading.Event()
        self._fresh_viewpoint = threading.Event()  # set by each viewpoint received
        self._shown = None  # (eye, slot) of the keyframe the client says it shows
        self._slot, self._slots = 0, 1  # this server's place among the client's servers
        self._delta_t = 0.5  # seconds, until the transmitter has measured one
        self._seq = 0

    def _socket(self, kind: int) -> zmq.Socket:
        sock = self._ctx.socket(kind)
        if self.keys is not None:
            self.keys.apply(sock)
        return sock

    # ----------------------------------------------------------------- SERVER-CONTROL

    def run(self) -> None:
        control = self._socket(zmq.REP)
        control.bind(self.addresses[0])
        threads = [threading.Thread(target=f, daemon=True, name=f.__name__)
                   for f in (self._receive_viewpoints, self._render_keyframes,
                             self._transmit_keyframes)]
        for t in threads:
            t.start()
        log.info("LOD server on %s", ", ".join(self.addresses))
        try:
            while not self._stop.is_set():
                if not control.poll(100):
                    continue
                frames = control.recv_multipart()
                control.send_multipart(encode(self._control(frames)))
        finally:
            self._stop.set()
            self.queue.close()
            for t in threads:
                t.join(timeout=5.0)
            control.close(linger=0)
            if self._auth is not None:
                self._auth.stop()
            self._ctx.term()

    def _control(self, frames: list[bytes]) -> dict:
        try:
            header, _ = decode(frames)
        except ProtocolError as exc:
            self.stats.rejected_messages += 1
            log.warning("rejected control message: %s", exc)
            return {"kind": "reply", "seq": 0, "ok": False, "error": str(exc)}
        op, seq = header.get("op"), header["seq"]
        reply = {"kind": "reply", "seq": seq, "ok": True, "error": "", "data": {}}
        if header["kind"] != "control":
            return {**reply, "ok": False, "error": "expected a control message"}
        if op == "ping":
            reply["data"] = {"running": self._running.is_set(), "loaded": self._loaded}
        elif op == "load":
            args = header.get("args") or {}
            if not isinstance(args, dict):
                return {**reply, "ok": False, "error": "load: args is not a map"}
            slot, slots = args.get("slot", 0), args.get("slots", 1)
            if not (isinstance(slot, int) and isinstance(slots, int) and 0 <= slot < slots):
                return {**reply, "ok": False, "error": f"bad slot {slot!r} of {slots!r}"}
            try:
                check_load_args(args)
            except ProtocolError as exc:
                return {**reply, "ok": False, "error": str(exc)}
            self._slot, self._slots = slot, slots
            with self._scene_lock:
                self._scene_request = args
            self._loaded = True
        elif op == "start":
            self._running.set()
        elif op == "stop":
            self._running.clear()
        elif op == "stats":
            reply["data"] = self.stats.as_dict()
        elif op == "shutdown":
            self._stop.set()
        else:
            reply.update(ok=False, error=f"unknown control op {op!r}")
        return reply

    # ------------------------------------------------------ viewpoints and prediction

    def _receive_viewpoints(self) -> None:
        sock = self._socket(zmq.SUB)
        sock.setsockopt(zmq.CONFLATE, 1)
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        sock.bind(self.addresses[1])
        try:
            while not self._stop.is_set():
                if not sock.poll(50):
                    continue
                frames = sock.recv_multipart()
                try:
                    header, _ = decode(frames)
                    if header["kind"] != "viewpoint":
                        raise ProtocolError("expected a viewpoint message")
                    vp = viewpoint_from_wire(header.get("viewpoint"))
                    shown = shown_from_wire(header.get("shown"))
                except ProtocolError as exc:
                    self.stats.rejected_messages += 1
                    log.warning("rejected viewpoint message: %s", exc)
                    continue
                with self._latest_lock:
                    self._predictor.observe(time.perf_counter(), vp)
                    self._shown = shown
                self._have_viewpoint.set()
                self._fresh_viewpoint.set()
        finally:
            sock.close(linger=0)

    def _predicted_viewpoint(self):
        """The viewpoint δt ahead, and what the client shows.  With several servers,
        server ``slot`` of ``slots`` aims ``δt (1 + slot/slots)`` ahead, so their keyframes
        cover different moments."""
        with self._latest_lock:
            lead = self._delta_t * (1.0 + self._slot / self._slots)
            return self._predictor.predict(lead), self._shown

    def _due(self, renderer: KeyframeRenderer, vp, shown) -> bool:
        """Whether to render for ``vp``.  With several servers they take turns: it is this
        server's turn when the client shows the previous slot's keyframe."""
        eye, turn = None, True
        if shown is not None:
            eye, slot = shown
            turn = (slot + 1) % self._slots == self._slot
        return renderer.pacer.due(vp, renderer.projection(vp), eye, turn)

    # -------------------------------------------------------------- KEYFRAME-RENDERER

    def _render_keyframes(self) -> None:
        renderer: KeyframeRenderer | None = None
        try:
            while not self._stop.is_set():
                with self._scene_lock:
                    request, self._scene_request = self._scene_request, None
                if request is not None:
                    if renderer is not None:
                        renderer.release()
                        renderer = None
                    try:
                        renderer = KeyframeRenderer(request)
                    except (LodspriteError, ValueError) as exc:
                        log.error("cannot load the scene: %s", exc)
                if renderer is None or not self._running.is_set():
                    time.sleep(0.01)
                    continue
                self._produce(renderer)
        except Closed:
            pass
        finally:
            if renderer is not None:
                renderer.release()

    def _produce(self, renderer) -> None:
        t0 = time.perf_counter()
        if not self._have_viewpoint.wait(0.1):
            return
        t_vp = time.perf_counter()
        vp, shown = self._predicted_viewpoint()
        while not self._due(renderer, vp, shown):
            if (self._stop.is_set() or not self._running.is_set()
                    or self._scene_request is not None):
                return
            self._fresh_viewpoint.wait(0.05)  # check again with the next viewpoint
            self._fresh_viewpoint.clear()
            vp, shown = self._predicted_viewpoint()
        t1 = time.perf_counter()  # δt runs from here: the prediction was made for t1 + δt
        self._seq += 1
        kf = renderer.render(vp, self._seq, t1)
        t2 = time.perf_counter()
        while not self.queue.put(kf, timeout=0.1):
            if self._stop.is_set() or not self._running.is_set():
                return
        t3 = time.perf_counter()
        s = self.stats
        s.viewpoint_wait_ms.append((t_vp - t0) * 1e3)
        s.paced_ms.append((t1 - t_vp) * 1e3)
        s.render_ms.append((t2 - t1) * 1e3)
        s.queue_insert_ms.append((t3 - t2) * 1e3)
        s.production_ms.append((t3 - t0) * 1e3)

    # ----------------------------------------------------------- KEYFRAME-TRANSMITTER

    def _transmit_keyframes(self) -> None:
        sock = self._socket(zmq.DEALER)
        sock.setsockopt(zmq.SNDHWM, 2)
        sock.bind(self.addresses[2])
        try:
            while not self._stop.is_set():
                t_wait = time.perf_counter()
                kf = self.queue.get(timeout=0.1)
                if kf is None:
                    continue
                t_send = time.perf_counter()
                sock.send_multipart(encode_keyframe(kf, self.codec), copy=False)
                if not self._await_ack(sock, kf.seq):
                    log.warning("no acknowledgement for keyframe %d", kf.seq)
                    continue
                t1 = time.perf_counter()
                self._delta_t = t1 - kf.t0
                s = self.stats
                s.queue_retrieve_ms.append((t_send - t_wait) * 1e3)
                s.transmission_ms.append((t1 - t_send) * 1e3)
                s.delta_t_ms.append(self._delta_t * 1e3)
        except Closed:
            pass
        finally:
            sock.close(linger=0)

    def _await_ack(self, sock, seq: int) -> bool:
        deadline = time.perf_counter() + ACK_TIMEOUT_S
        while not self._stop.is_set() and time.perf_counter() < deadline:
            if not sock.poll(50):
                continue
            try:
                header, _ = decode(sock.recv_multipart())
            except ProtocolError as exc:
                self.stats.rejected_messages += 1
                log.warning("rejected acknowledgement: %s", exc)
                continue
            if header["kind"] == "ack" and header["seq"] == seq:
                return True
        return False
