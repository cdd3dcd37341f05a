import threading
import time

import pytest

from lodsprite.distributed.queue import Closed, KeyframeQueue


def test_capacity_blocks_the_producer_until_a_consumer_takes_one():
    q = KeyframeQueue(2)
    assert q.put(1) and q.put(2)
    assert q.put(3, timeout=0.05) is False  # full
    got = []
    consumer = threading.Thread(target=lambda: (time.sleep(0.05), got.append(q.get())))
    consumer.start()
    assert q.put(3, timeout=2.0)
    consumer.join()
    assert got == [1] and len(q) == 2


def test_drain_returns_the_newest_and_drops_older_ones():
    q = KeyframeQueue(2)
    assert q.drain() is None
    q.put("old")
    q.put("new")
    assert q.drain() == "new"
    assert len(q) == 0


def test_get_times_out_and_close_wakes_waiters():
    q = KeyframeQueue(2)
    assert q.get(timeout=0.01) is None
    errors = []

    def wait():
        try:
            q.get()
        except Closed:
            errors.append("closed")

    th = threading.Thread(target=wait)
    th.start()
    time.sleep(0.05)
    q.close()
    th.join(timeout=2.0)
    assert errors == ["closed"]
    with pytest.raises(Closed):
        q.put(1)
