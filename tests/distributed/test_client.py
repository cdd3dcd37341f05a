"""The LOD client's links to servers: shutting down never hangs."""

import threading
import time

import zmq

from lodsprite.distributed.client import _Server


def test_a_closed_server_link_answers_at_once_and_opens_no_socket():
    # Regression: the control thread could open a new control socket after close() (a
    # request timing out during shutdown), and the context's term() then waited forever.
    ctx = zmq.Context()
    link = _Server(ctx, "127.0.0.1:59997")  # nothing listens there
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

    from lodsprite.distributed.client import keep_loaded
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
    link = _Server(ctx, f"127.0.0.1:{port}")
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


def test_viewpoint_messages_name_the_shown_keyframe_for_the_servers_pacing():
    """Servers pace against the keyframe the client shows, which may be another server's:
    once a keyframe is shown, every viewpoint message carries its eye."""
    import numpy as np

    from lodsprite.camera import Projection
    from lodsprite.distributed.client import LodClient
    from lodsprite.distributed.protocol import Keyframe, decode, encode_keyframe
    from lodsprite.distributed.render import scene_args
    from lodsprite.distributed.run import free_ports
    from lodsprite.run import RenderConfig, prepare

    cfg = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=8, frames=8,
                       path="chen1999", mode="sprite")
    sc, path = prepare(cfg)
    port = free_ports()
    stop = threading.Event()
    control = _fake_server(port, lambda h: {"data": {"running": True, "loaded": True}}, stop)
    ctx = zmq.Context()
    views = ctx.socket(zmq.SUB)
    views.setsockopt(zmq.SUBSCRIBE, b"")
    views.bind(f"tcp://127.0.0.1:{port + 1}")
    keys = ctx.socket(zmq.DEALER)
    keys.bind(f"tcp://127.0.0.1:{port + 2}")
    client = LodClient(sc, scene_args(cfg.terrain, cfg.texture, None, 1.0, cfg.size),
                       [f"127.0.0.1:{port}"], cfg.size, cfg.lod)

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
        vp = path.viewpoints[0]
        header = next_header(vp)
        assert "shown" not in header  # nothing shown yet: the client draws its own
        key_vp = path.viewpoints[3]
        rng = np.random.default_rng(1)
        kf = Keyframe(1, 0.0, key_vp, Projection(45.0, 1.0, 1.0, 1e5),
                      rng.integers(0, 256, (64, 64, 3), dtype=np.uint8),
                      np.full((64, 64), 0.5, np.float32))
        keys.send_multipart(encode_keyframe(kf))
        deadline = time.perf_counter() + 10.0
        while client.frame(vp).type != "keyframe":
            assert time.perf_counter() < deadline, "the keyframe never arrived"
        header = next_header(path.viewpoints[1])
        assert header["shown"] == {"eye": [float(v) for v in key_vp.o], "slot": 0}
    finally:
        client.close()
        stop.set()
        control.join(2.0)
        views.close(linger=0)
        keys.close(linger=0)
        ctx.destroy(linger=0)


def test_adopt_better_keeps_the_shown_keyframe_until_a_newer_one_serves_better():
    """A keyframe placed by a prediction that overshot must not replace a better one."""
    import numpy as np

    from lodsprite.camera import Projection
    from lodsprite.distributed.client import LodClient
    from lodsprite.distributed.protocol import Keyframe, encode_keyframe
    from lodsprite.distributed.render import scene_args
    from lodsprite.distributed.run import free_ports
    from lodsprite.run import RenderConfig, prepare

    cfg = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=8, frames=12,
                       path="chen1999", mode="sprite")
    sc, path = prepare(cfg)
    port = free_ports()
    stop = threading.Event()
    control = _fake_server(port, lambda h: {"data": {"running": True, "loaded": True}}, stop)
    ctx = zmq.Context()
    keys = ctx.socket(zmq.DEALER)
    keys.bind(f"tcp://127.0.0.1:{port + 2}")
    client = LodClient(sc, scene_args(cfg.terrain, cfg.texture, None, 1.0, cfg.size),
                       [f"127.0.0.1:{port}"], cfg.size, cfg.lod, adopt="better")
    rng = np.random.default_rng(2)

    def send(seq, vp):
        keys.send_multipart(encode_keyframe(Keyframe(
            seq, 0.0, vp, Projection(45.0, 1.0, 1.0, 1e5),
            rng.integers(0, 256, (64, 64, 3), dtype=np.uint8),
            np.full((64, 64), 0.5, np.float32))))

    def types(vp, n=15):
        out = []
        for _ in range(n):
            out.append(client.frame(vp).type)
            time.sleep(0.02)
        return out

    try:
        near, far = path.viewpoints[2], path.viewpoints[11]
        send(1, near)
        assert "keyframe" in types(near, 100)  # the first keyframe is always taken
        send(2, far)
        assert "keyframe" not in types(near)  # the far one serves worse here: kept back
        assert types(far)[0] == "keyframe"     # ... and taken once the viewer is there
        assert client.shown[-1]["seq"] == 2
    finally:
        client.close()
        stop.set()
        control.join(2.0)
        keys.close(linger=0)
        ctx.destroy(linger=0)
