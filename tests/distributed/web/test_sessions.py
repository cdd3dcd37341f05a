"""A web session's edge without a server: the wire's caps, the message handler under
random and hostile bytes (hypothesis), the rate cap, the drop-oldest keyframe queue and
the hub's round robin."""

import asyncio
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostile import hostile_frames, valid_header
from lodsprite.distributed.pool import Result
from lodsprite.distributed.protocol import LoadArgs, ProtocolError, decode_message, encode
from lodsprite.distributed.web.hub import Hub
from lodsprite.distributed.web.sessions import MAX_REPLIES, Caps, Pending, Session
from lodsprite.distributed.web.wire import MAX_PAGE_MESSAGE, MAX_PARTS, pack, unpack

VP = {"x": [1.0, 0.0, 0.0], "y": [0.0, 1.0, 0.0], "z": [0.0, 0.0, 1.0], "o": [0.0, 0.0, 500.0]}


class FakeHub:
    """Records what a session asks of the hub."""

    def __init__(self):
        self.loads, self.schedules, self.forgotten = [], 0, []

    def load(self, session, args, seq):
        self.loads.append((args, seq))

    def forget(self, named):
        self.forgotten.append(named)

    def schedule(self):
        self.schedules += 1

    def workers_count(self):
        return 1

    def summary(self):
        return {}


def replies(session: Session) -> list:
    return [decode_message(unpack(d, 2**30))[0] for d in session._replies
            if not isinstance(d, list)]  # a list: a queued scene's parts


def test_wire_round_trip_and_caps():
    parts = [b"head", b"", b"x" * 10]
    assert [bytes(p) for p in unpack(pack(parts))] == parts
    for bad in (b"", b"\x01\x00", struct.pack("<I", 0), struct.pack("<I", MAX_PARTS + 1),
                struct.pack("<II", 1, 10) + b"short", struct.pack("<II", 1, 2) + b"long!",
                struct.pack("<I", 2**31)):
        with pytest.raises(ProtocolError):
            unpack(bad)
    with pytest.raises(ProtocolError):
        unpack(b"\x00" * (MAX_PAGE_MESSAGE + 1))
    with pytest.raises(ProtocolError):
        pack([b""] * (MAX_PARTS + 1))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=3000) | st.builds(lambda b: struct.pack("<I", 1) + b,
                                            st.binary(max_size=300)))
def test_the_handler_never_raises_on_random_bytes(data):
    s = Session(FakeHub(), Caps(rate=1e9))
    s.handle(data)
    assert s.counts["internal"] == 0
    assert s.counts["rejected"] + s.counts["viewpoints"] + s.counts["acks"] \
        + s.counts["requests"] + len(s.hub.loads) + len(s._replies) >= 1


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_handler_never_raises_on_hostile_messages(seed):
    rng = np.random.default_rng(seed)
    s = Session(FakeHub(), Caps(rate=1e9))
    s.load = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=8)
    frames = hostile_frames("web", rng)
    s.handle(pack(frames) if len(frames) <= MAX_PARTS else b"".join(frames))
    assert s.counts["internal"] == 0 and s.counts["received"] == 1
    assert len(s.pending) <= s.caps.session_jobs


def test_a_valid_request_waits_and_a_request_before_load_is_refused():
    rng = np.random.default_rng(1)
    s = Session(FakeHub(), Caps(session_jobs=1, rate=1e9))
    s.handle(pack(encode(valid_header("request", rng))))
    assert replies(s)[-1].ok is False and "load" in replies(s)[-1].error
    s.load = LoadArgs()
    for seq in (1, 2):
        s.handle(pack(encode({"kind": "request", "seq": seq, "t": 0.5, "viewpoint": VP})))
    assert [p.seq for p in s.pending] == [2] and s.counts["superseded"] == 1  # newest kept
    s.handle(pack(encode({"kind": "control", "seq": 9, "op": "load",
                          "args": {"terrain": "fractal:64:1"}})))
    assert s.hub.loads[-1][0].terrain == "fractal:64:1" and s.hub.loads[-1][1] == 9


def test_the_rate_cap_drops_and_counts_the_excess():
    now = [0.0]
    s = Session(FakeHub(), Caps(rate=10.0), clock=lambda: now[0])
    ping = pack(encode({"kind": "control", "seq": 1, "op": "ping"}))
    for _ in range(25):
        s.handle(ping)
    assert s.counts["rate_dropped"] == 15 and len(s._replies) == 10
    now[0] = 1.0  # a second later the bucket is full again
    s.handle(ping)
    assert s.counts["rate_dropped"] == 15


def test_full_queues_drop_the_oldest():
    s = Session(FakeHub(), Caps(queue=2))
    for i in range(5):
        s.push_keyframe([b"%d" % i], Pending(i, 0.0, None, 0.0))
    assert s.counts["keyframes_dropped"] == 3
    assert [bytes(parts[0]) for parts, _ in s._keyframes] == [b"3", b"4"]
    for i in range(MAX_REPLIES + 3):
        s.reply(i, True)
    assert s.counts["replies_dropped"] == 3 and replies(s)[0].seq == 3


class FakePool:
    def __init__(self, workers=1):
        self.n, self.submitted, self.results = workers, [], []

    def workers(self):
        return ["w"] * self.n

    def submit(self, job):
        self.submitted.append(job)

    def poll(self):
        out, self.results = self.results, []
        return out


def scheduled(pool) -> tuple[Hub, Session]:
    """A hub over ``pool`` and a loaded session whose one request was scheduled (call
    inside a running loop)."""
    hub = Hub(pool, datasets=None)
    s = hub.open_session("a")
    s.load = s.named = LoadArgs()
    s.pending.append(Pending(5, 0.0, VP, 0.0))
    hub.schedule()
    return hub, s


def test_round_robin_serves_a_greedy_session_no_more_than_a_modest_one():
    async def run():
        pool = FakePool(1)
        hub = Hub(pool, datasets=None, caps=Caps(session_jobs=1))
        a, b = hub.open_session("a"), hub.open_session("b")
        for s in (a, b):
            s.load = s.named = LoadArgs()
        for i in range(6):  # a asks six times as often as b
            a.pending.append(Pending(i, 0.0, VP, 0.0))
            if i % 3 == 0:
                b.pending.append(Pending(i, 0.0, VP, 0.0))
        order = []
        for _ in range(4):
            hub.schedule()
            job = pool.submitted[-1]
            order.append(job.session)
            pool.results.append(Result(job.job, job.session, False, "x"))
            hub.drain()
        return order

    assert asyncio.run(run()) == ["a", "b", "a", "b"]


def test_a_request_with_a_bad_viewpoint_is_refused_before_any_render():
    s = Session(FakeHub(), Caps(rate=1e9))
    s.load = LoadArgs()
    skew = {**VP, "y": [0.5, 1.0, 0.0]}  # axes not orthonormal
    s.handle(pack(encode({"kind": "request", "seq": 3, "t": 0.0, "viewpoint": skew})))
    assert not s.pending and s.counts["rejected"] == 1 and replies(s)[-1].ok is False


def test_a_send_that_never_completes_ends_the_writer(monkeypatch):
    from lodsprite.distributed.web import sessions

    monkeypatch.setattr(sessions, "SEND_TIMEOUT_S", 0.05)
    s = Session(FakeHub())
    sent = []

    async def stuck(data):
        sent.append(data)
        await asyncio.Event().wait()  # a page that never reads

    async def run():
        s.reply(1, True)
        task = asyncio.get_running_loop().create_task(s.run_writer(stuck))
        await asyncio.wait({task}, timeout=10.0)  # a deadline against a hang only
        return task

    task = asyncio.run(run())
    assert task.done() and isinstance(task.exception(), TimeoutError)
    assert len(sent) == 1


def test_a_job_the_pool_refuses_is_answered_and_frees_its_place():
    from lodsprite.errors import InputError

    class Refusing(FakePool):
        def submit(self, job):
            raise InputError("bad job")

    async def run():
        return scheduled(Refusing(1))

    hub, s = asyncio.run(run())
    assert not hub.jobs and not s.inflight and s.counts["failed"] == 1
    assert replies(s)[-1].seq == 5 and "bad job" in replies(s)[-1].error


def test_loads_superseded_while_waiting_build_nothing(monkeypatch):
    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.web import hub as hub_module

    built = []
    monkeypatch.setattr(hub_module, "build_scene_field",
                        lambda args, codec, root=None: built.append(args.terrain) or (encode(
                            {"kind": "reply", "seq": 0, "ok": True}), None))

    async def run():
        hub = Hub(FakePool(1), Datasets(None))
        s = hub.open_session("a")
        for seed in range(5):  # five loads in a row: only the last one counts
            hub.load(s, LoadArgs(terrain=f"fractal:64:{seed}", lod=8), seed)
        await asyncio.gather(*hub._tasks)
        return s

    s = asyncio.run(run())
    assert built == ["fractal:64:4"] and s.load.terrain == "fractal:64:4"


def test_a_job_the_pool_gave_up_on_is_answered_with_its_code():
    async def run():
        pool = FakePool(1)
        hub, s = scheduled(pool)
        job = pool.submitted[-1]
        pool.results.append(Result(job.job, job.session, False, "refused by 2 render "
                                   "worker(s): no such file", code="refused"))
        hub.drain()
        return hub, s

    hub, s = asyncio.run(run())
    last = replies(s)[-1]
    assert (last.seq, last.ok, last.data) == (5, False, {"code": "refused"})
    assert "no such file" in last.error and not hub.jobs and s.counts["failed"] == 1


def test_a_request_superseded_before_its_render_is_never_rendered():
    """Coalescing: while the one renderer is busy, a session's newer request replaces its
    waiting one (counted ``superseded``); only the newest reaches the pool."""
    async def run():
        pool = FakePool(1)
        hub = Hub(pool, datasets=None, caps=Caps(session_jobs=1, rate=1e9))
        busy, s = hub.open_session("busy"), hub.open_session("s")
        for x in (busy, s):
            x.load = x.named = LoadArgs()
        busy.pending.append(Pending(1, 0.0, VP, 0.0))
        hub.schedule()  # the renderer is taken
        for seq in (10, 11, 12):  # s asks three times meanwhile
            s.handle(pack(encode({"kind": "request", "seq": seq, "t": seq / 10,
                                  "viewpoint": VP})))
        first = pool.submitted[-1]
        pool.results.append(Result(first.job, first.session, False, "x"))
        hub.drain()  # the renderer is free: s's waiting request goes
        return pool, s

    pool, s = asyncio.run(run())
    assert [(j.session, j.t) for j in pool.submitted] == [("busy", 0.0), ("s", 1.2)]
    assert s.counts["superseded"] == 2 and not s.pending


def test_a_scene_is_released_when_no_open_session_uses_it_any_more():
    """Closing, the release op and a load of another scene each give the renderers the
    old scene back, once no other open session uses it."""
    from lodsprite.distributed.pool.jobs import job_key

    class Releasing(FakePool):
        def __init__(self):
            super().__init__(1)
            self.released = []

        def release(self, key):
            self.released.append(key)

    async def run():
        pool = Releasing()
        hub = Hub(pool, datasets=None)
        one, other = LoadArgs(terrain="fractal:64:1"), LoadArgs(terrain="fractal:64:2")
        a, b, c = hub.open_session("a"), hub.open_session("b"), hub.open_session("c")
        a.named = b.named = one
        c.named = other
        hub.close_session(a)
        assert pool.released == []  # b still shows it
        hub._apply(b, other, other, 1)  # b loads another scene: nobody uses one now
        assert pool.released == [job_key(one)]
        c.handle(pack(encode({"kind": "control", "seq": 1, "op": "release", "args": {}})))
        assert pool.released == [job_key(one)]  # b shows other still
        hub.close_session(b)
        assert pool.released == [job_key(one), job_key(other)]
        hub.close()

    asyncio.run(run())
