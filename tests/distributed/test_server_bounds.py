"""A LOD server's bookkeeping does not grow with use: once-logged kinds, count tables and
timing samples stay bounded however long it runs and whatever clients send; the hold is
a lease on a replaceable clock."""

import logging
import re

import numpy as np
import pytest
from hostile import hostile_frames

from lodsprite.distributed import server_stats
from lodsprite.distributed.hold import Hold
from lodsprite.distributed.protocol import CONTROL_OPS, MAX_REPLY_BYTES, decode, encode
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.server import LodServer, ServerStats
from lodsprite.distributed.server_stats import MAX_ONCE_KEYS, MAX_SAMPLES, Tally

A = "a" * 16
SMALL = {"terrain": "fractal:64:1", "size": [64, 64], "lod": 8}


def control(server, op, args=None, client=A, seq=1) -> dict:
    return server._control(encode({"kind": "control", "seq": seq, "op": op,
                                   "args": args or {}, "client": client}))


@pytest.fixture
def server():
    s = LodServer(bind=f"127.0.0.1:{free_ports()}")
    yield s
    s._ctx.term()


# -------------------------------------------------------------------- said once, by kind

def test_loads_of_distinct_bogus_names_leave_one_once_key(server, caplog):
    """Regression: the once-key held the refusal's text, which carries the terrain name a
    client sent: a flood of distinct names grew the set without bound."""
    rng = np.random.default_rng(0)
    n = 500
    with caplog.at_level(logging.WARNING, logger="lodsprite.server"):
        for i in range(n):
            name = f"no-such-{i}-{rng.integers(2**62)}.npy"
            assert control(server, "load", {**SMALL, "terrain": name}, seq=i)["ok"] is False
    assert server._tally.said == {"refuse:load"}
    assert server.stats.refused == {"load": n}
    assert len([r for r in caplog.records if "refused load" in r.getMessage()]) == 1


def test_refusals_by_many_clients_leave_one_once_key_per_op(server):
    assert control(server, "load", SMALL, A)["ok"]
    for i in range(300):
        other = f"{i:016x}"
        for op in ("load", "start", "stop"):
            args = SMALL if op == "load" else None
            assert control(server, op, args, other)["ok"] is False
    assert server._tally.said == {"refuse:load", "refuse:start", "refuse:stop"}
    assert server.stats.refused == {"load": 300, "start": 300, "stop": 300}


def test_hostile_traffic_leaves_fixed_kinds_only(server):
    """Keys of the once-set and of every count table come from fixed sets, never from
    what a message carries."""
    rng = np.random.default_rng(7)
    assert control(server, "load", SMALL, A)["ok"]
    for _ in range(600):
        server._control(hostile_frames("control", rng))
        server._viewpoints.take(hostile_frames("viewpoint", rng))
        frames = hostile_frames("keyframe", rng)
        server._transmitter.ack([rng.bytes(int(rng.integers(0, 20))), *frames], A, 1)
    assert sum(server.stats.rejected.values()) > 500
    kinds = re.compile(r"^(reject:(control|viewpoint|ack)|refuse:[a-z]+|"
                       r"internal:(vp:|ack:)?[A-Za-z_]+|anonymous|no-ack)$")
    assert all(kinds.match(k) for k in server._tally.said), server._tally.said
    assert len(server._tally.said) <= 3 + len(CONTROL_OPS) + 6
    assert set(server.stats.received) == set(server_stats.RECEIVED)
    assert set(server.stats.rejected) == set(server_stats.REJECTED)
    assert set(server.stats.ignored) <= set(server_stats.IGNORED)
    assert set(server.stats.refused) <= set(CONTROL_OPS)


def test_keys_outside_their_set_count_as_other_and_the_once_set_is_capped():
    stats = ServerStats()
    tally = Tally(stats)
    tally.ignore("made up")
    tally.refuse("frobnicate", "no")
    assert stats.ignored == {"other": 1} and stats.refused == {"other": 1}
    for i in range(MAX_ONCE_KEYS + 50):
        tally.once(f"kind{i}", logging.DEBUG, "line %d", i)
    assert len(tally.said) == MAX_ONCE_KEYS


# ---------------------------------------------------------------------- timing samples

def test_timings_keep_the_most_recent_samples_and_exact_counts(server):
    n = MAX_SAMPLES + 25
    for i in range(n):
        server.stats.rendered(viewpoint_wait=i, paced=i, render=i, queue_insert=i,
                              production=i)
        server.stats.sent(queue_retrieve=i, transmission=i, delta_t=i)
    reply = control(server, "stats")
    data = reply["data"]
    assert data["keyframes_rendered"] == n and data["keyframes_sent"] == n
    for k in ("production_ms", "viewpoint_wait_ms", "paced_ms", "render_ms",
              "queue_insert_ms", "delta_t_ms", "queue_retrieve_ms", "transmission_ms"):
        assert isinstance(data[k], list) and len(data[k]) == MAX_SAMPLES
        assert data[k][0] == n - MAX_SAMPLES and data[k][-1] == n - 1
    frames = encode(reply)
    assert sum(len(f) for f in frames) < MAX_REPLY_BYTES // 16
    assert decode(frames)[0]["data"]["render_ms"] == data["render_ms"]


def test_stats_as_dict_is_a_copy():
    stats = ServerStats()
    stats.rendered(viewpoint_wait=1.0, paced=2.0, render=3.0, queue_insert=4.0, production=10.0)
    d = stats.as_dict()
    assert d["render_ms"] == [3.0] and d["keyframes_rendered"] == 1
    assert not any(k.startswith("_") for k in d)
    d["render_ms"].append(99.0)
    d["received"]["control"] = 99
    assert list(stats.render_ms) == [3.0] and stats.received["control"] == 0


# --------------------------------------------------------------------------------- hold

def test_a_hold_is_a_lease_on_its_clock():
    clock, lapsed = [0.0], []
    hold = Hold(2.0, lambda: clock[0], on_lapse=lambda: lapsed.append(clock[0]))
    assert hold.current() is None and not hold.touch(A)
    assert hold.take(A) and not hold.take(A)  # the holder changed once
    clock[0] = 1.5
    assert hold.touch(A) and not hold.touch("b" * 16)
    clock[0] = 3.4
    assert hold.current() == A  # renewed at 1.5
    clock[0] = 3.6
    assert hold.current() is None and lapsed == [3.6]
    assert hold.current() is None and lapsed == [3.6]  # lapses once
    hold.take(A)
    hold.drop()
    assert hold.current() is None and lapsed == [3.6]  # a release is not a lapse


def test_the_server_clock_is_the_holds(server):
    clock = [5.0]
    server.now = lambda: clock[0]
    assert server.now() == 5.0 and server._hold.now() == 5.0
    assert control(server, "load", SMALL, A)["ok"]
    clock[0] += server.lease_s + 0.1
    assert server.holder() is None
