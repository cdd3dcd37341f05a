"""The render pool on Ray (``serve --web --ray``): a local Ray instance of two CPUs, started
by this module once, serves its tests; two renderer actors render jobs, refuse what they
cannot serve (answered as the local pool answers), and pages of the web server get
keyframes through them, also when an actor's process is killed in the middle of a job
(Ray restarts it, its job completes elsewhere or after the restart)."""

from __future__ import annotations

import asyncio
import os
import signal
import threading
from typing import TYPE_CHECKING

import pytest

from conftest import needs, wait_until
from lodsprite.camera import look_at
from lodsprite.distributed.pool import Job, dispatch
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint, decode_keyframe

if TYPE_CHECKING:
    from lodsprite.distributed.pool.ray_pool import RayPool

# Ray is imported where the tests run, not while every worker collects (1.9 s each)
pytestmark = needs("ray", reason="the ray extra")

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
DEADLINE_S = 60.0
TOKEN = "test-token"
#: A scene whose first keyframe takes an actor a while (it generates and uploads a
#: 1025² height field first): long enough to kill the actor in the middle of it.
HEAVY = {"terrain": "fractal:1024:3", "size": [256, 256], "lod": 16}
#: A scene whose first keyframe takes several times the timeout below (it generates a
#: 4097² height field first, single-threaded numpy: 5 s on the 2-core machine here);
#: SCENE's first keyframe, in a fresh actor, a small part of it.
SLOW = LoadArgs(terrain="fractal:4096:3", size=(64, 64), lod=16)
VP = {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.6, 0.8], "z": [0.0, -0.8, 0.6],
      "o": [0.0, -1500.0, 1200.0]}


@pytest.fixture(scope="module")
def cluster():
    """The module's Ray instance: two CPUs, one per renderer actor."""
    import ray

    from lodsprite.distributed.pool.ray_pool import INLINE_BYTES

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             object_store_memory=100 * 2**20,  # lean: keyframes travel inline anyway
             _system_config={"max_direct_call_object_size": INLINE_BYTES})
    yield
    ray.shutdown()


@pytest.fixture
def pool(cluster):
    """Two renderer actors on a thread of the pool's own (a pool nobody starts on a
    loop); closing it kills them, freeing the CPUs for the next test's."""
    from lodsprite.distributed.pool.ray_pool import RayPool

    with RayPool("auto", 2) as p:  # joins the instance above
        assert p.wait_workers(2, DEADLINE_S), "two renderer actors joining"
        yield p


def results(pool: RayPool, jobs: set[int]) -> dict:
    got: dict = {}

    def more():
        got.update({r.job: r for r in pool.poll()})
        return jobs <= set(got)

    wait_until(more, DEADLINE_S, f"results of jobs {sorted(jobs)}")
    return got


def test_actors_render_jobs_and_refuse_what_they_cannot_serve(pool: RayPool) -> None:
    before = pool.stats()
    for i in range(1, 5):
        pool.submit(Job(i, "s", SCENE, VIEW, float(i)))
    missing = LoadArgs(terrain="nowhere.npy", size=(64, 64), lod=16)
    pool.submit(Job(5, "s", missing, VIEW, 5.0))
    got = results(pool, {1, 2, 3, 4, 5})
    for i in range(1, 5):
        assert got[i].ok and got[i].session == "s", got[i].error
        kf = decode_keyframe(got[i].parts)
        assert kf.seq == i and kf.color.shape[:2] == (64, 64)
    refused = got[5]
    assert not refused.ok and refused.code == "refused" and "nowhere.npy" in refused.error
    after = pool.stats()
    assert after["results"] - before["results"] == 4
    assert after["overhead_ms_p50"] is not None and after["overhead_ms_p50"] >= 0.0
    names = {w.name for w in pool.workers()}
    assert len(names) == 2 and all(n.startswith("ray-") for n in names)


def test_pages_play_through_actors_and_a_killed_actor_costs_no_keyframe(cluster) -> None:
    """The web server as ``serve --web --ray`` makes it (its pool on the server's loop):
    two pages get keyframes through the actors; the actor rendering a page's keyframe is
    killed (SIGKILL) in the middle of it: the keyframe still comes, Ray restarts the
    actor, which joins the pool again, and the page goes on getting keyframes."""
    import aiohttp

    from lodsprite.distributed.web.client import connect
    from lodsprite.distributed.web.server import WebConfig, WebServer

    out = {}

    async def main() -> int:
        server = WebServer(WebConfig(token=TOKEN, renderers=2, ray="auto"))
        pool = out["pool"] = server.pool
        assert type(pool).__name__ == "RayPool"
        url = await server.start()
        assert pool._owner == threading.get_ident()  # on this loop, not a thread of its own
        base = url.split("/?")[0]
        try:
            async with aiohttp.ClientSession() as http:
                light = await connect(http, base, TOKEN)
                heavy = await connect(http, base, TOKEN)
                await light.load({"terrain": "fractal:64:1", "size": [64, 64], "lod": 8})
                await heavy.load(HEAVY)
                assert (await light.keyframe(VP, 1.0)).seq == light.seq
                job = asyncio.create_task(heavy.keyframe(VP, 2.0))
                victim = None
                while victim is None and not job.done():  # the actor holding the job
                    busy = [w for w in pool.workers() if w.job is not None]
                    victim = busy[0].pid if busy else None
                    await asyncio.sleep(0.005)
                assert victim is not None, "the heavy keyframe was never in an actor"
                os.kill(victim, signal.SIGKILL)
                kf = await asyncio.wait_for(job, DEADLINE_S)
                assert kf.seq == heavy.seq and kf.t0 == 2.0
                for t in (3.0, 4.0):  # both pages keep playing
                    assert (await heavy.keyframe(VP, t)).t0 == t
                    assert (await light.keyframe(VP, t)).t0 == t
                stats = pool.stats()
                assert stats["dead"] == 1
                assert stats["requeued"] == 1  # it held the job when it died
                assert stats["failed"] == 0
                while len(pool.workers()) < 2:  # the killed actor, restarted by Ray
                    await asyncio.sleep(0.02)
                assert victim not in pool.actor_pids().values()
                await light.close()
                await heavy.close()
                return victim
        finally:
            await server.stop()

    asyncio.run(asyncio.wait_for(main(), 3 * DEADLINE_S))


def test_a_renderer_past_the_job_timeout_is_restarted_and_joins_again(cluster,
                                                                      monkeypatch) -> None:
    """A job that outlasts the timeout has its actor killed and restarted by Ray: the job
    is given up after its tries (one here: a job requeued after its actor died is the
    killed-actor test's, and the dispatcher's own), the renderer joins again and serves."""
    from lodsprite.distributed.pool.ray_pool import RayPool

    monkeypatch.setattr(dispatch, "MAX_TRIES", 1)
    with RayPool("auto", 1, job_timeout_s=1.5) as p:
        assert p.wait_workers(1, DEADLINE_S), "the renderer actor joining"
        p.submit(Job(1, "s", SLOW, VIEW, 1.0))
        late = results(p, {1})[1]
        assert not late.ok, "a job past the timeout every try is given up"
        assert p.wait_workers(1, DEADLINE_S), "the restarted renderer joining again"
        # the restarted actor's first job is a cold one (shaders, the scene); on a loaded
        # machine it may itself outlast 1.5 s, which is not what this test asks about
        p.table.job_timeout_s = DEADLINE_S
        p.submit(Job(2, "s", SCENE, VIEW, 2.0))
        served = results(p, {2})[2]
        assert served.ok, served.error
