"""A worker that says ``disconnect`` and closes at once: the broker's next send to it
fails (ROUTER_MANDATORY) while the ``disconnect`` is still unread.  The broker must count
that worker as leaving, not as dead.  The interleaving is forced by driving the broker's
loop steps by hand, its thread stopped before any worker joined (CI saw this race make
a cleanly stopped worker count as dead)."""

from __future__ import annotations

import time

import zmq

from lodsprite.distributed.pool import Broker
from lodsprite.distributed.pool.jobs import (
    POOL_VERSION,
    Disconnect,
    Heartbeat,
    Ready,
    encode_pool,
)

DEADLINE_S = 10.0


def test_a_disconnect_read_after_a_failed_send_counts_as_leaving() -> None:
    broker = Broker()
    broker._stop.set()  # its loop is driven below, step by step
    broker._thread.join(timeout=DEADLINE_S)
    assert not broker._thread.is_alive()
    zctx = zmq.Context()
    dealer = zctx.socket(zmq.DEALER)
    try:
        router = broker._socks[0]
        dealer.connect(broker.local_endpoint)
        dealer.send_multipart(encode_pool(Ready(POOL_VERSION, 1, "w", 2)))
        assert router.poll(DEADLINE_S * 1000)
        broker._receive(0, router)
        assert len(broker.table.peers) == 1
        dealer.send_multipart(encode_pool(Disconnect(POOL_VERSION, "worker stopping")))
        dealer.close(linger=500)  # delivered, then the connection closes
        deadline = time.monotonic() + DEADLINE_S
        while not broker.table.unreachable and broker.table.peers:  # a send fails
            assert time.monotonic() < deadline, "the send to a closed worker never failed"
            broker._broadcast(Heartbeat(POOL_VERSION))
            time.sleep(0.002)
        assert broker.table.peers, "lost on the failed send, before its disconnect was read"
        assert router.poll(0), "the disconnect is still waiting to be read"
        broker._receive(0, router)
        broker.table.lose_unreachable()
        assert not broker.table.peers
        assert broker.stats()["dead"] == 0
    finally:
        dealer.close(linger=0)
        zctx.term()
        broker.close()
