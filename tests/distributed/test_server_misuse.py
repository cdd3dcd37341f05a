"""What a peer must not do to a LOD server: make it keep a message of many frames, stop it
with ``shutdown``, stop one of its threads, or slip a previous holder's sample past a new
holder's reset."""

import threading
import time

import pytest
import zmq

from lodsprite.camera import look_at
from lodsprite.distributed.hold import Hold
from lodsprite.distributed.protocol import decode, encode
from lodsprite.distributed.queue import KeyframeQueue
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.server import LodServer, endpoints
from lodsprite.distributed.server_stats import ServerStats, Tally
from lodsprite.distributed.transmitter import KeyframeTransmitter
from lodsprite.distributed.viewpoints import ViewpointReceiver

A, B = "a" * 16, "b" * 16
SMALL = {"terrain": "fractal:64:1", "size": [64, 64], "lod": 8}
VP = look_at((0.0, -500.0, 300.0), (0.0, 0.0, 0.0))


def control(server, op, args=None, client=A) -> dict:
    return server._control(encode({"kind": "control", "seq": 1, "op": op,
                                   "args": args or {}, "client": client}))


def _until(condition, what, timeout=20.0):
    """Wait for ``condition()``; the deadline only guards against a hang."""
    deadline = time.perf_counter() + timeout
    while not condition():
        assert time.perf_counter() < deadline, f"{what} never happened"
        time.sleep(0.01)


# -------------------------------------------------------------- many frames, one message

@pytest.fixture
def spied():
    """A live server whose three handlers record how many frames each message they were
    handed had; yields (server, endpoints, {handler: [frame counts]})."""
    address = f"127.0.0.1:{free_ports()}"
    server = LodServer(bind=address)
    seen = {"control": [], "viewpoint": [], "ack": []}

    def spy(name, handler):
        def wrapped(frames, *args):
            seen[name].append(len(frames))
            return handler(frames, *args)
        return wrapped

    server._control = spy("control", server._control)
    server._viewpoints.take = spy("viewpoint", server._viewpoints.take)
    server._transmitter.ack = spy("ack", server._transmitter.ack)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    ctx = zmq.Context()
    yield server, endpoints(address, bind=False), seen, ctx
    ctx.destroy(linger=0)
    server.shutdown()
    thread.join(15)


def _ask(req, op) -> dict:
    req.send_multipart(encode({"kind": "control", "seq": 1, "op": op, "args": {}}))
    return decode(req.recv_multipart())[0]


def test_a_message_of_many_frames_is_rejected_without_keeping_its_frames(spied):
    """Regression: ``zmq.MAXMSGSIZE`` bounds each frame, not their number, and each loop
    took a whole message (``recv_multipart``, copied): 40,000 small frames made the server
    hold hundreds of MiB.  Now each handler gets at most the frames its kind has."""
    server, (ctl_ep, vp_ep, kf_ep), seen, ctx = spied
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.RCVTIMEO, 20000)
    req.connect(ctl_ep)
    many = [b"\x00" * 8] * 999
    req.send_multipart([encode({"kind": "control", "seq": 1, "op": "ping"})[0], *many])
    reply, _ = decode(req.recv_multipart())
    assert reply["ok"] is False and "1000 frames" in reply["error"]
    assert _ask(req, "ping")["ok"] is True  # one reply each, and the server goes on

    pub = ctx.socket(zmq.PUB)
    pub.connect(vp_ep)
    dealer = ctx.socket(zmq.DEALER)
    dealer.connect(kf_ep)
    vp_head = encode({"kind": "viewpoint", "seq": 1, "t": 1.0, "viewpoint": VP.to_dict()})[0]

    def flood_viewpoints():  # PUB drops messages until the subscription has arrived
        pub.send_multipart([vp_head, *many])
        return server.stats.rejected["viewpoint"] > 0

    _until(flood_viewpoints, "a rejected viewpoint message")
    dealer.send_multipart([encode({"kind": "ack", "seq": 1, "t": 0.0})[0], *many])
    _until(lambda: server.stats.rejected["ack"] > 0, "a rejected acknowledgement")
    assert max(seen["control"]) == 1 and max(seen["viewpoint"]) == 1
    assert max(seen["ack"]) == 2  # the sender's identity and the header
    assert server.stats.rejected["control"] == 1
    assert server.stats.rejected["ack"] == 1
    assert _ask(req, "ping")["ok"] is True


# ---------------------------------------------------------------------------- shutdown

@pytest.fixture
def server():
    s = LodServer(bind=f"127.0.0.1:{free_ports()}")
    yield s
    s._ctx.term()


def test_shutdown_is_refused_from_anyone_unless_allowed(server):
    """Regression: any peer could stop an idle server: take the hold with ``load``, then
    ``shutdown``."""
    reply = control(server, "shutdown", client=B)  # nobody holds it
    assert reply["ok"] is False and "--allow-shutdown" in reply["error"]
    assert control(server, "load", SMALL, A)["ok"]
    for client in (A, B, ""):
        assert control(server, "shutdown", client=client)["ok"] is False
    assert not server._stop.is_set()
    assert control(server, "ping", client=B)["ok"] is True
    assert server.stats.refused["shutdown"] == 4


def test_an_allowed_shutdown_is_carried_out_for_the_holder_only():
    s = LodServer(bind=f"127.0.0.1:{free_ports()}", allow_shutdown=True)
    try:
        assert control(s, "shutdown", client=B)["ok"] is False  # nobody holds it
        assert control(s, "load", SMALL, A)["ok"]
        reply = control(s, "shutdown", client=B)
        assert reply["ok"] is False and "held by another client" in reply["error"]
        assert not s._stop.is_set()
        assert control(s, "shutdown", client=A)["ok"] is True
        assert s._stop.is_set()
    finally:
        s._ctx.term()


# -------------------------------------------------------- the threads' loops go on

class _FailingOnce:
    """A socket whose first ``poll`` raises (an unexpected error); later polls find
    nothing."""

    def __init__(self):
        self.polls = 0

    def poll(self, timeout=0):
        self.polls += 1
        if self.polls == 1:
            raise RuntimeError("injected")
        time.sleep(0.002)
        return 0

    def close(self, linger=None):
        pass


@pytest.mark.parametrize("which", ["viewpoints", "transmitter"])
def test_an_unexpected_error_does_not_stop_the_receiver_or_transmitter_thread(which):
    """Regression: their loops had no catch-all: one unexpected exception ended the
    thread, and the server answered ping but received no viewpoints (sent no keyframes)."""
    tally, stop = Tally(ServerStats()), threading.Event()
    if which == "viewpoints":
        module = ViewpointReceiver("linear", Hold(), tally, stop)
    else:
        module = KeyframeTransmitter(KeyframeQueue(2), Hold(), tally, "raw", stop)
    sock = _FailingOnce()
    thread = threading.Thread(target=module.run, args=(sock,), daemon=True)
    thread.start()
    try:
        _until(lambda: sock.polls >= 5, "the loop going on after the error", timeout=10.0)
        assert thread.is_alive()
        assert any(key.startswith("internal:") and key.endswith("RuntimeError")
                   for key in tally.said)  # said once
    finally:
        stop.set()
        thread.join(5)
    assert not thread.is_alive()


# ------------------------------------------------- a stale sample after a new holder's load

def test_a_sample_of_the_previous_holder_is_not_kept_after_a_new_holders_reset(server):
    """Regression: the holder was checked before the receiver's lock was taken, so a
    sample of A in flight while B's ``load`` reset the receiver set the newest sample
    time, and B's samples older than it were then ignored."""
    assert control(server, "load", SMALL, A)["ok"]
    views = server._viewpoints
    frames = encode({"kind": "viewpoint", "seq": 1, "t": 1e6, "viewpoint": VP.to_dict(),
                     "client": A})
    # A's sample has passed the hold check (A still holds); B's load resets the receiver.
    views.reset(B)
    assert views.take(frames) is False
    assert views._last_t is None and not views.have.is_set()
    assert server.stats.ignored == {"viewpoint_not_holder": 1}


def test_the_web_pages_path_op_is_refused_by_the_zeromq_server(server):
    reply = control(server, "path", {"spec": "chen1999", "frames": 5})
    assert reply["ok"] is False and "web page" in reply["error"]
    assert server.stats.refused["path"] == 1
