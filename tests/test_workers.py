"""The one process mechanism beside the frame loop (issue 31, must-have 6): a worker
process driven without waiting from the frame's thread, its lifecycle and its errors."""

from __future__ import annotations

import os
import signal
import textwrap
import time

import pytest

from lodsprite.workers import (
    HandlerError,
    ProcessWorker,
    WorkerDied,
    WorkerUnavailable,
)

HANDLER = textwrap.dedent('''
    import os
    import time

    import numpy as np

    def make(scale):
        def handle(meta, data):
            if meta == b"raise":
                raise ValueError("a bad request")
            if meta == b"die":
                os._exit(3)
            if meta == b"sleep":
                time.sleep(60)
            if meta == b"tile":  # a tile's samples made from the request's seed
                rng = np.random.default_rng(int.from_bytes(data, "little"))
                return meta, rng.random((65, 65), dtype=np.float32).tobytes()
            return meta, data * scale
        return handle


    def refuse(what):
        from lodsprite.errors import InputError
        raise InputError(f"no such thing: {what}")


    def vanish():
        os._exit(3)
''')


@pytest.fixture
def factory(tmp_path, monkeypatch):
    (tmp_path / "echo_worker.py").write_text(HANDLER)
    monkeypatch.syspath_prepend(str(tmp_path))  # a spawned child gets this sys.path
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
        err = got[1][1]
        assert isinstance(err, HandlerError) and "a bad request" in err.text
        assert isinstance(err.cause, ValueError)  # the handler's own exception, typed
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
        assert isinstance(got["victim"], WorkerDied) and "died" in got["victim"].text
        assert got["next"] == (b"next", b"") and got["last"] == (b"last", b"")
        assert w.alive and w.pid != pid and w.deaths == 1
        w.submit("boom", b"die")                        # the second death: no restart left
        got = collect(w, 1)
        assert isinstance(got[0][1], WorkerDied) and not w.alive
        w.submit("after", b"x")                         # every later request fails at once
        assert isinstance(w.poll()[0][1], WorkerUnavailable)
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


def test_a_worker_killed_mid_request_is_noticed_and_its_request_fails_typed(factory):
    w = ProcessWorker(factory, {"scale": 1}, in_flight=2, restarts=0)
    try:
        assert w.wait_ready(20.0)
        w.submit("slow", b"sleep")
        os.kill(w.pid, signal.SIGKILL)            # mid-request: the handler is asleep
        got = collect(w, 1)
        assert got and got[0][0] == "slow" and isinstance(got[0][1], WorkerDied)
        assert not w.alive and w.deaths == 1
    finally:
        w.close()


def _shm_names() -> set[str]:
    return set(os.listdir("/dev/shm"))


def test_close_leaves_no_process_and_no_shared_memory(factory):
    w = ProcessWorker(factory, {"scale": 1}, in_flight=2, slot_bytes=4096)
    name, pid = w.shm.name.lstrip("/"), w.pid
    assert name in _shm_names()                   # the slots this object owns
    w.submit("a", b"sleep")                       # busy: the stop must terminate it
    w.close()
    w.close()                                     # idempotent
    assert name not in _shm_names()
    with pytest.raises(ProcessLookupError):       # reaped: not even a zombie is left
        os.kill(pid, 0)
    w.submit("late", b"x")
    assert isinstance(w.poll()[0][1], WorkerUnavailable)


def test_tile_payloads_arrive_intact_through_slots_and_pipe(factory):
    import numpy as np

    tile = 65 * 65 * 4
    for slot_bytes in (tile, 0):                  # in the shared slots, then in the pipe
        w = ProcessWorker(factory, {"scale": 1}, in_flight=3, slot_bytes=slot_bytes)
        try:
            held, n = {}, 0
            while n < 12 or w.pending:
                if n < 12 and w.submit(n, b"tile", n.to_bytes(4, "little")):
                    n += 1
                for key, (_, data) in w.poll():
                    held[key] = data
            for key, data in held.items():        # held answers are not the reused slots
                want = np.random.default_rng(key).random((65, 65), dtype=np.float32)
                assert data == want.tobytes()
        finally:
            w.close()


def test_a_factory_that_fails_fails_every_request_with_its_reason():
    w = ProcessWorker("lodsprite.terrain.reader:tile_reader", {"path": "/nonexistent"},
                      restarts=3)
    try:
        assert not w.wait_ready(20.0)
        w.submit("a", b"x")
        got = w.poll()
        assert isinstance(got[0][1], WorkerUnavailable) and "nonexistent" in got[0][1].text
        assert w.deaths == 0 and not w.alive      # not started again and again
    finally:
        w.close()


def test_the_answer_pipe_can_be_watched_by_a_selector(factory):
    import selectors

    w = ProcessWorker(factory, {"scale": 1})
    sel = selectors.DefaultSelector()
    try:
        sel.register(w, selectors.EVENT_READ)
        w.submit("a", b"m", b"d")
        got, deadline = [], time.monotonic() + 20.0
        while not got and time.monotonic() < deadline:
            if sel.select(timeout=1.0):
                got += w.poll()
        assert got == [("a", (b"m", b"d"))]
    finally:
        sel.close()
        w.close()


def test_a_call_in_a_fresh_process_returns_its_value_or_its_typed_error(factory):
    import importlib

    from lodsprite.errors import InputError
    from lodsprite.procs import WorkerDied, call_in_child

    mod = importlib.import_module("echo_worker")
    assert call_in_child(os.getpid) != os.getpid()        # another process, its answer
    with pytest.raises(InputError, match="no such thing: x"):  # the child's own type
        call_in_child(mod.refuse, "x")
    with pytest.raises(WorkerDied, match="exit code 3"):   # died without an answer
        call_in_child(mod.vanish)


def test_answers_are_read_in_the_wire_format_connections_write():
    """read_messages parses multiprocessing.connection's own framing: small and large
    messages, one cut in the middle (kept until its end comes), and the pipe's end."""
    import multiprocessing as mp

    from lodsprite.workers import read_messages

    r, w = mp.Pipe(duplex=False)
    os.set_blocking(r.fileno(), False)
    buf = bytearray()
    big = bytes(range(256)) * 100                 # over 16 KiB: header and body apart
    w.send_bytes(b"one")
    w.send_bytes(big)
    assert read_messages(r.fileno(), buf) == ([b"one", big], False) and not buf
    w.send_bytes(b"")
    os.write(w.fileno(), (5).to_bytes(4, "big") + b"ab")  # a message cut short
    assert read_messages(r.fileno(), buf) == ([b""], False) and len(buf) == 6
    os.write(w.fileno(), b"cde")
    w.close()
    assert read_messages(r.fileno(), buf) == ([b"abcde"], True) and not buf
    r.close()
