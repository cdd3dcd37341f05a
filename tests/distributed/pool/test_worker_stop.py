"""Render worker processes (real GL, EGL llvmpipe) joined over the broker's endpoint:
stopped by SIGINT while idle and SIGTERM while it holds a job, a worker leaves the pool
with a ``disconnect`` (not by going silent), releases its scenes and GL context and exits
0 without a traceback, and the job it held is done by another worker.  A job a worker
refuses (a dataset its --data lacks) goes to a worker that has it; one no worker can do
fails with code ``refused``, also when the last worker that could take it leaves."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import msgspec
import numpy as np
import pytest
import zmq
from test_pool import results

from conftest import wait_until
from lodsprite.camera import look_at
from lodsprite.distributed.pool import Broker, Job
from lodsprite.distributed.pool.jobs import (
    POOL_VERSION,
    Disconnect,
    Heartbeat,
    Ready,
    ResultMessage,
    encode_pool,
)
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint, decode_keyframe
from lodsprite.scene import load_scene

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
BIG = LoadArgs(terrain="fractal:1024:3", size=(64, 64), lod=16)  # a slow first load
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
DEADLINE_S = 30.0
"""Start-up, GL and a render on this shared machine (a guard against a hang)."""
STOP_DEADLINE_S = 15.0
"""A stopped worker's exit: a heartbeat, the render in progress, GL's release."""


def job(i: int, load: LoadArgs = SCENE) -> Job:
    return Job(i, "s", load, VIEW, float(i))


WORKER = """
import logging, sys
from lodsprite.distributed.pool.render_worker import Worker, stop_on_signals
logging.basicConfig(level=logging.INFO, format="render worker: %(message)s")
worker = Worker(sys.argv[1], sys.argv[2] or None, name="test")
stop_on_signals(worker)
worker.run()
"""


def worker(endpoint: str, data=None) -> subprocess.Popen:
    """A worker process with its own data folder (local workers share the server's:
    here two see different ones), stopped by SIGTERM or SIGINT."""
    cmd = [sys.executable, "-c", WORKER, endpoint, str(data) if data else ""]
    return subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)


def pid_of(broker: Broker, proc: subprocess.Popen) -> str:
    """The broker's id of the worker process ``proc`` once it joined."""
    return wait_until(lambda: [w.id for w in broker.workers() if w.pid == proc.pid],
                      DEADLINE_S, f"worker {proc.pid} joining")[0]


def stopped(proc: subprocess.Popen, signum: int) -> str:
    """Signal ``proc``, wait for it to exit; its stderr (asserting exit 0, no traceback,
    its scenes and GL released)."""
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=STOP_DEADLINE_S)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr, stderr
    assert "and the GL context released" in stderr, stderr
    return stderr


@pytest.fixture
def broker():
    b = Broker()
    yield b
    b.close()


def test_a_worker_stopped_idle_or_mid_job_leaves_the_pool_cleanly(broker: Broker) -> None:
    a, b = worker(broker.local_endpoint), worker(broker.local_endpoint)
    try:
        a_id, b_id = pid_of(broker, a), pid_of(broker, b)
        broker.submit(job(1))
        broker.submit(job(2))  # both render: each holds a GL context and a scene
        assert all(r.ok for r in results(broker, 2, DEADLINE_S).values())
        before = broker.stats()
        stopped(a, signal.SIGINT)  # idle
        wait_until(lambda: a_id not in {w.id for w in broker.workers()}, STOP_DEADLINE_S,
                   "the broker seeing the idle worker leave")
        broker.submit(job(3, BIG))
        wait_until(lambda: [w for w in broker.workers() if w.job == 3], DEADLINE_S,
                   "job 3 dispatched")
        stopped(b, signal.SIGTERM)  # holding job 3
        wait_until(lambda: b_id not in {w.id for w in broker.workers()}, STOP_DEADLINE_S,
                   "the broker seeing the busy worker leave")
        after = broker.stats()
        assert after["dead"] == before["dead"]  # both said disconnect: none went silent
        assert after["requeued"] == before["requeued"] + 1  # job 3 back in the queue
        c = worker(broker.local_endpoint)  # another worker does it
        try:
            r = results(broker, 1, DEADLINE_S)[3]
            assert r.ok and r.worker == pid_of(broker, c), r.error
        finally:
            stopped(c, signal.SIGTERM)
    finally:
        for p in (a, b):
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=10)


def test_a_job_a_worker_refuses_is_done_by_one_that_can(broker: Broker, tmp_path) -> None:
    full, empty = tmp_path / "full", tmp_path / "empty"
    full.mkdir()
    empty.mkdir()
    np.save(full / "hill.npy", load_scene("fractal:64:5", "terrain", 64, 1.0).hf.heights)
    hill = msgspec.structs.replace(SCENE, terrain="hill.npy")
    has, lacks = worker(broker.local_endpoint, full), worker(broker.local_endpoint, empty)
    try:
        has_id, _ = pid_of(broker, has), pid_of(broker, lacks)
        for i in range(4):  # two idle workers: the one that lacks the file gets some
            broker.submit(job(i, hill))
        got = results(broker, 4, DEADLINE_S)
        assert all(r.ok and r.worker == has_id for r in got.values()), got
        assert all(decode_keyframe(r.parts).color.std() > 1.0 for r in got.values())
        assert broker.stats()["declined"] >= 1  # it was refused, then retried
        broker.submit(job(9, msgspec.structs.replace(SCENE, terrain="none.npy")))
        r = results(broker, 1, DEADLINE_S)[9]  # no worker has it: a typed failure, not a hang
        assert not r.ok and r.code == "refused", r
        assert "by 2 render worker(s)" in r.error and "none.npy" in r.error
        stopped(has, signal.SIGTERM)  # the only worker that has it leaves
        wait_until(lambda: has_id not in {w.id for w in broker.workers()}, STOP_DEADLINE_S,
                   "the broker seeing the worker leave")
        broker.submit(job(10, hill))
        r = results(broker, 1, DEADLINE_S)[10]
        assert not r.ok and r.code == "refused" and "by 1 render worker(s)" in r.error, r
    finally:
        for p in (has, lacks):
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=10)


def next_job(sock: zmq.Socket, timeout_s: float = 5.0) -> int:
    """Play a worker on ``sock``: answer heartbeats until a job comes; its id."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sock.poll(100):
            msg = msgspec.msgpack.decode(sock.recv_multipart()[0])
            if msg["kind"] == "job":
                return msg["job"]["job"]
        sock.send_multipart(encode_pool(Heartbeat(POOL_VERSION)))
    pytest.fail(f"no job within {timeout_s} s", pytrace=False)


def test_a_declined_job_fails_when_the_last_worker_that_could_take_it_leaves() -> None:
    """Two workers (played on DEALER sockets) hold jobs 1 and 2; the one with job 1
    refuses it, which leaves job 1 waiting for the other; that one leaves: job 1 fails
    (refused), job 2 goes to the worker that is left."""
    with Broker() as b:
        socks = []
        for name in ("x", "y"):
            s = zmq.Context.instance().socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            s.connect(b.local_endpoint)
            s.send_multipart(encode_pool(Ready(POOL_VERSION, name=name)))
            socks.append(s)
        try:
            wait_until(lambda: len(b.workers()) == 2, 5.0, "both workers joining")
            b.submit(job(1))
            b.submit(job(2))
            held = {next_job(s): s for s in socks}
            assert sorted(held) == [1, 2]
            x, y = held[1], held[2]
            x.send_multipart(encode_pool(ResultMessage(POOL_VERSION, 1, False,
                                                       "InputError: no such file",
                                                       refused=True)))
            y.send_multipart(encode_pool(Disconnect(POOL_VERSION, "stopping")))
            r = results(b, 1, DEADLINE_S)[1]
            assert not r.ok and r.code == "refused" and "no such file" in r.error, r
            assert next_job(x) == 2  # the job the leaving worker held: to the one left
            assert b.stats()["declined"] == 1 and b.stats()["requeued"] == 1
        finally:
            for s in socks:
                s.close(linger=0)
