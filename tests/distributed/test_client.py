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
