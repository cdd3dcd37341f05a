"""The LOD server (Swan, Arango & Nakshatrala 2002, §3.3, Figures 6-7): renders keyframes.

No user interface: it is driven by messages on three connections, bound to consecutive
ports ``port``, ``port + 1``, ``port + 2`` (the paper's Figure 4):

* control (REP): ``ping``, ``load`` (terrain, texture, grid, exaggeration, size, fov, and
  the client's coarse level, visibility rule, ε and pace), ``start``, ``stop``,
  ``release``, ``stats``, ``shutdown`` (refused unless allowed, see below);
* viewpoint (SUB): viewpoint samples, each stamped with the client's clock;
* keyframe (ROUTER): keyframes out to the client that holds the server, acknowledgements
  back.

Modules, each a thread: SERVER-CONTROL (here), the viewpoint receiver feeding the
VIEWPOINT-PREDICTOR (:mod:`.viewpoints`), KEYFRAME-RENDERER (:mod:`.producer`, owns the GL
context), SERVER-KEYFRAME-QUEUE (capacity 2) and KEYFRAME-TRANSMITTER
(:mod:`.transmitter`), which measures ``δt = t1 - t0``.  With pace ``needed`` (default;
:mod:`lodsprite.distributed.pacing`) the renderer waits until the client will need a new
keyframe; ``continuous`` renders back to back as in the paper.

The edge (a server no message can stop, wedge or misuse):

* Every message is decoded and validated by :mod:`.protocol`; a malformed one is counted
  per kind (``stats``: ``rejected``), logged once per kind, and a control message gets
  ``ok: false`` with the reason.  No handler lets an exception out.
* One client holds the server at a time.  A client sends its id (random hex) in every
  control and viewpoint message, and its keyframe socket's ZeroMQ identity is the same
  id, so keyframes go to the holder only.  The first ``load`` takes the hold; a ``load``,
  ``start``, ``stop``, ``release`` or ``shutdown`` from another client is refused while the
  holder is alive ("held by another client"); viewpoints and acknowledgements from
  other clients are ignored and counted (``ignored``).  The hold lapses after
  ``lease_s`` seconds without a message from the holder, or on its ``release``
  (:mod:`.hold`).
* A client names datasets, not paths (:mod:`.datasets`).  A ``load`` the machine cannot
  hold (estimated memory against ``MemAvailable``, sizes against the GL maximum texture
  size) is refused before anything is allocated.
* The renderer thread survives a scene that fails to load or render (any exception,
  ``MemoryError`` and GL errors included): ``ping`` answers ``state`` (``idle``,
  ``loading``, ``ready``, ``failed``) and the last ``error``; a later ``load`` starts
  afresh (:mod:`.producer`).
* Every socket has a ``zmq.MAXMSGSIZE``; the server binds loopback unless
  ``allow_remote``.  Each message is received frame by frame (:mod:`.frames`), keeping at
  most the frames its kind has (1 for control and viewpoint messages, 1 after the
  identity for acknowledgements); one with more is dropped as it comes and rejected.
  ZeroMQ bounds each frame, not the number of frames of one message; libzmq holds a
  multipart message whole before delivering it, so a peer can still make the server hold
  one long message; beyond loopback use ``--keys``, which admits only known clients.
* ``shutdown`` over the network is refused unless the server was started with
  ``allow_shutdown=True`` (``lodsprite serve --allow-shutdown``), and then it is carried
  out only for the client that holds the server.  A server is otherwise stopped by its
  owner: a signal, or :meth:`LodServer.shutdown` in the same process.
* Nothing grows with use (:mod:`.server_stats`): ``stats`` keeps the most recent
  ``MAX_SAMPLES`` timings of each kind and exact keyframe counts; counts are keyed by a
  fixed set of kinds and ops, and lines said once by their kind, never by what a message
  carries.

Prediction uses the client's clock (:mod:`.viewpoints`): each sample is observed at the client
time ``t`` it carries, and a keyframe is aimed ``δt`` plus the time since the newest sample
arrived (server clock) after that sample.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import msgspec
import zmq

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.hold import LEASE_S, Hold
from lodsprite.distributed.keys import ServerKeys
from lodsprite.distributed.producer import STATES, KeyframeProducer
from lodsprite.distributed.protocol import (
    CODECS,
    LOOPBACK_HOSTS,
    MAX_ACK_BYTES,
    MAX_CONTROL_BYTES,
    MAX_VIEWPOINT_BYTES,
    Control,
    Keyframe,
    LoadArgs,
    ProtocolError,
    decode_message,
    encode,
)
from lodsprite.distributed.queue import KeyframeQueue
from lodsprite.distributed.render import (
    MEMORY_FRACTION,
    check_scene_memory,
    estimate_scene_bytes,
    working_grid,
)
from lodsprite.distributed.server_stats import MAX_SAMPLES, ServerStats, Tally
from lodsprite.distributed.transmitter import ACK_TIMEOUT_S, KeyframeTransmitter
from lodsprite.distributed.viewpoints import MAX_ELAPSED_S, MIN_SAMPLE_SPACING_S, ViewpointReceiver
from lodsprite.errors import InputError, LodspriteError
from lodsprite.sprite.predictors import PREDICTORS

__all__ = ["ACK_TIMEOUT_S", "DEFAULT_BIND", "LEASE_S", "LOOPBACK_HOSTS", "MAX_ELAPSED_S",
           "MAX_SAMPLES", "MEMORY_FRACTION", "MIN_SAMPLE_SPACING_S", "STATES", "LodServer",
           "ServerStats", "endpoints", "is_loopback"]

log = logging.getLogger("lodsprite.server")

DEFAULT_BIND = "127.0.0.1:5555"
CONTROL_FRAMES = 1
"""Frames of a control message (a header); the server keeps no more of one."""


def endpoints(address: str, bind: bool) -> tuple[str, str, str]:
    """ZeroMQ endpoints of the three connections from ``HOST:PORT`` (consecutive ports)."""
    if not isinstance(address, str):
        raise InputError(f"address must look like HOST:PORT, got {address!r}")
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65534:
        raise InputError(f"address must look like HOST:PORT, got '{address}'")
    p = int(port)
    host = "*" if bind and host in ("0.0.0.0", "*") else host
    return tuple(f"tcp://{host}:{p + i}" for i in range(3))  # type: ignore[return-value]


def is_loopback(address: str) -> bool:
    """Whether ``HOST:PORT`` names this machine's loopback interface."""
    return address.rpartition(":")[0] in LOOPBACK_HOSTS


class LodServer:
    """A keyframe server; :meth:`run` blocks until :meth:`shutdown` (or, with
    ``allow_shutdown``, the holder's ``shutdown`` message).

    ``bind`` is ``HOST:PORT``; a host other than loopback needs ``allow_remote=True``
    (raises :class:`InputError` otherwise).  ``data_dir``: the folder whose files clients
    may name (None: built-in datasets only).  ``lease_s``: see the module docstring.
    ``allow_shutdown``: carry out a ``shutdown`` message from the holding client
    (otherwise it is refused).
    """

    def __init__(self, bind: str = DEFAULT_BIND, predictor: str = "linear",
                 codec: str = "raw", keys: ServerKeys | None = None,
                 data_dir: Path | str | None = None, allow_remote: bool = False,
                 lease_s: float = LEASE_S, allow_shutdown: bool = False) -> None:
        self.addresses = endpoints(bind, bind=True)
        if not is_loopback(bind) and not allow_remote:
            raise InputError(f"binding {bind} exposes the server beyond this machine: "
                             "pass allow_remote=True (--allow-remote)")
        if predictor not in PREDICTORS:
            raise InputError(f"unknown predictor '{predictor}': use {', '.join(PREDICTORS)}")
        if codec not in CODECS:
            raise InputError(f"unknown codec '{codec}': use {', '.join(CODECS)}")
        self.datasets = Datasets(data_dir)
        self.keys = keys
        self.predictor_name = predictor
        self.codec = codec
        self.allow_shutdown = bool(allow_shutdown)
        self.stats = ServerStats()
        self.queue: KeyframeQueue[Keyframe] = KeyframeQueue(2)
        self._ctx = zmq.Context()
        self._auth = None
        self._stop = threading.Event()
        self._running = threading.Event()
        self._loaded = False  # a load request was accepted
        self._hold = Hold(lease_s, time.perf_counter, on_lapse=self._running.clear)
        self._tally = Tally(self.stats)
        self._viewpoints = ViewpointReceiver(predictor, self._hold, self._tally, self._stop)
        self._transmitter = KeyframeTransmitter(self.queue, self._hold, self._tally, codec,
                                                self._stop)
        self._producer = KeyframeProducer(self.queue, self.stats, self._viewpoints,
                                          self._hold, lambda: self._transmitter.delta_t,
                                          self._running, self._stop)

    @property
    def now(self):
        """The server clock (seconds; replaceable in tests): the hold's and prediction's."""
        return self._hold.now

    @now.setter
    def now(self, clock) -> None:
        self._hold.now = clock

    @property
    def lease_s(self) -> float:
        return self._hold.lease_s

    def holder(self) -> str | None:
        """The id of the client holding the server, or None; lapses an expired hold."""
        return self._hold.current()

    def shutdown(self) -> None:
        """Make :meth:`run` return (thread-safe)."""
        self._stop.set()

    def run(self) -> None:
        """SERVER-CONTROL: start the other modules' threads, answer control requests until
        ``shutdown``."""
        control, views, keyframes = self._bind()
        threads = [threading.Thread(target=self._viewpoints.run, args=(views,), daemon=True,
                                    name="viewpoints"),
                   threading.Thread(target=self._producer.run, daemon=True, name="renderer"),
                   threading.Thread(target=self._transmitter.run, args=(keyframes,),
                                    daemon=True, name="transmitter")]
        for t in threads:
            t.start()
        log.info("LOD server on %s", ", ".join(self.addresses))
        try:
            while not self._stop.is_set():
                if not control.poll(100):
                    continue
                try:  # a REP socket: exactly one reply to each message received
                    frames = recv_frames(control, CONTROL_FRAMES)
                except zmq.Again:
                    continue
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

    # ------------------------------------------------------------------------- sockets

    def _bind(self) -> list[zmq.Socket]:
        """The control, viewpoint and keyframe sockets, bound (:class:`LodspriteError` if
        they cannot be, with nothing left open)."""
        socks: list[zmq.Socket] = []
        try:
            if self.keys is not None:
                from zmq.auth.thread import ThreadAuthenticator

                self._auth = ThreadAuthenticator(self._ctx)
                self._auth.start()
                # Only clients whose public key file lies in the keys folder get in.
                self._auth.configure_curve(domain="*", location=str(self.keys.clients_dir))
            self._socket(zmq.REP, MAX_CONTROL_BYTES, socks)
            views = self._socket(zmq.SUB, MAX_VIEWPOINT_BYTES, socks)
            views.setsockopt(zmq.SUBSCRIBE, b"")
            views.setsockopt(zmq.RCVHWM, 1000)
            keyframes = self._socket(zmq.ROUTER, MAX_ACK_BYTES, socks)
            keyframes.setsockopt(zmq.ROUTER_MANDATORY, 1)  # unknown peer: an error, not a drop
            keyframes.setsockopt(zmq.ROUTER_HANDOVER, 1)   # a reconnecting client takes over
            keyframes.setsockopt(zmq.SNDHWM, 2)
            for sock, address in zip(socks, self.addresses, strict=True):
                sock.bind(address)
        except zmq.ZMQError as exc:
            for s in socks:
                s.close(linger=0)
            if self._auth is not None:
                self._auth.stop()
            self._ctx.term()
            raise LodspriteError(f"cannot bind {', '.join(self.addresses)}: {exc}") from exc
        return socks

    def _socket(self, kind: int, max_bytes: int, socks: list) -> zmq.Socket:
        sock = self._ctx.socket(kind)
        socks.append(sock)
        sock.setsockopt(zmq.MAXMSGSIZE, max_bytes)
        sock.setsockopt(zmq.LINGER, 0)
        if self.keys is not None:
            self.keys.apply(sock)
        return sock

    # ----------------------------------------------------------------- SERVER-CONTROL

    def _control(self, frames: list) -> dict:
        """The reply (a map) to one control message; never raises."""
        self._tally.received("control")
        try:
            try:
                check_frames(frames)
                msg, _ = decode_message(frames, Control)
            except ProtocolError as exc:
                self._tally.reject("control", exc)
                return {"kind": "reply", "seq": 0, "ok": False, "error": str(exc)[:4000]}
            reply = {"kind": "reply", "seq": msg.seq, "ok": True, "error": "", "data": {}}
            error = self._handle(msg, reply)
            if error is not None:
                self._tally.refuse(msg.op, error)  # said once per op, not per reason
                reply.update(ok=False, error=error[:4000])
            return reply
        except Exception as exc:  # a bug must not stop the server: say so, keep serving
            self._tally.once(f"internal:{type(exc).__name__}", logging.ERROR,
                             "internal error handling a control message: %r", exc)
            return {"kind": "reply", "seq": 0, "ok": False,
                    "error": f"internal error: {type(exc).__name__}"}

    def _handle(self, msg: Control, reply: dict) -> str | None:
        """Carry out one control request; the reason for refusing it, or None."""
        holder = self.holder()
        mine = self._hold.touch(msg.client)
        free = holder is None
        op = msg.op
        if op == "ping":
            reply["data"] = {"state": self._producer.state, "error": self._producer.error,
                             "running": self._running.is_set(), "loaded": self._loaded,
                             "held": not free, "yours": mine}
        elif op == "stats":
            reply["data"] = self.stats.as_dict()
        elif not (free or mine) and op != "release":
            return "held by another client"
        elif op == "load":
            return self._load(msg.args, msg.client)
        elif op == "start":
            if not mine:
                return "load a scene first"
            if self._producer.state == "failed":  # a start must not outlive its scene
                return f"the scene failed: {self._producer.error}"
            self._running.set()
        elif op == "stop":
            if mine:
                self._running.clear()
        elif op == "release":
            if not free and not mine:
                return "held by another client"
            if mine:
                self._hold.drop()
                self._running.clear()
        elif op == "path":
            return "path: only a web page's session (serve --web) sends a path"
        elif op == "shutdown":
            if not self.allow_shutdown:
                return ("shutdown: not allowed (this server was started without "
                        "--allow-shutdown)")
            if not mine:
                return "shutdown: only the client holding the server may stop it"
            self._stop.set()
        return None

    def _load(self, args: LoadArgs, client: str) -> str | None:
        """Hand the scene ``args`` names to the renderer, or the reason not to."""
        try:
            terrain = self.datasets.terrain(args.terrain)
            texture = self.datasets.texture(args.texture)
        except InputError as exc:
            return f"load: {exc}"
        grid = working_grid(args)
        if args.lod > grid:
            return f"load: lod {args.lod} exceeds the working grid {grid}"
        need = estimate_scene_bytes(args, terrain.shape, texture.shape)
        error = self._too_big(args, grid, terrain.shape, texture.shape)
        if error is not None:
            return error
        resolved = msgspec.structs.replace(args, terrain=terrain.spec, texture=texture.spec)
        if self._hold.take(client):  # a new session: nothing of the previous one is kept
            self._viewpoints.reset(client)
        self._producer.request(resolved, need)
        self._loaded = True
        return None

    def _too_big(self, args: LoadArgs, grid: int, source: tuple | None,
                 texture_shape: tuple | None) -> str | None:
        """Why this machine cannot hold the scene (working grid ``grid``, source and
        texture shapes), or None: sides against the GL maximum texture size, memory."""
        max_tex = self._producer.max_texture
        if max_tex is not None:
            sides = {"working grid": grid + 1, "keyframe": max(args.size),
                     "texture": max(texture_shape) if texture_shape else grid + 1}
            for what, side in sides.items():
                if side > max_tex:
                    return (f"load: {what} side {side} exceeds this GL driver's maximum "
                            f"texture size {max_tex}")
        # the current scene goes first: its memory counts as available
        reason = check_scene_memory(args, source, texture_shape, self._producer.scene_bytes)
        return None if reason is None else f"load: {reason}"
