"""The LOD client (Swan et al. 2002, §3.2, Figure 5): spriteframes from server keyframes.

SPRITEFRAME-RENDERER (:meth:`LodClient.frame`, on the caller's thread, which owns the GL
context): send the viewpoint (never blocks; the server keeps only the newest), drain
the CLIENT-KEYFRAME-QUEUE to its newest keyframe, render the coarse level textured from
it with the LOD-sprite visibility rules.  ``adopt="newest"`` (default) takes every newer
keyframe at once, as in the paper.  With ``adopt="needed"`` a newer keyframe waits until
the 1999 error metric of the current viewpoint against the shown keyframe reaches half
of ε, sparing uploads when keyframes arrive faster than they are needed (a server with
pace ``continuous``; with the default pace ``needed`` the server already renders a
keyframe only when one is due).  With ``adopt="better"`` a newer keyframe is shown
once its error metric at the current viewpoint is lower than the shown one's: a keyframe
placed by a viewpoint prediction that overshot waits until the viewer reaches it,
instead of replacing a better one.  A keyframe's ``C'`` (1.3 ms for Jacksboro, 3.6 ms
for a 512² fractal, at a 16² coarse level) is computed once, in the first frame that
considers it; a frame then costs one or two metric evaluations (about 0.04 ms each).

The client's own keyframes (Chen, Swan & Kaufman 1999, §3.1 step 1, rendered in the
frame loop at the current viewpoint, as the inline algorithm does):

* before any server keyframe is shown (no server yet, or none that answers), whenever
  the error metric (Eq. 2, :func:`~lodsprite.sprite.policy.keyframe_error_px`) of the
  shown keyframe reaches ε: the 1999 algorithm;
* afterwards only with ``max_error`` (pixels): when the shown keyframe's error at the
  current viewpoint reaches it (``inf``, nothing measurable, included) and no better
  server keyframe has arrived.  A server keyframe whose error here is ``max_error`` or
  more is then kept back (it would be replaced at once) until the viewer is where it
  serves.  Without ``max_error`` (the paper's client) a server keyframe, once shown, is
  shown until a newer one is taken, however far the viewer has gone from it.

Frames drawn from the client's own keyframes are ``local_keyframe`` (rendered this
frame) and ``local_sprite``.  Every frame, keyframe frames included, is a spriteframe
drawn from the keyframe it shows, and every keyframe shown (server or own) is logged in
:attr:`LodClient.shown`, so that :mod:`lodsprite.distributed.quality` can replay each
frame exactly.

KEYFRAME-RECEIVER (:meth:`LodClient.receive`, on the frame's thread at the start of each
frame; never waits): takes the keyframes every server has sent (frame by frame, keeping
at most the three a keyframe has, and without copying them: the images are views of the
received frames and go to the textures as they are), at most :data:`RECEIVE_BUDGET`
messages or :data:`RECEIVE_MS` a frame; acknowledges them, drops any not newer than the
last one from the same server (unless none came from it for :data:`SEQ_RESET_S`), and
keeps the newest (``C'`` is never computed for a keyframe a newer one replaced before a
frame considered it).  It refuses malformed messages, keyframes whose images are not this
client's keyframe size (the image size: the client's sprite drawer has no guard band)
and anything else a message may cause, counts them (:attr:`LodClient.rejected_keyframes`)
and goes on: no message stops it.  Refused keyframes are not acknowledged, and an
acknowledgement is never waited for: one the server does not take is dropped and counted
(:attr:`LodClient.dropped_acks`).
CLIENT-CONTROL (:class:`~lodsprite.distributed.link.LinkKeeper`, on the frame's thread
too, never waiting): loads the scene on each server (with the client's coarse level,
visibility rule, ε and pace, so that the server sends the z-buffer this client reads and
keyframes when it needs them) and starts it, pings every second and loads again when a
server comes back after a restart.  When no server answers, the client says so once and
draws from its last keyframe; it says so again when one is back.

Neither is a thread: moderngl holds the GIL through each draw call, so a thread beside
the frame loop runs only between draws.  Sockets only wait, so a zero-timeout poll on the
frame's thread (:func:`lodsprite.workers.ready`) does a receiver thread's work without
one, and a keyframe is acknowledged when the frame that can show it takes it.  Under the
test's flood (5,000 refused messages, then 200 keyframes, from a server that reads no
acknowledgement) the last keyframe was shown after 3.8-4.7 s here (6.3-12.4 s with the
receiver thread), and after 5.9-14.4 s with two full-resolution renders running beside
the client (12.4-16.8 s with the thread).
"""

from __future__ import annotations

import itertools
import logging
import time

import numpy as np
import zmq

from lodsprite.distributed.frames import check_frames, recv_frames
from lodsprite.distributed.keys import ClientKeys
from lodsprite.distributed.link import LinkKeeper, ServerLink, control
from lodsprite.distributed.pacing import DEFAULT_PACE, PACES
from lodsprite.distributed.protocol import (
    Keyframe,
    ProtocolError,
    decode_keyframe,
    encode,
    viewpoint_to_wire,
)
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.sprite import SpriteDrawer
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.record import Frame
from lodsprite.scene import Scene
from lodsprite.sprite.adoption import AdoptionRule
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_due, keyframe_error_px
from lodsprite.workers import ready

log = logging.getLogger("lodsprite.client")

#: The client's bound on the error of the frames it shows, pixels (None: no bound, the
#: paper's client).  4 px, chosen from ``lodsprite reproduce swan2002`` and a sweep of
#: bounds (README): the worst frame shows 4 px instead of the paper client's tens to
#: hundreds, with the client's own keyframes about 1 % of frames; a bound of ε (1 px)
#: turns half the keyframes into the client's own and raises the frame-time σ about
#: 6.5-fold (9.86 ms against 1.51 ms in the measured sweep).
DEFAULT_MAX_ERROR: float | None = 4.0
KEYFRAME_FRAMES = 3
"""Frames of a keyframe message (header, colour, depth); the receiver keeps no more."""
RECEIVE_BUDGET = 64
"""Messages the receiver takes in one frame at most (the servers hold the rest)."""
RECEIVE_MS = 8.0
"""Milliseconds the receiver spends in one frame at most (checked after each message)."""
SEQ_RESET_S = 2.0
"""A keyframe not newer than the last one taken from its server is dropped, unless none
was taken for this long: then its sequence number starts afresh (a server that sent a
number far ahead, by fault or restart, cannot freeze the link)."""


def check_max_error(max_error: float | None) -> float | None:
    """``max_error`` as a float in pixels, or None (no bound); raises :class:`InputError`
    unless it is None or a number > 0."""
    if max_error is None:
        return None
    value = float(max_error)
    if not value > 0:  # NaN too
        raise InputError(f"--max-error must be > 0 pixels (or off), got {max_error}")
    return value


class LodClient:
    """Spriteframes along any viewpoint stream, keyframes from one or more LOD servers.

    ``max_error``: bound (pixels) on the error of the keyframe shown, above which the
    client renders its own keyframe; None: no bound (the paper's client).  ``ctx``: the
    GL context to draw with (a viewer window's); None makes a headless one.
    """

    def __init__(self, scene: Scene, scene_args: dict, servers: list[str],
                 size: tuple[int, int] = (512, 512), lod: int = 16,
                 visibility: str = "coarse", epsilon: float = 1.0,
                 adopt: str = "newest", keys: ClientKeys | None = None,
                 border: bool = True, pace: str = DEFAULT_PACE,
                 max_error: float | None = DEFAULT_MAX_ERROR,
                 ctx: GLContext | None = None) -> None:
        if pace not in PACES:
            raise InputError(f"pace must be one of {', '.join(PACES)}, got {pace!r}")
        if not epsilon > 0:
            raise InputError(f"error threshold epsilon must be > 0 pixels, got {epsilon}")
        self.adopt = adopt
        self.epsilon_px = float(epsilon)
        self.max_error = check_max_error(max_error)
        self.rule = AdoptionRule(adopt, self.epsilon_px, self.max_error)
        # (server slot, keyframe, C' or None) received and not shown yet
        self._pending: tuple[int, Keyframe, np.ndarray | None] | None = None
        # C' of the shown keyframe (None: nothing shown yet, or a server keyframe whose
        # C' no rule here reads)
        self._c_prime: np.ndarray | None = None
        self._own = False  # whether the shown keyframe is the client's own
        self.scene_args = {**scene_args, "lod": lod, "visibility": visibility,
                           "border": border, "epsilon": float(epsilon), "pace": pace}
        self.terrain_gl = TerrainGL(scene, size, float(scene_args.get("fov_y_deg", 45.0)), ctx)
        self.sprite = SpriteDrawer(self.terrain_gl.drawer, lod, visibility, border=border,
                                     guard_px=0)
        self.metric = ErrorMetric.for_level(scene.hf, lod)
        # the newest keyframe received and not yet considered: (slot, keyframe, None)
        self._arrived: tuple[int, Keyframe, np.ndarray | None] | None = None
        self._zmq = zmq.Context()
        self._servers = [ServerLink(self._zmq, a, keys) for a in servers]
        self._poller = zmq.Poller()
        for link in self._servers:
            self._poller.register(link.keyframes, zmq.POLLIN)
        self._by_socket = {link.keyframes: (i, link) for i, link in enumerate(self._servers)}
        self._counter = itertools.count(1)
        self._current: Keyframe | None = None  # the last server keyframe taken
        # Every keyframe shown, in order: {slot, seq, t0, viewpoint, local} (to replay
        # the frames afterwards and measure their image error).  The client's own have
        # ``local: true``, ``seq`` 0 and the slot of the last server keyframe shown (0
        # before any): the servers' turns (pacing) go on from that server.
        self.shown: list[dict] = []
        self.local_keyframes = 0
        self._silent = False
        self.rejected_keyframes = 0
        self.dropped_acks = 0  # acknowledgements a server did not take (never waited for)
        self._logged: set[str] = set()  # kinds of rejection said once already
        self._keepers = [LinkKeeper(link, {**self.scene_args, "slot": i,
                                           "slots": len(self._servers)}, self._counter)
                         for i, link in enumerate(self._servers)]
        self.pump()

    def pump(self) -> None:
        """CLIENT-CONTROL and KEYFRAME-RECEIVER's work so far, without waiting (each
        frame does it; call it to make progress without drawing)."""
        for keeper in self._keepers:
            keeper.step()
        self.receive()

    # ---------------------------------------------------------------- KEYFRAME-RECEIVER

    def receive(self) -> int:
        """Take what the servers have sent, without waiting (at most
        :data:`RECEIVE_BUDGET` messages and about :data:`RECEIVE_MS`); returns the
        messages taken."""
        taken, t_end = 0, time.perf_counter() + RECEIVE_MS / 1e3
        for sock in ready(list(self._by_socket), self._poller):
            slot, s = self._by_socket[sock]
            while taken < RECEIVE_BUDGET:
                try:
                    self._take(slot, s, sock)
                except zmq.Again:
                    break
                except Exception as exc:  # noqa: BLE001 - no message may stop the receiver
                    self._reject(s, exc)
                taken += 1
                if time.perf_counter() > t_end:  # checked after one: a loaded machine
                    return taken               # still takes a message a frame
        return taken

    def _take(self, slot: int, s: ServerLink, sock: zmq.Socket) -> bool:
        """Receive one message from server ``slot``; keep it if it is a newer keyframe
        this client can show.  Raises for anything else (``zmq.Again``: none waiting)."""
        frames = recv_frames(sock, KEYFRAME_FRAMES)
        check_frames(frames)
        kf = decode_keyframe(frames)
        self._check_fits(kf)  # a refused keyframe is not acknowledged
        try:  # never waits: a server that reads no acknowledgements loses them
            sock.send_multipart(encode({"kind": "ack", "seq": kf.seq,
                                        "t": time.perf_counter()}), flags=zmq.NOBLOCK)
        except zmq.Again:
            self.dropped_acks += 1
        now = time.monotonic()
        if kf.seq <= s.last_seq and now - s.last_taken < SEQ_RESET_S:
            return True  # older than one taken from this server lately
        s.last_seq, s.last_taken = kf.seq, now
        s.taken += 1
        self._arrived = (slot, kf, None)  # newest wins; its C' when a frame needs it
        return True

    def _check_fits(self, kf: Keyframe) -> None:
        """Raise :class:`ProtocolError` unless ``kf`` can be uploaded here: images of this
        client's keyframe size and a z-buffer its visibility rule reads."""
        w, h = self.sprite.key_size
        if kf.color.shape != (h, w, 3) or kf.depth.shape != (h, w):
            raise ProtocolError(f"keyframe images must be {w}x{h}, got colour "
                                f"{kf.color.shape}, depth {kf.depth.shape}")
        if kf.zbuffer not in ("full", "coarse") or (kf.zbuffer == "coarse"
                                                    and self.sprite.visibility != "coarse"):
            raise ProtocolError(f"a {kf.zbuffer!r} z-buffer does not serve the "
                                f"{self.sprite.visibility!r} visibility rule")

    def _reject(self, s: ServerLink, exc: BaseException) -> None:
        """Count a refused message; say it once per kind of fault."""
        self.rejected_keyframes += 1
        kind = type(exc).__name__
        level = logging.DEBUG if kind in self._logged else logging.WARNING
        self._logged.add(kind)
        log.log(level, "rejected keyframe message from %s (%s): %s", s.address, kind, exc)

    # ------------------------------------------------------------ SPRITEFRAME-RENDERER

    def frame(self, viewpoint) -> Frame:
        """Draw one frame for ``viewpoint``; returns once its GL work has finished.  Its
        ``kind``: ``keyframe`` (a server keyframe was taken this frame), ``sprite`` (drawn
        from a server keyframe), ``local_keyframe`` (the client rendered its own this
        frame) or ``local_sprite``; ``ms`` wall time; ``extra``: ``keyframe_seq`` (the shown
        server keyframe's sequence number, 0 for the client's own) and ``keyframe`` (the
        shown keyframe's index in :attr:`shown`).  ``error_px`` is NaN (measured apart,
        :meth:`shown_error_px`)."""
        t0 = time.perf_counter()
        header = {"kind": "viewpoint", "seq": next(self._counter), "t": t0,
                  "viewpoint": viewpoint_to_wire(viewpoint)}
        if self._current is not None:
            last = self.shown[-1]  # the shown keyframe, for the servers' pacing
            header["shown"] = {"eye": last["viewpoint"]["o"], "slot": last["slot"]}
        for s in self._servers:
            s.send_viewpoint(header)  # adds the link's client id
        projection = self.terrain_gl.drawer.projection(viewpoint)
        self.pump()
        kind = "local_sprite" if self._own else "sprite"
        triangles = 0
        if self._arrived is not None:
            self._pending, self._arrived = self._arrived, None
        if self._pending is not None and self._pending[2] is None and (
                self.rule.compares):
            slot, kf, _ = self._pending  # C' for the rules that compare errors
            self._pending = (slot, kf, self.metric.reproject(kf.viewpoint.o))
        if self._pending is not None and self._should_adopt(viewpoint, projection,
                                                            self._pending[2]):
            (slot, kf, self._c_prime), self._pending = self._pending, None
            self.sprite.upload_keyframe(kf.viewpoint, kf.projection, kf.color, kf.depth, kf.t0,
                                        kf.zbuffer)
            self._current, self._own, kind = kf, False, "keyframe"
            self.shown.append({"slot": slot, "seq": kf.seq, "t0": kf.t0,
                               "viewpoint": kf.viewpoint.to_dict(), "local": False})
        if self._own_keyframe_due(viewpoint, projection):
            triangles += self.sprite.render_keyframe(viewpoint, t0, projection).triangles
            self._c_prime, self._own = self.metric.reproject(viewpoint.o), True
            kind = "local_keyframe"
            self.local_keyframes += 1
            self.shown.append({"slot": self.shown[-1]["slot"] if self.shown else 0, "seq": 0,
                               "t0": t0, "viewpoint": viewpoint.to_dict(), "local": True})
        triangles += self.sprite.render_spriteframe(viewpoint, projection).triangles
        self.terrain_gl.ctx.finish()
        self._say_link_state()
        seq = self._current.seq if self._current is not None and not self._own else 0
        return Frame(kind, (time.perf_counter() - t0) * 1e3, triangles,
                     extra={"keyframe_seq": seq, "keyframe": len(self.shown) - 1})

    def _error(self, c_prime: np.ndarray, viewpoint, projection) -> float:
        """Error (pixels, Eq. 2) of the keyframe with ``C' = c_prime`` here; may be inf."""
        return keyframe_error_px(self.metric, c_prime, viewpoint, projection,
                                 self.sprite.target.height)

    def shown_error_px(self, viewpoint) -> float:
        """Error (pixels, Eq. 2) of the shown keyframe at ``viewpoint``; NaN when none is
        shown or its ``C'`` is unknown."""
        if self._c_prime is None:
            return float("nan")
        return self._error(self._c_prime, viewpoint, self.terrain_gl.drawer.projection(viewpoint))

    @property
    def links_alive(self) -> list[bool | None]:
        """Per server: answers (True), silent (False) or not asked yet (None)."""
        return [s.alive for s in self._servers]

    def _own_keyframe_due(self, viewpoint, projection) -> bool:
        """Whether to render the client's own keyframe: nothing shown yet, or the shown
        keyframe's error here reached the bound (ε before any server keyframe was taken,
        then ``max_error``; inf and NaN reach any bound)."""
        if not self.shown:
            return True
        bound = self.epsilon_px if self._current is None else self.max_error
        if bound is None:
            return False
        return keyframe_due(self._error(self._c_prime, viewpoint, projection), bound)

    def _say_link_state(self) -> None:
        """Say once when no server answers any more, and once when one answers again."""
        states = [s.alive for s in self._servers]
        if not self._silent and states and all(a is False for a in states):
            self._silent = True
            log.warning("no LOD server answers: drawing from the %s",
                        "last keyframe" if self._current is not None else "client's own keyframes")
        elif self._silent and any(states):
            self._silent = False
            log.warning("a LOD server answers again")

    def _should_adopt(self, viewpoint, projection, c_prime: np.ndarray | None) -> bool:
        """Whether to show the pending server keyframe (``C' = c_prime``) now.

        The rule of :class:`~lodsprite.sprite.adoption.AdoptionRule` (``adopt`` and
        ``max_error``); the first server keyframe is always taken (when it is within
        ``max_error``)."""
        shown = (None if self._current is None or self._c_prime is None else
                 lambda: self._error(self._c_prime, viewpoint, projection))
        return self.rule.adopt(shown, lambda: self._error(c_prime, viewpoint, projection))

    def image(self):
        """The last frame's image, ``(H, W, 3) uint8``, row 0 at the top."""
        return self.sprite.target.read_color()

    def server_stats(self) -> list[dict]:
        out = []
        for s in self._servers:
            reply = control(s, self._counter, "stats")
            out.append(reply.get("data", {}) if reply else {})
        return out

    def close(self, shutdown_servers: bool = False) -> None:
        if shutdown_servers:
            for s in self._servers:
                control(s, self._counter, "shutdown")
        for s in self._servers:
            s.close()
        self._zmq.destroy(linger=0)  # closes any socket still open, then ends the context
        self.sprite.release()
        self.terrain_gl.release()
