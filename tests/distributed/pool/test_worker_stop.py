"""`lodsprite render-worker` processes (real GL, EGL llvmpipe) joined over tcp://:
stopped by SIGINT while idle and SIGTERM while it holds a job, a worker leaves the pool
with a ``disconnect`` (not by going silent), releases its scenes and GL context and exits
0 without a traceback, and the job it held is done by another worker."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from conftest import wait_until
from lodsprite.camera import look_at
from lodsprite.distributed.pool import Broker, Job
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
BIG = LoadArgs(terrain="fractal:1024:3", size=(64, 64), lod=16)  # a slow first load
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
DEADLINE_S = 30.0
"""Start-up, GL and a render on this shared machine (a guard against a hang)."""
STOP_DEADLINE_S = 15.0
"""A stopped worker's exit: a heartbeat, the render in progress, GL's release."""


def job(i: int, load: LoadArgs = SCENE) -> Job:
    return Job(i, "s", load, VIEW, float(i))


def worker(endpoint: str, data=None) -> subprocess.Popen:
    cmd = [sys.executable, "-c", "from lodsprite.cli import main; main()", "render-worker",
           "--connect", endpoint, *(["--data", str(data)] if data else [])]
    return subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)


def results(broker: Broker, n: int, timeout_s: float = DEADLINE_S) -> dict:
    got: dict = {}

    def more():
        for r in broker.poll():
            got[r.job] = r
        return len(got) >= n

    wait_until(more, timeout_s, f"{n} results")
    return got


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
    b = Broker(bind="tcp://127.0.0.1:*")
    yield b
    b.close()


def test_a_worker_stopped_idle_or_mid_job_leaves_the_pool_cleanly(broker: Broker) -> None:
    a, b = worker(broker.endpoints[1]), worker(broker.endpoints[1])
    try:
        a_id, b_id = pid_of(broker, a), pid_of(broker, b)
        broker.submit(job(1))
        broker.submit(job(2))  # both render: each holds a GL context and a scene
        assert all(r.ok for r in results(broker, 2).values())
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
        c = worker(broker.endpoints[1])  # another worker does it
        try:
            r = results(broker, 1)[3]
            assert r.ok and r.worker == pid_of(broker, c), r.error
        finally:
            stopped(c, signal.SIGTERM)
    finally:
        for p in (a, b):
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=10)
