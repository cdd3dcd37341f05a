"""The web hub's load generations, scene queueing, path requests and job timeout, over a
fake pool and fake scene builds (no GL, no dataset loads)."""

import asyncio

import numpy as np
from test_sessions import VP, FakeHub, FakePool, replies, scheduled

from lodsprite.distributed.pool import Result
from lodsprite.distributed.protocol import LoadArgs, encode
from lodsprite.distributed.web.hub import Hub
from lodsprite.distributed.web.sessions import Pending, Session
from lodsprite.distributed.web.wire import unpack


def fake_scene(monkeypatch, built: list) -> None:
    """Scene builds that record their terrain and give a scene-like message with one
    large buffer (the cached object a queued scene must share, not copy)."""
    from lodsprite.distributed.web import hub as hub_module

    def build(args, codec, root=None):
        built.append(args.terrain)
        return encode({"kind": "reply", "seq": 0, "ok": True}, np.zeros(2**20, np.uint8)), (
            f"hf of {args.terrain}")

    monkeypatch.setattr(hub_module, "build_scene_field", build)


def test_a_result_of_an_old_load_is_dropped(monkeypatch):
    """A keyframe rendered for the terrain before a new load never reaches the page."""
    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.web import hub as hub_module

    fake_scene(monkeypatch, [])
    monkeypatch.setattr(hub_module, "_restamp", lambda parts, p: parts)

    async def run():
        pool = FakePool(1)
        hub = Hub(pool, Datasets(None))
        s = hub.open_session("a")
        hub.load(s, LoadArgs(terrain="fractal:64:1", lod=8), 1)
        await asyncio.gather(*hub._tasks)
        s.pending.append(Pending(2, 0.0, VP, 0.0))
        hub.schedule()
        old = pool.submitted[-1]  # in flight for fractal:64:1 ...
        hub.load(s, LoadArgs(terrain="fractal:64:2", lod=8), 3)  # ... when the page moves on
        await asyncio.gather(*hub._tasks)
        pool.results.append(Result(old.job, old.session, True, "", [b"old keyframe"]))
        hub.drain()
        return hub, s

    hub, s = asyncio.run(run())
    assert s.load.terrain == "fractal:64:2" and not s._keyframes and not hub.jobs
    assert s.counts["keyframes_sent"] == 0 and s.counts["stale"] == 1


def test_a_stale_pending_is_dropped_even_if_its_job_is_still_known():
    async def run():
        pool = FakePool(1)
        hub, s = scheduled(pool)
        s.generation += 1  # a newer load applied while the job rendered
        job = pool.submitted[-1]
        pool.results.append(Result(job.job, job.session, True, "", [b"kf"]))
        hub.drain()
        return s

    s = asyncio.run(run())
    assert not s._keyframes and s.counts["stale"] == 1


def test_loads_of_a_cached_scene_queue_one_scene_sharing_the_cached_buffers(monkeypatch):
    from lodsprite.distributed.datasets import Datasets

    built = []
    fake_scene(monkeypatch, built)

    async def run():
        hub = Hub(FakePool(1), Datasets(None))
        s = hub.open_session("a")
        for seq in range(1, 6):  # the page never reads: five loads of one cached scene
            hub.load(s, LoadArgs(terrain="fractal:64:1", lod=8), seq)
            await asyncio.gather(*hub._tasks)
        return hub, s

    hub, s = asyncio.run(run())
    scenes = [r for r in s._replies if isinstance(r, list)]
    cached = next(iter(hub._scenes.values()))[0]
    assert built == ["fractal:64:1"] and len(scenes) == 1 and s.counts["scenes_replaced"] == 4
    assert scenes[0][1] is cached[1]  # the cached buffer itself, not a copy
    assert msgspec_seq(scenes[0]) == 5


def msgspec_seq(parts: list) -> int:
    import msgspec

    return msgspec.msgpack.decode(parts[0])["seq"]


def test_the_writer_sends_a_queued_scene_as_one_web_message():
    s = Session(FakeHub())
    buf = np.arange(10, dtype=np.uint8)
    s.push_scene(encode({"kind": "reply", "seq": 4, "ok": True}, buf))
    s.reply(4, True)
    sent = []

    async def send(data):
        sent.append(bytes(data))
        if len(sent) == 2:
            s.close()

    asyncio.run(asyncio.wait_for(s.run_writer(send), 10.0))
    assert bytes(unpack(sent[0], 2**30)[1]) == buf.tobytes() and len(sent) == 2


def test_resolve_runs_off_the_event_loop(monkeypatch):
    import threading

    from lodsprite.distributed.datasets import Datasets

    fake_scene(monkeypatch, [])
    threads = []

    async def run():
        hub = Hub(FakePool(1), Datasets(None))
        resolve = hub._resolve
        hub._resolve = lambda args: threads.append(threading.current_thread()) or resolve(args)
        hub.load(hub.open_session("a"), LoadArgs(terrain="fractal:64:1", lod=8), 1)
        await asyncio.gather(*hub._tasks)

    asyncio.run(run())
    assert threads and threads[0] is not threading.main_thread()


def test_one_path_at_a_time_per_session_from_the_cached_height_field(monkeypatch):
    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.protocol import PathArgs
    from lodsprite.distributed.web import hub as hub_module

    fake_scene(monkeypatch, [])
    fields = []
    monkeypatch.setattr(hub_module, "path_data",
                        lambda load, args, hf, root=None: fields.append(hf) or {"viewpoints": []})

    async def run():
        hub = Hub(FakePool(1), Datasets(None))
        s = hub.open_session("a")
        hub.load(s, LoadArgs(terrain="fractal:64:1", lod=8), 1)
        await asyncio.gather(*hub._tasks)
        for seq in (2, 3, 4):  # three at once: the first is computed, the others refused
            hub.path(s, PathArgs(), seq)
        await asyncio.gather(*hub._tasks)
        hub.path(s, PathArgs(), 5)  # the first done: a new one is taken
        await asyncio.gather(*hub._tasks)
        return s

    s = asyncio.run(run())
    answers = {r.seq: r.ok for r in replies(s) if r.seq >= 2}
    assert answers == {2: True, 3: False, 4: False, 5: True}
    assert fields == ["hf of fractal:64:1"] * 2  # the scene's field: no second load


def test_the_hub_waits_for_the_pools_own_job_timeout(monkeypatch):
    """The broker re-queues a slow job itself: the hub must not give up (and resubmit)
    before the broker's timeout times its tries (lost and declined workers)."""
    from lodsprite.distributed.web import hub as hub_module

    class Slow(FakePool):
        job_timeout_s = 100.0

    now = [1000.0]
    monkeypatch.setattr(hub_module.time, "monotonic", lambda: now[0])

    async def run():
        hub, s = scheduled(Slow(1))
        now[0] += 100.0 * hub_module.POOL_TRIES - 1.0  # the broker still owns the job
        hub._expire()
        kept = len(hub.jobs)
        now[0] += 1.0 + hub_module.JOB_GRACE_S + 1.0
        hub._expire()
        return kept, hub, s

    kept, hub, s = asyncio.run(run())
    assert kept == 1 and not hub.jobs and s.counts["failed"] == 1


def test_only_the_newest_built_scene_keeps_its_height_field(monkeypatch):
    from lodsprite.distributed.datasets import Datasets

    fake_scene(monkeypatch, [])

    async def run():
        hub = Hub(FakePool(1), Datasets(None))
        s = hub.open_session("a")
        for seed in (1, 2, 3):
            hub.load(s, LoadArgs(terrain=f"fractal:64:{seed}", lod=8), seed)
            await asyncio.gather(*hub._tasks)
        return hub

    fields = [hf for _, hf in asyncio.run(run())._scenes.values()]
    assert fields == [None, None, "hf of fractal:64:3"]  # the scene cache stays 4 deep
