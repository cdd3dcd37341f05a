"""Served paths that a long render cannot stall.

A 4096² terrain seen whole is about 33 M triangles a keyframe; on llvmpipe the draw call
shades them on the calling thread for seconds.  Drawn through moderngl, which holds the
GIL meanwhile, it stopped every other thread of the process: the LOD server's control
thread (pings unanswered past the client's
:data:`~lodsprite.distributed.link.CONTROL_TIMEOUT_MS`).  The LOD server's ping test
renders a 2048² keyframe (an end-to-end check: its draw through moderngl stalled the
control thread about 0.66 s on an idle 2-core machine, under the 1 s control timeout, so
that test passed before the fix there too); the test that fails before the fix, at
2048², times the longest stall of a thread beside a keyframe render against the render's
own time (0.655 of 0.66 s before the fix).  Each renders on as small an image as the
protocol allows (the cost is the vertices, not the pixels)."""

from __future__ import annotations

import threading
import time

import zmq

from lodsprite.camera import look_at
from lodsprite.distributed.link import CONTROL_TIMEOUT_MS
from lodsprite.distributed.protocol import (
    LoadArgs,
    decode,
    decode_keyframe,
    encode,
)
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.server import LodServer, endpoints

SIZE = (32, 32)
SERVED = LoadArgs(terrain="fractal:2048:1", size=SIZE, lod=16, pace="continuous")
WHOLE = look_at((0.0, -1.0, 200000.0), (0.0, 0.0, 0.0))
"""High above a fractal:4096 (122880 m a side; a 2048² one is half that): every chunk in
view, all 33 M triangles (8.4 M)."""
CLIENT = "c" * 16
GENEROUS_S = 240.0
"""Deadline against a hang only: a 4096² load and keyframe on a busy 2-core machine."""


def _ask(req: zmq.Socket, seq: int, op: str, args: dict | None = None) -> dict | None:
    """One control request; its reply, or None when none came within the client's
    control timeout (what a client waits before it counts the server gone)."""
    req.send_multipart(encode({"kind": "control", "seq": seq, "op": op, "args": args or {},
                               "client": CLIENT}))
    if not req.poll(CONTROL_TIMEOUT_MS):
        return None
    return decode(req.recv_multipart())[0]


def test_the_lod_server_answers_pings_while_it_renders_a_2048_keyframe() -> None:
    """Regression: the producer thread drew with the GIL held; the control thread could
    not answer a ping until the keyframe was done (seconds)."""
    address = f"127.0.0.1:{free_ports()}"
    server = LodServer(bind=address)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    ctx = zmq.Context()
    ctl, views, keyframes = endpoints(address, bind=False)
    req, pub, dealer = ctx.socket(zmq.REQ), ctx.socket(zmq.PUB), ctx.socket(zmq.DEALER)
    dealer.setsockopt(zmq.IDENTITY, CLIENT.encode())
    for sock, ep in ((req, ctl), (pub, views), (dealer, keyframes)):
        sock.connect(ep)
    try:
        load = {"terrain": SERVED.terrain, "size": list(SIZE), "lod": SERVED.lod,
                "pace": "continuous"}
        assert _ask(req, 1, "load", load)["ok"]
        seq, answered, deadline = 1, 0, time.monotonic() + GENEROUS_S
        started = False
        while not dealer.poll(0):  # until the keyframe arrives: through load and render
            assert time.monotonic() < deadline, "no keyframe"
            seq += 1
            reply = _ask(req, seq, "ping")
            assert reply is not None, f"ping {seq} unanswered within {CONTROL_TIMEOUT_MS} ms"
            answered += 1
            if not started and reply["data"]["state"] == "ready":
                seq += 1
                assert _ask(req, seq, "start")["ok"]
                started = True
            time.sleep(0.02)  # a client's pace, not a busy loop contending for the GIL
            if started:
                pub.send_multipart(encode({"kind": "viewpoint", "seq": seq, "t": seq * 0.01,
                                           "viewpoint": WHOLE.to_dict(), "client": CLIENT}))
        kf = decode_keyframe(dealer.recv_multipart(copy=False))
        assert kf.color.shape == (SIZE[1], SIZE[0], 3)
        assert started and answered > 1
    finally:
        server.shutdown()
        thread.join(15)
        ctx.destroy(linger=0)


def _longest_stall(render) -> tuple[float, float]:
    """``render()`` on this thread while another ticks every 5 ms: (the longest gap
    between its ticks, the render's own time), seconds.  A draw that holds the GIL stops
    the ticker for all of it."""
    gaps: list[float] = []
    stop = threading.Event()

    def tick() -> None:
        last = time.perf_counter()
        while not stop.is_set():
            time.sleep(0.005)
            now = time.perf_counter()
            gaps.append(now - last)
            last = now

    ticker = threading.Thread(target=tick)
    ticker.start()
    t0 = time.perf_counter()
    render()
    took = time.perf_counter() - t0
    stop.set()
    ticker.join()
    return max(gaps, default=0.0), took


def test_a_keyframe_render_lets_the_other_threads_of_its_process_run() -> None:
    """Regression: the LOD server's producer (and the pool's renders) drew through
    moderngl holding the GIL, so the control thread stalled for the whole draw; drawn
    unlocked, a thread beside it keeps ticking.  The bound is relative to the draw's own
    time (a fast GPU's draw is short and stalls nothing either way)."""
    from lodsprite.distributed.render import KeyframeService

    r = KeyframeService(SERVED)
    try:
        r.render(WHOLE, 0, 0.0)  # loaded, compiled: the next render is the draw alone
        stall, took = _longest_stall(lambda: r.render(WHOLE, 0, 0.0))
    finally:
        r.release()
    assert stall < max(0.25, took / 2), (stall, took)
