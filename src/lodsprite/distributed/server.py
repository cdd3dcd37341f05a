"""The LOD server (Swan, Arango & Nakshatrala 2002, §3.3, Figures 6-7): renders keyframes.

No user interface: it is driven by messages on three connections, bound to consecutive
ports ``port``, ``port + 1``, ``port + 2`` (the paper's Figure 4):

* control (REP): ``ping``, ``load`` (terrain, texture, grid, exaggeration, size, fov, and
  the client's coarse level, visibility rule, ε and pace), ``start``, ``stop``,
  ``release``, ``stats``, ``shutdown``;
* viewpoint (SUB): viewpoint samples, each stamped with the client's clock;
* keyframe (ROUTER): keyframes out to the client that holds the server, acknowledgements
  back.

Modules, each a thread: SERVER-CONTROL, the viewpoint receiver feeding the
VIEWPOINT-PREDICTOR, KEYFRAME-RENDERER (owns the GL context), SERVER-KEYFRAME-QUEUE
(capacity 2) and KEYFRAME-TRANSMITTER, which measures ``δt = t1 - t0``.  With pace
``needed`` (default; :mod:`lodsprite.distributed.pacing`) the renderer waits until the
client will need a new keyframe; ``continuous`` renders back to back as in the paper.

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
  ``lease_s`` seconds without a message from the holder, or on its ``release``.
* A client names datasets, not paths (:mod:`.datasets`).  A ``load`` the machine cannot
  hold (estimated memory against ``MemAvailable``, sizes against the GL maximum texture
  size) is refused before anything is allocated.
* The renderer thread survives a scene that fails to load or render (any exception,
  ``MemoryError`` and GL errors included): ``ping`` answers ``state`` (``idle``,
  ``loading``, ``ready``, ``failed``) and the last ``error``; a later ``load`` starts
  afresh.
* Every socket has a ``zmq.MAXMSGSIZE``; the server binds loopback unless
  ``allow_remote``.

Prediction uses the client's clock: each sample is observed at the client time ``t`` it
carries, and a keyframe is aimed ``δt`` plus the time since the newest sample arrived
(server clock) after that sample.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import zmq

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.keys import ServerKeys
from lodsprite.distributed.predictors import PREDICTORS
from lodsprite.distributed.protocol import (
    CODECS,
    MAX_ACK_BYTES,
    MAX_CONTROL_BYTES,
    MAX_VIEWPOINT_BYTES,
    Ack,
    Control,
    Keyframe,
    LoadArgs,
    ProtocolError,
    ViewpointMessage,
    decode_message,
    encode,
    encode_keyframe,
    shown_from_wire,
    viewpoint_from_wire,
)
from lodsprite.distributed.queue import Closed, KeyframeQueue
from lodsprite.distributed.render import (
    KeyframeRenderer,
    estimate_scene_bytes,
    memory_available,
    working_grid,
)
from lodsprite.errors import InputError, LodspriteError

log = logging.getLogger("lodsprite.server")

DEFAULT_BIND = "127.0.0.1:5555"
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
ACK_TIMEOUT_S = 5.0
LEASE_S = 10.0
"""Seconds without a message from the holding client after which its hold lapses."""
MAX_ELAPSED_S = 1.0
"""Longest time since the newest viewpoint sample that prediction extrapolates over."""
MIN_SAMPLE_SPACING_S = 1e-4
"""Samples closer than this (client clock) to the previous one are ignored."""
MEMORY_FRACTION = 0.8
"""Share of the available memory a scene may take (its estimate)."""
STATES = ("idle", "loading", "ready", "failed")


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


@dataclass
class ServerStats:
    """Per-keyframe timings (ms) of Figures 11-12.  ``production_ms`` is the whole
    Figure 6 loop: ``viewpoint_wait_ms`` (for a first viewpoint), ``paced_ms`` (with
    pace ``needed``, until a keyframe is due), ``render_ms`` and ``queue_insert_ms``.

    ``rejected`` counts malformed messages per socket (``control``, ``viewpoint``,
    ``ack``; ``rejected_messages`` is their sum) of those ``received`` per socket
    (``control``, ``viewpoint``, ``keyframe``); ``ignored`` counts well-formed
    messages set aside (from a client that does not hold the server, or viewpoint
    samples not newer than the last); ``refused`` counts control requests answered
    ``ok: false`` per op."""

    production_ms: list = field(default_factory=list)
    viewpoint_wait_ms: list = field(default_factory=list)
    paced_ms: list = field(default_factory=list)
    render_ms: list = field(default_factory=list)
    queue_insert_ms: list = field(default_factory=list)
    delta_t_ms: list = field(default_factory=list)
    queue_retrieve_ms: list = field(default_factory=list)
    transmission_ms: list = field(default_factory=list)
    rejected_messages: int = 0
    received: dict = field(default_factory=lambda: {"control": 0, "viewpoint": 0,
                                                    "keyframe": 0})
    rejected: dict = field(default_factory=lambda: {"control": 0, "viewpoint": 0, "ack": 0})
    ignored: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    keyframes_sent: int = 0

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, list) else dict(v) if isinstance(v, dict) else v
                for k, v in self.__dict__.items()}


class LodServer:
    """A keyframe server; :meth:`run` blocks until a ``shutdown`` message (or
    :meth:`shutdown`).

    ``bind`` is ``HOST:PORT``; a host other than loopback needs ``allow_remote=True``
    (raises :class:`InputError` otherwise).  ``data_dir``: the folder whose files clients
    may name (None: built-in datasets only).  ``lease_s``: see the module docstring.
    """

    def __init__(self, bind: str = DEFAULT_BIND, predictor: str = "linear",
                 codec: str = "raw", keys: ServerKeys | None = None,
                 data_dir: Path | str | None = None, allow_remote: bool = False,
                 lease_s: float = LEASE_S) -> None:
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
        self.lease_s = float(lease_s)
        self.stats = ServerStats()
        self.queue: KeyframeQueue[Keyframe] = KeyframeQueue(2)
        self.now = time.perf_counter  # the server clock (replaceable in tests)
        self._ctx = zmq.Context()
        self._auth = None
        self._stop = threading.Event()
        self._running = threading.Event()
        self._scene_lock = threading.Lock()
        self._scene_request: LoadArgs | None = None
        self._scene_bytes = 0  # estimate for the scene asked for last
        self._loaded = False  # a load request was accepted
        self._state, self._error = "idle", ""
        self._max_texture: int | None = None  # from the GL driver, once probed
        self._hold_lock = threading.Lock()
        self._holder: str | None = None
        self._holder_seen = 0.0
        self._latest_lock = threading.Lock()
        self._predictor = PREDICTORS[predictor]()
        self._last_t: float | None = None  # client clock of the newest sample
        self._last_arrival = 0.0  # server clock when it arrived
        self._last_vp = None
        self._have_viewpoint = threading.Event()
        self._fresh_viewpoint = threading.Event()  # set by each viewpoint received
        self._shown = None  # (eye, slot) of the keyframe the client says it shows
        self._slot, self._slots = 0, 1  # this server's place among the client's servers
        self._delta_t = 0.5  # seconds, until the transmitter has measured one
        self._seq = 0
        self._logged: set[str] = set()

    # --------------------------------------------------------------------- bookkeeping

    def _once(self, key: str, level: int, text: str, *args) -> None:
        """Log ``text`` the first time ``key`` comes up (a flood must not flood the log)."""
        if key not in self._logged:
            self._logged.add(key)
            log.log(level, text + " (said once)", *args)

    def _reject(self, kind: str, exc: Exception) -> None:
        self.stats.rejected[kind] = self.stats.rejected.get(kind, 0) + 1
        self.stats.rejected_messages += 1
        self._once(f"reject:{kind}", logging.WARNING, "rejected %s message: %s", kind, exc)

    def _ignore(self, why: str) -> None:
        self.stats.ignored[why] = self.stats.ignored.get(why, 0) + 1

    def _set_state(self, state: str, error: str | None = None) -> None:
        self._state = state
        if error is not None:
            self._error = error

    def shutdown(self) -> None:
        """Make :meth:`run` return (thread-safe)."""
        self._stop.set()

    # -------------------------------------------------------------------------- holding

    def holder(self) -> str | None:
        """The id of the client holding the server, or None; lapses an expired hold."""
        with self._hold_lock:
            if self._holder is not None and self.now() - self._holder_seen > self.lease_s:
                log.info("the hold of client %s lapsed after %.0f s without a message",
                         self._holder or "(anonymous)", self.lease_s)
                self._holder = None
                self._running.clear()
            return self._holder

    def _touch(self, client: str) -> bool:
        """Note a message from ``client``; whether it holds the server."""
        with self._hold_lock:
            if self._holder is not None and client == self._holder:
                self._holder_seen = self.now()
                return True
            return False

    def _take_hold(self, client: str) -> None:
        with self._hold_lock:
            changed = client != self._holder
            self._holder, self._holder_seen = client, self.now()
        if changed:  # a new session: nothing of the previous client's motion is kept
            with self._latest_lock:
                self._predictor = PREDICTORS[self.predictor_name]()
                self._last_t, self._last_vp, self._shown = None, None, None
                self._have_viewpoint.clear()

    # ----------------------------------------------------------------- SERVER-CONTROL

    def run(self) -> None:
        socks = []
        try:
            if self.keys is not None:
                from zmq.auth.thread import ThreadAuthenticator

                self._auth = ThreadAuthenticator(self._ctx)
                self._auth.start()
                # Only clients whose public key file lies in the keys folder get in.
                self._auth.configure_curve(domain="*", location=str(self.keys.clients_dir))
            control = self._socket(zmq.REP, MAX_CONTROL_BYTES, socks)
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
        threads = [threading.Thread(target=self._receive_viewpoints, args=(views,), daemon=True,
                                    name="viewpoints"),
                   threading.Thread(target=self._render_keyframes, daemon=True, name="renderer"),
                   threading.Thread(target=self._transmit_keyframes, args=(keyframes,),
                                    daemon=True, name="transmitter")]
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

    def _socket(self, kind: int, max_bytes: int, socks: list) -> zmq.Socket:
        sock = self._ctx.socket(kind)
        socks.append(sock)
        sock.setsockopt(zmq.MAXMSGSIZE, max_bytes)
        sock.setsockopt(zmq.LINGER, 0)
        if self.keys is not None:
            self.keys.apply(sock)
        return sock

    def _control(self, frames: list) -> dict:
        """The reply (a map) to one control message; never raises."""
        self.stats.received["control"] += 1
        try:
            try:
                msg, _ = decode_message(frames)
                if not isinstance(msg, Control):
                    raise ProtocolError(f"expected a control message, got {type(msg).__name__}")
            except ProtocolError as exc:
                self._reject("control", exc)
                return {"kind": "reply", "seq": 0, "ok": False, "error": str(exc)[:4000]}
            reply = {"kind": "reply", "seq": msg.seq, "ok": True, "error": "", "data": {}}
            error = self._handle(msg, reply)
            if error is not None:
                self.stats.refused[msg.op] = self.stats.refused.get(msg.op, 0) + 1
                self._once(f"refuse:{msg.op}:{error}", logging.WARNING, "refused %s: %s",
                           msg.op, error)
                reply.update(ok=False, error=error[:4000])
            return reply
        except Exception as exc:  # a bug must not stop the server: say so, keep serving
            self._once(f"internal:{type(exc).__name__}", logging.ERROR,
                       "internal error handling a control message: %r", exc)
            return {"kind": "reply", "seq": 0, "ok": False,
                    "error": f"internal error: {type(exc).__name__}"}

    def _handle(self, msg: Control, reply: dict) -> str | None:
        """Carry out one control request; the reason for refusing it, or None."""
        holder = self.holder()
        mine = self._touch(msg.client)
        free = holder is None
        op = msg.op
        if op == "ping":
            reply["data"] = {"state": self._state, "error": self._error,
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
            self._running.set()
        elif op == "stop":
            if mine:
                self._running.clear()
        elif op == "release":
            if not free and not mine:
                return "held by another client"
            if mine:
                with self._hold_lock:
                    self._holder = None
                self._running.clear()
        elif op == "shutdown":
            self._stop.set()
        return None

    def _load(self, args: LoadArgs, client: str) -> str | None:
        try:
            terrain = self.datasets.terrain(args.terrain)
            texture = self.datasets.texture(args.texture)
        except InputError as exc:
            return f"load: {exc}"
        grid = working_grid(args)
        if args.lod > grid:
            return f"load: lod {args.lod} exceeds the working grid {grid}"
        max_tex = self._max_texture
        if max_tex is not None:
            sides = {"working grid": grid + 1, "keyframe": max(args.size),
                     "texture": max(texture.shape) if texture.shape else grid + 1}
            for what, side in sides.items():
                if side > max_tex:
                    return (f"load: {what} side {side} exceeds this GL driver's maximum "
                            f"texture size {max_tex}")
        need = estimate_scene_bytes(args, terrain.shape, texture.shape)
        available = memory_available()
        if available is not None:
            available += self._scene_bytes  # the current scene goes first
            if need > MEMORY_FRACTION * available:
                return (f"load: the scene needs about {need / 2**20:.0f} MiB, this machine "
                        f"has {available / 2**20:.0f} MiB available")
        resolved = msgspec.structs.replace(args, terrain=terrain.spec, texture=texture.spec)
        self._take_hold(client)
        self._slot, self._slots = args.slot, args.slots
        with self._scene_lock:
            self._scene_request = resolved
            self._scene_bytes = need
            self._set_state("loading", "")
        self._loaded = True
        return None

    # ------------------------------------------------------ viewpoints and prediction

    def _receive_viewpoints(self, sock: zmq.Socket) -> None:
        try:
            while not self._stop.is_set():
                if not sock.poll(50):
                    continue
                for _ in range(1000):  # everything queued, oldest first
                    try:
                        frames = sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self._viewpoint(frames)
        finally:
            sock.close(linger=0)

    def _viewpoint(self, frames: list) -> bool:
        """Take one viewpoint message; whether it was observed.  Never raises."""
        self.stats.received["viewpoint"] += 1
        try:
            try:
                msg, _ = decode_message(frames)
                if not isinstance(msg, ViewpointMessage):
                    raise ProtocolError(f"expected a viewpoint message, got "
                                        f"{type(msg).__name__}")
                vp = viewpoint_from_wire(msg.viewpoint)
                shown = shown_from_wire(msg.shown)
            except ProtocolError as exc:
                self._reject("viewpoint", exc)
                return False
            if self.holder() is None or not self._touch(msg.client):
                self._ignore("viewpoint_not_holder")
                return False
            with self._latest_lock:
                if self._last_t is not None and msg.t < self._last_t + MIN_SAMPLE_SPACING_S:
                    self._ignore("viewpoint_not_newer")
                    return False
                self._predictor.observe(msg.t, vp)  # the client's clock, not arrival
                self._last_t, self._last_arrival, self._last_vp = msg.t, self.now(), vp
                self._shown = shown
            self._have_viewpoint.set()
            self._fresh_viewpoint.set()
            return True
        except Exception as exc:
            self._once(f"internal:vp:{type(exc).__name__}", logging.ERROR,
                       "internal error handling a viewpoint: %r", exc)
            return False

    def _predicted_viewpoint(self):
        """The viewpoint a keyframe started now should show, and what the client shows.

        Aimed ``δt`` plus the time since the newest sample arrived (server clock, at most
        ``MAX_ELAPSED_S``) after that sample.  With several servers, server ``slot`` of
        ``slots`` aims ``δt (1 + slot/slots)`` ahead, so their keyframes cover different
        moments.  A prediction that fails (a client's odd samples) gives the newest
        sample itself."""
        with self._latest_lock:
            elapsed = min(max(self.now() - self._last_arrival, 0.0), MAX_ELAPSED_S)
            lead = self._delta_t * (1.0 + self._slot / self._slots) + elapsed
            try:
                vp = self._predictor.predict(lead)
            except (LodspriteError, ValueError, ArithmeticError):
                vp = self._last_vp
            return vp, self._shown

    def _due(self, renderer: KeyframeRenderer, vp, shown) -> bool:
        """Whether to render for ``vp``.  With several servers they take turns: it is this
        server's turn when the client shows the previous slot's keyframe."""
        eye, turn = None, True
        if shown is not None:
            eye, slot = shown
            turn = (slot + 1) % self._slots == self._slot
        return renderer.pacer.due(vp, renderer.projection(vp), eye, turn)

    # -------------------------------------------------------------- KEYFRAME-RENDERER

    def _probe_gl(self) -> None:
        """Read the GL driver's maximum texture size (for refusing oversized loads)."""
        from lodsprite.gl.context import GLContext

        try:
            ctx = GLContext()
        except Exception as exc:
            self._set_state("failed", f"no OpenGL: {exc}")
            log.error("no OpenGL context: %s", exc)
            return
        try:
            self._max_texture = ctx.info.max_texture_size
        finally:
            ctx.release()

    def _fail(self, what: str, exc: BaseException) -> None:
        error = f"{what}: {type(exc).__name__}: {exc}"[:2000]
        with self._scene_lock:
            if self._scene_request is None:  # a newer load is not failed by this one
                self._set_state("failed", error)
        self._running.clear()
        log.error("%s", error)

    def _render_keyframes(self) -> None:
        renderer: KeyframeRenderer | None = None

        def release() -> None:
            nonlocal renderer
            if renderer is not None:
                try:
                    renderer.release()
                except Exception as exc:  # a broken context: drop it all the same
                    log.warning("releasing the scene: %r", exc)
                renderer = None

        self._probe_gl()
        try:
            while not self._stop.is_set():
                self.holder()  # lapse an expired hold
                with self._scene_lock:
                    request, self._scene_request = self._scene_request, None
                if request is not None:
                    release()
                    try:
                        renderer = KeyframeRenderer(request)
                    except Exception as exc:  # MemoryError, GL errors, bad files, anything
                        self._fail("cannot load the scene", exc)
                    else:
                        with self._scene_lock:
                            if self._scene_request is None:
                                self._set_state("ready", "")
                if renderer is None or not self._running.is_set():
                    time.sleep(0.01)
                    continue
                try:
                    self._produce(renderer)
                except Closed:
                    raise
                except Exception as exc:
                    self._fail("cannot render a keyframe", exc)
                    release()
        except Closed:
            pass
        finally:
            release()

    def _produce(self, renderer) -> None:
        t0 = time.perf_counter()
        if not self._have_viewpoint.wait(0.1):
            return
        t_vp = time.perf_counter()
        vp, shown = self._predicted_viewpoint()
        while vp is None or not self._due(renderer, vp, shown):
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

    def _transmit_keyframes(self, sock: zmq.Socket) -> None:
        try:
            while not self._stop.is_set():
                t_wait = time.perf_counter()
                kf = self.queue.get(timeout=0.05)
                if kf is None:
                    self._drain_acks(sock)
                    continue
                holder = self.holder()
                if not holder:
                    if holder == "":
                        self._once("anonymous", logging.WARNING, "the holding client sent no "
                                   "id: its keyframes cannot be addressed")
                    continue
                t_send = time.perf_counter()
                if not self._send(sock, holder, kf):
                    continue
                if not self._await_ack(sock, holder, kf.seq):
                    self._once("no-ack", logging.WARNING, "no acknowledgement for keyframe %d",
                               kf.seq)
                    continue
                t1 = time.perf_counter()
                self._delta_t = t1 - kf.t0
                s = self.stats
                s.keyframes_sent += 1
                s.queue_retrieve_ms.append((t_send - t_wait) * 1e3)
                s.transmission_ms.append((t1 - t_send) * 1e3)
                s.delta_t_ms.append(self._delta_t * 1e3)
        except Closed:
            pass
        finally:
            sock.close(linger=0)

    def _send(self, sock: zmq.Socket, holder: str, kf: Keyframe) -> bool:
        """Send ``kf`` to the holder's keyframe socket; False when it cannot take it
        before the acknowledgement timeout (not connected, or not reading)."""
        frames = [holder.encode(), *encode_keyframe(kf, self.codec)]
        deadline = time.perf_counter() + ACK_TIMEOUT_S
        while not self._stop.is_set() and time.perf_counter() < deadline:
            if self.holder() != holder:
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
                    frames = sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    return
                self._ack(frames, None, -1)

    def _ack(self, frames: list, holder: str | None, seq: int) -> bool:
        """Take one message from the keyframe socket (``[identity, *message]``); whether it
        is ``holder``'s acknowledgement of keyframe ``seq``.  Never raises."""
        self.stats.received["keyframe"] += 1
        try:
            if len(frames) < 2:
                self._reject("ack", ProtocolError("no message after the identity frame"))
                return False
            try:
                msg, _ = decode_message(frames[1:])
                if not isinstance(msg, Ack):
                    raise ProtocolError(f"expected an ack, got {type(msg).__name__}")
            except ProtocolError as exc:
                self._reject("ack", exc)
                return False
            identity = bytes(frames[0])
            current = self.holder()
            if current is None or identity != current.encode():
                self._ignore("ack_not_holder")
                return False
            self._touch(current)
            return holder == current and msg.seq == seq
        except Exception as exc:
            self._once(f"internal:ack:{type(exc).__name__}", logging.ERROR,
                       "internal error handling an acknowledgement: %r", exc)
            return False

    def _await_ack(self, sock: zmq.Socket, holder: str, seq: int) -> bool:
        deadline = time.perf_counter() + ACK_TIMEOUT_S
        while not self._stop.is_set() and time.perf_counter() < deadline:
            if not sock.poll(50):
                if self.holder() != holder:
                    return False
                continue
            try:
                frames = sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                continue
            if self._ack(frames, holder, seq):
                return True
        return False
