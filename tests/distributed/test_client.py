"""The LOD client's links to servers: shutting down never hangs."""

import threading
import time

import numpy as np
import pytest
import zmq

from lodsprite.distributed.link import ServerLink


def test_a_closed_server_link_answers_at_once_and_opens_no_socket():
    # Regression: the control thread could open a new control socket after close() (a
    # request timing out during shutdown), and the context's term() then waited forever.
    ctx = zmq.Context()
    link = ServerLink(ctx, "127.0.0.1:59997")  # nothing listens there
    link.close()
    t0 = time.perf_counter()
    assert link.request({"kind": "control", "seq": 1, "op": "ping", "args": {}}) is None
    assert time.perf_counter() - t0 < 0.5
    assert link.control is None
    ender = threading.Thread(target=ctx.term, daemon=True)
    ender.start()
    ender.join(5.0)
    assert not ender.is_alive()


def _fake_server(port: int, answer, stop: threading.Event) -> threading.Thread:
    """A control socket answering with ``answer(header) -> reply or None (no answer)``."""
    from lodsprite.distributed.protocol import decode, encode

    ctx = zmq.Context.instance()

    def serve():
        sock = ctx.socket(zmq.REP)
        sock.bind(f"tcp://127.0.0.1:{port}")
        try:
            while not stop.is_set():
                if not sock.poll(20):
                    continue
                header, _ = decode(sock.recv_multipart())
                reply = answer(header)
                if reply is None:  # drop it: the REP socket must be made afresh
                    sock.close(linger=0)
                    sock = ctx.socket(zmq.REP)
                    sock.bind(f"tcp://127.0.0.1:{port}")
                    continue
                sock.send_multipart(encode({"kind": "reply", "seq": header["seq"], "ok": True,
                                            "error": "", **reply}))
        finally:
            sock.close(linger=0)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    return t


def test_a_load_that_got_no_answer_is_sent_again():
    # Regression: the client marked a server loaded even when its load request timed out
    # (a server busy starting up), and never loaded it again: no keyframes, ever.
    import itertools

    from lodsprite.distributed.link import keep_loaded
    from lodsprite.distributed.run import free_ports

    port = free_ports()
    state = {"loads": 0, "loaded": False, "running": False}

    def answer(header):
        op = header["op"]
        if op == "load":
            state["loads"] += 1
            if state["loads"] == 1:
                return None  # lost
            state["loaded"] = True
        if op == "start":
            state["running"] = True
        return {"data": {"running": state["running"], "loaded": state["loaded"]}}

    stop = threading.Event()
    server = _fake_server(port, answer, stop)
    ctx = zmq.Context()
    link = ServerLink(ctx, f"127.0.0.1:{port}")
    counter = itertools.count(1)
    try:
        keep_loaded(link, {"terrain": "x"}, counter)
        assert link.alive and not link.loaded and state["loads"] == 1
        keep_loaded(link, {"terrain": "x"}, counter)
        assert link.loaded and state["loads"] == 2 and state["running"]
        keep_loaded(link, {"terrain": "x"}, counter)
        assert state["loads"] == 2  # loaded and running: nothing more to send
    finally:
        stop.set()
        server.join(2.0)
        link.close()
        ctx.destroy(linger=0)


class _FakeLodServer:
    """A server's three sockets played by the test: control answers "loaded and
    running", viewpoints are read, keyframes are sent by hand."""

    def __init__(self):
        from lodsprite.distributed.run import free_ports
        from lodsprite.run import RenderConfig, prepare

        self.cfg = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=8, frames=12,
                                path="chen1999", mode="sprite")
        self.scene, self.path = prepare(self.cfg)
        self.port = free_ports()
        self.stop = threading.Event()
        self.control = _fake_server(
            self.port, lambda h: {"data": {"running": True, "loaded": True}}, self.stop)
        self.ctx = zmq.Context()
        self.views = self.ctx.socket(zmq.SUB)
        self.views.setsockopt(zmq.SUBSCRIBE, b"")
        self.views.bind(f"tcp://127.0.0.1:{self.port + 1}")
        self.keys = self.ctx.socket(zmq.DEALER)
        self.keys.bind(f"tcp://127.0.0.1:{self.port + 2}")
        self.rng = np.random.default_rng(1)

    def client(self, **kw):
        from lodsprite.distributed.client import LodClient
        from lodsprite.distributed.render import scene_args

        c = self.cfg
        return LodClient(self.scene, scene_args(c.terrain, c.texture, None, 1.0, c.size),
                         [f"127.0.0.1:{self.port}"], c.size, c.lod, **kw)

    def send(self, seq, vp):
        from lodsprite.camera import Projection
        from lodsprite.distributed.protocol import Keyframe, encode_keyframe

        self.keys.send_multipart(encode_keyframe(Keyframe(
            seq, 0.0, vp, Projection(45.0, 1.0, 1.0, 1e5),
            self.rng.integers(0, 256, (64, 64, 3), dtype=np.uint8),
            np.full((64, 64), 0.5, np.float32))))

    def close(self):
        self.stop.set()
        self.control.join(2.0)
        self.views.close(linger=0)
        self.keys.close(linger=0)
        self.ctx.destroy(linger=0)


@pytest.fixture
def fake():
    f = _FakeLodServer()
    yield f
    f.close()


def test_viewpoint_messages_name_the_shown_keyframe_for_the_servers_pacing(fake):
    """Servers pace against the keyframe the client shows, which may be another server's:
    once a keyframe is shown, every viewpoint message carries its eye."""
    from lodsprite.distributed.protocol import decode

    client = fake.client()
    views = fake.views

    def next_header(vp) -> dict:
        """The newest viewpoint message after drawing ``vp`` (PUB drops messages until
        the subscription has joined, so draw until one comes)."""
        while views.poll(0):
            views.recv_multipart()
        for _ in range(100):
            client.frame(vp)
            if views.poll(100):
                while views.poll(0):
                    header, _ = decode(views.recv_multipart())
                return header
        raise AssertionError("no viewpoint message reached the server")

    try:
        vp = fake.path.viewpoints[0]
        header = next_header(vp)
        assert "shown" not in header  # nothing shown yet: the client draws its own
        key_vp = fake.path.viewpoints[3]
        fake.send(1, key_vp)
        deadline = time.perf_counter() + 10.0
        while client.frame(vp).type != "keyframe":
            assert time.perf_counter() < deadline, "the keyframe never arrived"
        header = next_header(fake.path.viewpoints[1])
        assert header["shown"] == {"eye": [float(v) for v in key_vp.o], "slot": 0}
    finally:
        client.close()


def test_adopt_better_keeps_the_shown_keyframe_until_a_newer_one_serves_better(fake):
    """A keyframe placed by a prediction that overshot must not replace a better one."""
    client = fake.client(adopt="better")

    def types(vp, n=15):
        out = []
        for _ in range(n):
            out.append(client.frame(vp).type)
            time.sleep(0.02)
        return out

    try:
        near, far = fake.path.viewpoints[2], fake.path.viewpoints[11]
        fake.send(1, near)
        assert "keyframe" in types(near, 100)  # the first keyframe is always taken
        fake.send(2, far)
        deadline = time.perf_counter() + 10.0
        while client._pending is None:  # until the far keyframe has been received
            assert client.frame(near).type == "sprite"
            assert time.perf_counter() < deadline, "the second keyframe never arrived"
        assert "keyframe" not in types(near)  # the far one serves worse here: kept back
        assert types(far)[0] == "keyframe"     # ... and taken once the viewer is there
        assert client.shown[-1]["seq"] == 2
    finally:
        client.close()
