"""The local render pool: jobs through local workers, a worker killed mid-keyframe,
hostile frames to the broker, and no process left behind.

One broker with two local workers serves the module's tests in order (round trip,
hostile frames, kill, close); the orphan test starts its own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import zmq

from conftest import gone, wait_until
from lodsprite.camera import look_at
from lodsprite.distributed.pool import LIVENESS_S, Broker, Job
from lodsprite.distributed.pool.jobs import (
    POOL_VERSION,
    Heartbeat,
    Ready,
    ResultMessage,
    encode_pool,
)
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint, decode_keyframe
from lodsprite.errors import InputError

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
OTHER = LoadArgs(terrain="fractal:64:2", texture="checker:4", size=(64, 64), lod=16)
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
SLACK_S = 0.5
"""Scheduling slack on this loaded machine beyond the 1 s liveness (a stated tolerance)."""


def job(i: int, load: LoadArgs = SCENE, session: str = "s") -> Job:
    return Job(i, session, load, VIEW, float(i))


def results(broker: Broker, n: int, timeout_s: float = 20.0) -> dict:
    got: dict = {}

    def more():
        for r in broker.poll():
            got[r.job] = r
        return len(got) >= n

    wait_until(more, timeout_s, f"{n} results")
    return got


@pytest.fixture(scope="module")
def broker():
    b = Broker()
    b.spawn_local(2)
    wait_until(lambda: len(b.workers()) == 2, 30.0, "two local workers connecting")
    yield b
    b.close()


def grew(before: dict, after: dict, key: str) -> int:
    """How much the broker's count ``key`` grew during a test (module-scoped broker:
    counts of earlier tests are not this test's)."""
    return after[key] - before[key]


def test_jobs_round_trip_through_two_local_workers(broker: Broker) -> None:
    before = broker.stats()
    for i in range(4):
        broker.submit(job(i))
    got = results(broker, 4)
    assert sorted(got) == [0, 1, 2, 3]
    for i, r in got.items():
        assert r.ok and r.session == "s", r.error
        kf = decode_keyframe(r.parts)
        assert kf.seq == i and kf.t0 == float(i)
        assert kf.color.shape == (64, 64, 3) and kf.depth.shape == (64, 64)
        assert kf.color.std() > 1.0  # terrain drawn, not a cleared target
    # Four jobs at once on two idle workers: both took some.
    assert {r.worker for r in got.values()} == {w.id for w in broker.workers()}
    after = broker.stats()
    assert grew(before, after, "results") == 4
    # The render capacity is measured: four answered jobs took time on the workers.
    assert after["busy_s"] > before["busy_s"] and after["job_ms_p50"] > 0.0
    assert after["job_ms_p90"] >= after["job_ms_p50"]


def test_workers_follow_the_data_rule_and_jobs_are_checked_on_submit(broker: Broker) -> None:
    import msgspec

    broker.submit(job(40, msgspec.structs.replace(SCENE, terrain="dem.npy")))
    broker.submit(job(41, msgspec.structs.replace(SCENE, texture="/etc/hosts")))
    got = results(broker, 2)
    assert not got[40].ok and "serves no files" in got[40].error
    assert not got[41].ok and "serves no files" in got[41].error
    with pytest.raises(InputError, match="bad job"):
        broker.submit(job(42, session="x" * 500))
    with pytest.raises(InputError, match="takes a Job"):
        broker.submit({"job": 1})


def test_hostile_frames_do_not_stop_the_broker(broker: Broker) -> None:
    rng = np.random.default_rng(7)
    before = broker.stats()
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(broker.local_endpoint)
    hostile = [[rng.bytes(int(n))] for n in rng.integers(0, 300, 200)]
    hostile += [[b""], [b"\x81\xa1v\x01"], [b"\xc1"], [b"x"] * 200,  # many frames
                encode_pool(Ready(POOL_VERSION, cache=1)) + [b"extra"],
                [b'\x82\xa1v\x63\xa4kind\xa5ready'],                    # wrong version
                encode_pool(ResultMessage(POOL_VERSION, 99, True)),     # no keyframe parts
                encode_pool(ResultMessage(POOL_VERSION, 99, False, "x" * 5000))]
    for frames in hostile:
        sock.send_multipart(frames)
    # A worker that says ready, takes a job and answers garbage: disconnected, its job
    # re-queued and rendered by a real worker.
    sock.send_multipart(encode_pool(Ready(POOL_VERSION, name="liar")))
    wait_until(lambda: len(broker.workers()) == 3, 5.0, "the liar joining")
    for i in (10, 11, 12):  # the real two are busy, the liar gets one
        broker.submit(job(i))
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    deadline = time.monotonic() + 10.0
    lied = False
    while not lied and time.monotonic() < deadline:
        if poller.poll(100):
            msg = sock.recv_multipart()
            if b"job" in msg[0]:
                import msgspec

                jid = msgspec.msgpack.decode(msg[0])["job"]["job"]
                sock.send_multipart(encode_pool(ResultMessage(POOL_VERSION, jid, True),
                                                b"\x00" * 10, b"junk", b"more junk"))
                lied = True
            else:
                sock.send_multipart(encode_pool(Heartbeat(POOL_VERSION)))
    assert lied, "the liar was never given a job"
    got = results(broker, 3)
    assert all(r.ok for r in got.values())
    assert {r.worker for r in got.values()} <= {w.id for w in broker.workers()}
    assert all(w.name != "liar" for w in broker.workers())
    stats = broker.stats()
    assert grew(before, stats, "rejected") >= 200 and grew(before, stats, "requeued") >= 1
    sock.close(linger=0)
    broker.submit(job(13))  # still serving
    assert results(broker, 1)[13].ok


def test_a_silent_worker_is_dead_after_a_second_and_rejoins_when_it_wakes(
        broker: Broker) -> None:
    """SIGSTOP keeps the connection open: only the heartbeats' absence tells."""
    broker.submit(job(30, LoadArgs(terrain="fractal:1024:4", size=(64, 64), lod=16)))
    busy = wait_until(lambda: [w for w in broker.workers() if w.job == 30], 5.0,
                      "job 30 dispatched")[0]
    os.kill(busy.pid, signal.SIGSTOP)
    try:  # noticed within the liveness (the wait's deadline), done by the other worker
        wait_until(lambda: busy.id not in {w.id for w in broker.workers()},
                   LIVENESS_S + SLACK_S, "the silent worker declared dead")
        r = results(broker, 1, 30.0)[30]
        assert r.ok and r.worker != busy.id, r.error
    finally:
        os.kill(busy.pid, signal.SIGCONT)
    wait_until(lambda: busy.pid in {w.pid for w in broker.workers()}, 10.0,
               "the woken worker rejoining")
    assert len(broker.workers()) == 2


def test_a_worker_killed_mid_keyframe_is_noticed_and_its_job_done_by_another(
        broker: Broker) -> None:
    big = LoadArgs(terrain="fractal:1024:3", size=(64, 64), lod=16)  # a slow first load
    before = broker.stats()
    broker.submit(job(20, big))
    busy = wait_until(lambda: [w for w in broker.workers() if w.job == 20], 5.0,
                      "job 20 dispatched")[0]
    os.kill(busy.pid, signal.SIGKILL)
    wait_until(lambda: busy.id not in {w.id for w in broker.workers()},  # the deadline:
               LIVENESS_S + SLACK_S, "the killed worker noticed")  # noticed within it
    r = results(broker, 1, 30.0)[20]
    assert r.ok, r.error
    assert r.worker != busy.id
    after = broker.stats()  # this test's own kill and re-queue, not an earlier test's
    assert grew(before, after, "dead") >= 1 and grew(before, after, "requeued") >= 1


def test_close_leaves_no_process(broker: Broker) -> None:
    pids = [p.pid for p in broker.local_processes()]
    assert len(pids) == 2
    broker.close()
    assert all(gone(pid) for pid in pids)
    broker.close()  # idempotent


ORPHAN = textwrap.dedent("""
    from lodsprite.distributed.pool import Broker
    if __name__ == "__main__":
        b = Broker()
        print(*b.spawn_local(1), flush=True)
        b.wait_workers(1, 30.0)
        print("ready", flush=True)
        import time; time.sleep(60)
""")


def test_local_workers_exit_when_their_broker_process_is_killed(tmp_path) -> None:
    script = tmp_path / "parent.py"
    script.write_text(ORPHAN)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                              text=True)
    try:
        pid = int(parent.stdout.readline())
        assert parent.stdout.readline().strip() == "ready"
        parent.kill()
        parent.wait(timeout=10)
        wait_until(lambda: gone(pid), 5.0, "the orphaned worker exiting")
    finally:
        parent.kill()
        if not gone(pid):
            os.kill(pid, signal.SIGKILL)


def test_a_reconnecting_worker_forgets_the_jobs_of_its_last_connection() -> None:
    """Jobs queued for the render thread when a connection ended went back to the
    broker's queue: a new connection starts with none of them."""
    import threading

    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.pool.jobs import Disconnect
    from lodsprite.distributed.pool.render_worker import Worker, _RenderThread

    zctx = zmq.Context()
    router = zctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    router.bind("inproc://test-broker")
    pipe = zctx.socket(zmq.PAIR)
    pipe.setsockopt(zmq.LINGER, 0)
    pipe.bind("inproc://test-render")
    renderer = _RenderThread(zctx, "inproc://test-render", Datasets(None), 1)  # not started
    renderer.jobs.put("left over from the last connection")
    worker = Worker("inproc://test-broker")
    session = threading.Thread(target=worker._session, args=(zctx, pipe, renderer))
    session.start()
    try:
        assert router.poll(5000), "the worker never said ready"
        peer = router.recv_multipart()[0]
        router.send_multipart([peer, *encode_pool(Disconnect(POOL_VERSION, "test"))])
        session.join(timeout=5.0)
        assert not session.is_alive() and renderer.jobs.empty()
    finally:
        worker.stop()
        session.join(timeout=5.0)
        renderer.out.close(linger=0)
        for sock in (router, pipe):
            sock.close(linger=0)
        zctx.term()


def test_a_worker_renders_without_pacing_what_it_is_asked_for() -> None:
    """The submitter decides when a keyframe is due: a worker's renderer never paces
    (no per-keyframe reprojection for a pacer), even when the job's load says
    ``pace="needed"`` (the default), and the keyframe it returns is the job's.  Checked
    on the render process's scene cache, in this process."""
    from lodsprite.distributed.pool.jobs import JobMessage, decode_pool, job_key
    from lodsprite.distributed.pool.render_process import SceneCache

    assert SCENE.pace == "needed"
    scenes = SceneCache(None, 1)
    try:
        frames = scenes.render(JobMessage(POOL_VERSION, job(7), "raw"))
        msg, parts = decode_pool(frames)
        assert msg.ok, msg.error
        assert decode_keyframe(parts).seq == 7
        kept = scenes.scenes[job_key(SCENE)]
        assert kept.pacer.pace == "continuous" and kept.pacer.metric is None
    finally:
        for r in scenes.scenes.values():
            r.release()
        scenes.gl.release()
