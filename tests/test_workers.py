"""The shared mechanism for work beside the draws: a worker process driven without
waiting from the frame's thread (issue 21, must-have 7)."""

from __future__ import annotations

import os
import signal
import textwrap
import time

import pytest

from lodsprite.workers import Failure, ProcessWorker

HANDLER = textwrap.dedent('''
    import os

    def make(scale):
        def handle(meta, data):
            if meta == b"raise":
                raise ValueError("a bad request")
            if meta == b"die":
                os._exit(3)
            return meta, data * scale
        return handle
''')


@pytest.fixture
def factory(tmp_path, monkeypatch):
    (tmp_path / "echo_worker.py").write_text(HANDLER)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    return "echo_worker:make"


def collect(worker: ProcessWorker, n: int, seconds: float = 20.0) -> list:
    out, deadline = [], time.monotonic() + seconds
    while len(out) < n and time.monotonic() < deadline:
        out += worker.poll()
        time.sleep(0.002)
    return out


def test_answers_come_in_order_and_a_failing_request_does_not_stop_the_process(factory):
    w = ProcessWorker(factory, {"scale": 2}, in_flight=3)
    try:
        assert w.submit("a", b"x", b"ab") and w.submit("b", b"raise") and w.submit("c", b"y")
        assert w.full and not w.submit("d", b"z")        # bounded: the caller keeps it
        got = collect(w, 3)
        assert [k for k, _ in got] == ["a", "b", "c"] and not w.pending
        assert got[0][1] == (b"x", b"abab") and got[2][1] == (b"y", b"")
        assert isinstance(got[1][1], Failure) and "a bad request" in got[1][1].text
        assert w.deaths == 0 and w.alive
    finally:
        w.close()


def test_a_dead_process_is_restarted_its_request_fails_and_the_rest_are_sent_again(factory):
    w = ProcessWorker(factory, {"scale": 1}, in_flight=4, restarts=1)
    try:
        pid = w.pid
        os.kill(pid, signal.SIGSTOP)                    # it answers nothing ...
        for key in ("victim", "next", "last"):
            w.submit(key, key.encode())
        os.kill(pid, signal.SIGKILL)                    # ... and dies with all three sent
        got = dict(collect(w, 3))
        assert isinstance(got["victim"], Failure) and "died" in got["victim"].text
        assert got["next"] == (b"next", b"") and got["last"] == (b"last", b"")
        assert w.alive and w.pid != pid and w.deaths == 1
        w.submit("boom", b"die")                        # the second death: no restart left
        got = collect(w, 1)
        assert isinstance(got[0][1], Failure) and not w.alive
        w.submit("after", b"x")                         # every later request fails at once
        assert isinstance(w.poll()[0][1], Failure)
    finally:
        w.close()


def test_close_ends_the_process(factory):
    w = ProcessWorker(factory, {"scale": 1})
    pid = w.pid
    w.close()
    assert not w.alive
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_requests_are_small():
    w = ProcessWorker("lodsprite.terrain.reader:tile_reader", {"path": "/nonexistent"})
    try:
        with pytest.raises(ValueError):
            w.submit(0, b"x" * 2000)
    finally:
        w.close()


def test_answers_come_back_through_shared_slots_when_they_fit(factory):
    w = ProcessWorker(factory, {"scale": 1000}, in_flight=2, slot_bytes=1500)
    try:
        for n in range(6):  # the slots are reused as answers are collected
            w.submit(n, b"m", bytes([n]))
            while w.full:
                for key, (meta, data) in collect(w, 1):
                    assert meta == b"m" and data == bytes([key]) * 1000
        w.submit("big", b"m", b"ab")  # 2000 bytes: too big for a slot, through the pipe
        rest = collect(w, len(w.pending))
        assert rest[-1] == ("big", (b"m", b"ab" * 1000))
    finally:
        w.close()
