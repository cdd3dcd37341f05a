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
instead of replacing a better one.  The receiver computes each keyframe's ``C'`` (about
2 ms) off the frame loop; a frame then costs two metric evaluations (about 0.04 ms
each).  It never waits for a keyframe: with none yet (no server, or
a server that died before sending one) it renders keyframes itself with the 1999
algorithm.

KEYFRAME-RECEIVER (a thread): receives keyframes from every server (without copying
them: the images are views of the received frames and go to the textures as they are),
acknowledges them, drops any not newer than the last one from the same server, and
queues the rest.  CLIENT-CONTROL (a thread): loads the scene on each server (with the
client's coarse level, visibility rule, ε and pace, so that the server sends the
z-buffer this client reads and keyframes when it needs them) and starts it, pings every
second and loads again when a server comes back after a restart.  When no server
answers, the client says so once and draws from its last keyframe; it says so again
when one is back.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from dataclasses import dataclass

import numpy as np
import zmq

from lodsprite.distributed.keys import ClientKeys
from lodsprite.distributed.link import ServerLink, control, keep_loaded
from lodsprite.distributed.pacing import DEFAULT_PACE, PACES
from lodsprite.distributed.protocol import (
    Keyframe,
    ProtocolError,
    decode_keyframe,
    encode,
    viewpoint_to_wire,
)
from lodsprite.distributed.queue import Closed, KeyframeQueue
from lodsprite.errors import InputError
from lodsprite.gl.paths import PathRenderer
from lodsprite.gl.sprite import SpriteRenderer
from lodsprite.scene import Scene
from lodsprite.sprite.engine import LodSpriteEngine
from lodsprite.sprite.policy import keyframe_error_px

log = logging.getLogger("lodsprite.client")

ADOPT_MODES = ("needed", "newest", "better")
ADOPT_FRACTION = 0.5


@dataclass(frozen=True)
class ClientFrame:
    """One client frame: ``type`` is ``keyframe`` (a server keyframe was taken this frame),
    ``sprite``, or ``local_keyframe`` / ``local_sprite`` (drawn without any server
    keyframe); wall time in ms; triangles drawn; the shown server keyframe's sequence
    number and its index in :attr:`LodClient.shown` (0 and -1 when none)."""

    type: str
    ms: float
    triangles: int
    keyframe_seq: int
    keyframe_index: int = -1


class LodClient:
    """Spriteframes along any viewpoint stream, keyframes from one or more LOD servers."""

    def __init__(self, scene: Scene, scene_args: dict, servers: list[str],
                 size: tuple[int, int] = (512, 512), lod: int = 16,
                 visibility: str = "coarse", epsilon: float = 1.0,
                 adopt: str = "newest", keys: ClientKeys | None = None,
                 border: bool = True, pace: str = DEFAULT_PACE) -> None:
        if adopt not in ADOPT_MODES:
            raise InputError(f"adopt must be one of {', '.join(ADOPT_MODES)}, got {adopt!r}")
        if pace not in PACES:
            raise InputError(f"pace must be one of {', '.join(PACES)}, got {pace!r}")
        self.adopt = adopt
        # (server slot, keyframe, C' or None) received and not shown yet
        self._pending: tuple[int, Keyframe, np.ndarray | None] | None = None
        self._c_prime = None
        self.scene_args = {**scene_args, "lod": lod, "visibility": visibility,
                           "border": border, "epsilon": float(epsilon), "pace": pace}
        self.paths = PathRenderer(scene, size, float(scene_args.get("fov_y_deg", 45.0)))
        self.sprite = SpriteRenderer(self.paths.renderer, lod, visibility, border=border,
                                     guard_px=0)
        self.local = LodSpriteEngine(self.sprite, epsilon)
        self.queue: KeyframeQueue[tuple[int, Keyframe, np.ndarray | None]] = KeyframeQueue(2)
        self._zmq = zmq.Context()
        self._servers = [ServerLink(self._zmq, a, keys) for a in servers]
        self._stop = threading.Event()
        self._counter = itertools.count(1)
        self._current: Keyframe | None = None
        # Every server keyframe taken, in order: {slot, seq, t0, viewpoint} (to replay
        # the frames afterwards and measure their image error).
        self.shown: list[dict] = []
        self._silent = False
        self.rejected_messages = 0
        self._threads = [threading.Thread(target=self._receive, daemon=True),
                         threading.Thread(target=self._control, daemon=True)]
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ CLIENT-CONTROL

    def _control(self) -> None:
        while not self._stop.is_set():
            for i, s in enumerate(self._servers):
                keep_loaded(s, {**self.scene_args, "slot": i, "slots": len(self._servers)},
                            self._counter)
            self._stop.wait(1.0)

    # ---------------------------------------------------------------- KEYFRAME-RECEIVER

    def _receive(self) -> None:
        poller = zmq.Poller()
        for s in self._servers:
            poller.register(s.keyframes, zmq.POLLIN)
        by_socket = {s.keyframes: (i, s) for i, s in enumerate(self._servers)}
        while not self._stop.is_set():
            for sock, _ in poller.poll(50):
                slot, s = by_socket[sock]
                frames = sock.recv_multipart(copy=False)
                try:
                    kf = decode_keyframe(frames)
                except ProtocolError as exc:
                    self.rejected_messages += 1
                    log.warning("rejected keyframe from %s: %s", s.address, exc)
                    continue
                sock.send_multipart(encode({"kind": "ack", "seq": kf.seq,
                                            "t": time.perf_counter()}))
                if kf.seq <= s.last_seq:
                    continue  # older than one already taken from this server
                s.last_seq = kf.seq
                # C' for the adoption rules that compare errors, computed here, not in
                # the frame loop
                c_prime = (None if self.adopt == "newest"
                           else self.local.metric.reproject(kf.viewpoint.o))
                try:
                    if not self.queue.put((slot, kf, c_prime), timeout=0):
                        self.queue.drain()  # full: newest wins
                        self.queue.put((slot, kf, c_prime), timeout=0)
                except Closed:
                    return  # the client is closing

    # ------------------------------------------------------------ SPRITEFRAME-RENDERER

    def frame(self, viewpoint) -> ClientFrame:
        """Draw one frame for ``viewpoint``; returns once its GL work has finished."""
        t0 = time.perf_counter()
        header = {"kind": "viewpoint", "seq": next(self._counter), "t": t0,
                  "viewpoint": viewpoint_to_wire(viewpoint)}
        if self._current is not None:
            last = self.shown[-1]  # the shown keyframe, for the servers' pacing
            header["shown"] = {"eye": last["viewpoint"]["o"], "slot": last["slot"]}
        msg = encode(header)
        for s in self._servers:
            try:
                s.viewpoint.send_multipart(msg, flags=zmq.NOBLOCK)
            except zmq.Again:
                pass
        newest = self.queue.drain()
        kind = "sprite"
        if newest is not None:
            self._pending = newest
        if self._pending is not None and self._should_adopt(viewpoint, self._pending[2]):
            (slot, kf, self._c_prime), self._pending = self._pending, None
            self.sprite.upload_keyframe(kf.viewpoint, kf.projection, kf.color, kf.depth, kf.t0,
                                        kf.zbuffer)
            self._current, kind = kf, "keyframe"
            self.shown.append({"slot": slot, "seq": kf.seq, "t0": kf.t0,
                               "viewpoint": kf.viewpoint.to_dict()})
        if self._current is None:
            f = self.local.frame(viewpoint)
            kind = "local_keyframe" if f.type == "keyframe" else "local_sprite"
            triangles = f.triangles
        else:
            triangles = self.sprite.render_spriteframe(viewpoint).triangles
            self.paths.ctx.finish()
        self._say_link_state()
        seq = self._current.seq if self._current is not None else 0
        return ClientFrame(kind, (time.perf_counter() - t0) * 1e3, triangles, seq,
                           len(self.shown) - 1)

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

    def _should_adopt(self, viewpoint, c_prime: np.ndarray | None) -> bool:
        """``newest`` (the paper): take every newer keyframe.  ``needed``: keep the current
        keyframe while the error metric of this viewpoint against it stays under
        ``ADOPT_FRACTION`` ε, sparing the upload.  ``better``: take the newer keyframe
        once its error here is lower than the current one's."""
        if self._current is None or self.adopt == "newest":
            return True
        projection = self.paths.renderer.projection(viewpoint)
        height = self.sprite.target.height
        err = keyframe_error_px(self.local.metric, self._c_prime, viewpoint, projection, height)
        if self.adopt == "needed":
            return err >= ADOPT_FRACTION * self.local.epsilon_px
        return keyframe_error_px(self.local.metric, c_prime, viewpoint, projection, height) < err

    def image(self):
        """The last frame's image, ``(H, W, 3) uint8``."""
        if self._current is None:
            return self.local.read_image()
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
        self._stop.set()
        self.queue.close()
        for t in self._threads:
            t.join(timeout=3.0)
        for s in self._servers:
            s.close()
        self._zmq.destroy(linger=0)  # closes any socket still open, then ends the context
        self.sprite.release()
        self.paths.release()
