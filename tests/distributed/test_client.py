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
