"""The render pool's dispatch policy without processes (:class:`JobTable`): who gets a job,
when a declined or orphaned job fails, and who counts as dead."""

from __future__ import annotations

from lodsprite.camera import look_at
from lodsprite.distributed.pool import Job
from lodsprite.distributed.pool.dispatch import MAX_TRIES, JobTable
from lodsprite.distributed.pool.jobs import POOL_VERSION, Ready, job_key
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
OTHER = LoadArgs(terrain="fractal:64:2", size=(64, 64), lod=16)
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
A, B, C = (1, b"a"), (1, b"b"), (0, b"c")


def table(*keys, now: float = 0.0) -> JobTable:
    t = JobTable(60.0, lambda: None)
    for i, k in enumerate(keys):
        t.ready(k, Ready(POOL_VERSION, pid=i), now + i)  # A idle longest
    return t


def job(i: int, load: LoadArgs = SCENE) -> Job:
    return Job(i, "s", load, VIEW, float(i))


def test_a_job_goes_to_a_worker_with_its_scene_else_to_the_one_idle_longest():
    t = table(A, B)
    t.peers[B].scenes.append(job_key(OTHER))
    t.add(job(1, OTHER))
    t.add(job(2))
    t.add(job(3))
    got = [(k, e.job.job) for k, e in t.assign(10.0)]
    assert got == [(B, 1), (A, 2)]  # B has OTHER loaded; job 3 waits for an idle worker
    assert [e.job.job for e in t.queue] == [3]


def test_a_job_declined_by_every_connected_worker_fails_as_refused():
    t = table(A, B)
    t.add(job(1))
    for key in (A, B):
        [(k, entry)] = t.assign(1.0)
        assert k == key  # the decliner is not asked again
        t.answered(t.peers[k], 2.0)
        t.declined(k, t.release(t.peers[k], 2.0), f"no data on {k[1]!r}", refused=True)
    [result] = t.done
    assert not result.ok and result.code == "refused" and "2 render worker(s)" in result.error
    assert not t.queue and t.counts["declined"] == 2


def test_a_job_whose_workers_die_is_requeued_in_front_then_lost():
    t = table(*[(0, bytes([i])) for i in range(MAX_TRIES + 1)])  # one keeps job 2
    t.add(job(1))
    t.add(job(2))
    for i in range(MAX_TRIES):
        [(k, entry), *_] = t.assign(float(i))
        assert entry.job.job == 1  # back in front each time
        t.lose(k, "silent")
    assert [r.job for r in t.done] == [1] and t.done[0].code == "lost"
    assert t.counts["dead"] == MAX_TRIES and t.counts["requeued"] == MAX_TRIES - 1


def test_a_worker_holding_a_job_past_the_timeout_expires_and_an_idle_one_never():
    t = table(A, B)  # a 60 s job timeout
    t.add(job(1))
    [(k, _)] = t.assign(10.0)
    assert t.expired(70.0) == [] and t.expired(70.1) == [k]
    idle = B if k == A else A
    assert idle not in t.expired(1e6)
    t.lose(k, "timed out")
    assert t.counts["dead"] == 1 and [q.job.job for q in t.queue] == [1]
