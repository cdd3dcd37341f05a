"""The local render pool: jobs through two renderer processes, a renderer killed
mid-keyframe, one answering garbage, one hung past the job timeout, and no process left
behind.

One pool with two renderers serves the module's tests in order (round trip, garbage,
kill, close); the timeout and orphan tests start their own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from conftest import gone, wait_until
from lodsprite.camera import look_at
from lodsprite.distributed.pool import Job, LocalPool
from lodsprite.distributed.pool.jobs import POOL_VERSION
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint, decode_keyframe
from lodsprite.errors import InputError

SCENE = LoadArgs(terrain="fractal:64:1", size=(64, 64), lod=16)
OTHER = LoadArgs(terrain="fractal:64:2", texture="checker:4", size=(64, 64), lod=16)
VIEW = WireViewpoint(**look_at((0.0, -900.0, 500.0), (0.0, 0.0, 0.0)).to_dict())
NOTICED_S = 5.0
"""A killed renderer's pipe ends at once: noticed within this (a loaded machine's slack)."""


def job(i: int, load: LoadArgs = SCENE, session: str = "s") -> Job:
    return Job(i, session, load, VIEW, float(i))


def results(broker: LocalPool, n: int, timeout_s: float = 20.0) -> dict:
    got: dict = {}

    def more():
        for r in broker.poll():
            got[r.job] = r
        return len(got) >= n

    wait_until(more, timeout_s, f"{n} results")
    return got


@pytest.fixture(scope="module")
def broker():
    b = LocalPool()
    b.spawn_local(2)
    wait_until(lambda: len(b.workers()) == 2, 30.0, "two local workers connecting")
    yield b
    b.close()


def grew(before: dict, after: dict, key: str) -> int:
    """How much the broker's count ``key`` grew during a test (module-scoped broker:
    counts of earlier tests are not this test's)."""
    return after[key] - before[key]


def test_jobs_round_trip_through_two_local_workers(broker: LocalPool) -> None:
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


def thread_nices(pid: int) -> list[int]:
    """The nice value of every thread of process ``pid`` (Linux ``/proc``)."""
    out = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        out.append(int(fields[16]))  # field 19 of stat; 3 is the first after the name
    return out


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="Linux /proc")
def test_renderers_draw_at_a_lower_priority_than_the_page_they_serve(
        broker: LocalPool) -> None:
    """Every thread of a renderer, the GL driver's started with its context included,
    runs at the pool's nice (the page or notebook on the same machine keeps its frames);
    this process keeps its own."""
    broker.submit(job(50))
    assert results(broker, 1)[50].ok
    base = os.getpriority(os.PRIO_PROCESS, 0)
    pids = [p.pid for p in broker.local_processes() if p.is_alive()]
    assert pids
    for pid in pids:
        nices = thread_nices(pid)
        assert len(nices) > 1 and min(nices) >= min(19, base + broker.nice), nices
    assert broker.nice > 0 and os.getpriority(os.PRIO_PROCESS, 0) == base


def test_workers_follow_the_data_rule_and_jobs_are_checked_on_submit(broker: LocalPool) -> None:
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


def test_a_renderer_answering_garbage_is_killed_and_its_job_done_by_another(
        broker: LocalPool, monkeypatch) -> None:
    """An answer that does not decode as its job's keyframe: the renderer is lost and
    killed, the job rendered again by a renderer that answers properly."""
    from lodsprite.distributed.pool import local_pool

    real = local_pool.LocalPool._answer
    lied: list[int] = []

    def liar(self, r, answer, now):
        if not lied:
            lied.append(r.worker.pid)
            answer = (answer[0], b"\x00" * len(answer[1]))
        return real(self, r, answer, now)

    monkeypatch.setattr(local_pool.LocalPool, "_answer", liar)
    before = broker.stats()
    broker.submit(job(10))
    r = results(broker, 1)[10]
    assert r.ok, r.error
    assert lied and lied[0] not in {w.pid for w in broker.workers()}
    wait_until(lambda: len(broker.workers()) == 2, 30.0, "the liar's successor joining")
    stats = broker.stats()
    assert grew(before, stats, "rejected") == 1 and grew(before, stats, "requeued") == 1


def test_a_hung_renderer_is_killed_at_the_job_timeout_and_replaced() -> None:
    """SIGSTOP: the process lives and its pipe stays open; only the job's timeout tells."""
    with LocalPool(job_timeout_s=2.0) as pool:  # a warm 64² job takes tens of ms
        pool.spawn_local(1)
        wait_until(lambda: len(pool.workers()) == 1, 30.0, "one renderer ready")
        pool.submit(job(1))
        assert results(pool, 1)[1].ok
        stuck = pool.workers()[0]
        os.kill(stuck.pid, signal.SIGSTOP)
        pool.submit(job(2))
        r = results(pool, 1, 60.0)[2]
        assert r.ok and r.worker != stuck.id, r.error
        assert gone(stuck.pid)
        # the stuck one at least (on a loaded machine the replacement's cold first job can
        # outlast the 2 s timeout too, and be retried on another)
        assert pool.stats()["dead"] >= 1


def test_a_renderer_killed_mid_keyframe_is_noticed_and_its_job_done_by_another(
        broker: LocalPool) -> None:
    big = LoadArgs(terrain="fractal:1024:3", size=(64, 64), lod=16)  # a slow first load
    before = broker.stats()
    broker.submit(job(20, big))
    busy = wait_until(lambda: [w for w in broker.workers() if w.job == 20], 5.0,
                      "job 20 dispatched")[0]
    os.kill(busy.pid, signal.SIGKILL)
    wait_until(lambda: busy.id not in {w.id for w in broker.workers()},
               NOTICED_S, "the killed renderer noticed")
    r = results(broker, 1, 30.0)[20]
    assert r.ok, r.error
    assert r.worker != busy.id
    after = broker.stats()  # this test's own kill and re-queue, not an earlier test's
    assert grew(before, after, "dead") >= 1 and grew(before, after, "requeued") >= 1


def test_a_scene_no_session_uses_is_dropped_by_the_renderers_that_held_it(
        broker: LocalPool) -> None:
    from lodsprite.distributed.pool.jobs import job_key

    broker.submit(job(50, OTHER))
    assert results(broker, 1)[50].ok
    before = broker.stats()["released"]
    broker.release(job_key(OTHER))
    wait_until(lambda: broker.stats()["released"] == before + 1, 20.0, "the scene dropped")
    broker.release(job_key(OTHER))  # held by none now: nothing more dropped
    broker.submit(job(51))  # and the renderers go on
    assert results(broker, 1)[51].ok
    assert broker.stats()["released"] == before + 1


def test_a_prepared_scene_is_opened_by_one_renderer_which_then_takes_its_first_job(
        broker: LocalPool) -> None:
    """``prepare``: one idle renderer opens the scene (counted ``prepared``); the first
    job of that scene goes to it; a scene a renderer holds already is not prepared again."""
    from lodsprite.distributed.pool.jobs import job_key

    fresh = LoadArgs(terrain="fractal:64:7", size=(64, 64), lod=16)
    wait_until(lambda: len(broker.workers()) == 2, 30.0, "both renderers serving")
    before = broker.stats()["prepared"]
    broker.prepare(fresh)
    wait_until(lambda: broker.stats()["prepared"] == before + 1, 30.0, "the scene opened")
    holders = [k for k, p in broker.table.peers.items() if job_key(fresh) in p.scenes]
    assert len(holders) == 1
    broker.submit(job(60, fresh))
    assert results(broker, 1)[60].worker == holders[0][1].hex()
    broker.prepare(fresh)  # held already: nothing opened again
    broker.submit(job(61))
    assert results(broker, 1)[61].ok
    assert broker.stats()["prepared"] == before + 1
    assert not any(("prepare", job_key(fresh)) in r.worker.pending  # nor on its way
                   for r in broker._renderers if r.worker is not None)
    # a renderer opening a scene is the last choice for another scene's job (chosen by
    # when it was last idle, not by how long the opening takes)
    slow = LoadArgs(terrain="fractal:64:5", size=(64, 64), lod=16)
    broker.prepare(slow)
    broker.submit(job(62, LoadArgs(terrain="fractal:64:9", size=(64, 64), lod=16)))
    opener = wait_until(lambda: [k for k, p in broker.table.peers.items()
                                 if job_key(slow) in p.scenes], 10.0, "the prepare sent")[0]
    assert results(broker, 1, 60.0)[62].worker != opener[1].hex()


def test_a_scene_prepared_as_python_builds_it_is_the_one_its_jobs_ask_for(
        broker: LocalPool) -> None:
    """A load built in Python with ``key_scale=2`` (an int) is prepared under the key its
    jobs have once decoded (``2.0``): the first job goes to the renderer that opened it
    (before, the two keys differed and the job opened the scene again elsewhere)."""
    from lodsprite.distributed.pool.jobs import check_load, job_key

    load = LoadArgs(terrain="fractal:64:11", size=(64, 64), lod=16, key_scale=2)
    wait_until(lambda: len(broker.workers()) == 2, 30.0, "both renderers serving")
    before = broker.stats()["prepared"]
    broker.prepare(load)
    wait_until(lambda: broker.stats()["prepared"] == before + 1, 30.0, "the scene opened")
    holders = [k for k, p in broker.table.peers.items() if job_key(check_load(load)) in p.scenes]
    assert len(holders) == 1
    broker.submit(job(70, load))
    assert results(broker, 1)[70].worker == holders[0][1].hex()
    with pytest.raises(InputError):
        broker.prepare({"terrain": "fractal:64:11"})  # not a load: refused, not queued


def test_a_replacement_renderer_opens_what_the_lost_one_held_before_it_takes_jobs(
        broker: LocalPool) -> None:
    """A renderer SIGKILLed: its replacement joins only after opening the scenes the lost
    one held (counted ``prepared``), so that no job waits behind a cold opening."""
    from lodsprite.distributed.pool.jobs import job_key

    held = LoadArgs(terrain="fractal:64:11", size=(64, 64), lod=16)
    wait_until(lambda: len(broker.workers()) == 2, 30.0, "both renderers serving")
    broker.submit(job(70, held))
    victim = results(broker, 1)[70].worker
    before, ids = broker.stats()["prepared"], {w.id for w in broker.workers()}
    os.kill(next(w.pid for w in broker.workers() if w.id == victim), signal.SIGKILL)
    wait_until(lambda: victim not in {w.id for w in broker.workers()}, NOTICED_S,
               "the killed renderer noticed")
    wait_until(lambda: len(broker.workers()) == 2, 60.0, "its replacement serving")
    (new,) = {w.id for w in broker.workers()} - ids
    peer = next(p for k, p in broker.table.peers.items() if k[1].hex() == new)
    assert job_key(held) in peer.scenes  # opened before it joined
    assert broker.stats()["prepared"] >= before + 1


def test_close_leaves_no_process(broker: LocalPool) -> None:
    pids = [p.pid for p in broker.local_processes()]
    assert len(pids) == 2
    broker.close()
    assert all(gone(pid) for pid in pids)
    broker.close()  # idempotent


ORPHAN = textwrap.dedent("""
    from lodsprite.distributed.pool import LocalPool
    if __name__ == "__main__":
        b = LocalPool()
        print(*b.spawn_local(1), flush=True)
        b.wait_workers(1, 30.0)
        print("ready", flush=True)
        import time; time.sleep(60)
""")


def test_renderers_exit_when_their_pool_process_is_killed(tmp_path) -> None:
    script = tmp_path / "parent.py"
    script.write_text(ORPHAN)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                              text=True)
    try:
        pid = int(parent.stdout.readline())
        assert parent.stdout.readline().strip() == "ready"
        parent.kill()
        parent.wait(timeout=10)
        wait_until(lambda: gone(pid), 5.0, "the orphaned renderer exiting")
    finally:
        parent.kill()
        if not gone(pid):
            os.kill(pid, signal.SIGKILL)


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


def test_a_renderer_holds_its_scenes_within_its_cap_least_recently_used_dropped() -> None:
    """Scenes are kept by their estimates (render.keyframe_scene_bytes) under the cap: a
    third scene drops the least recently used, one over the cap alone is refused in one
    line, and the renderer goes on rendering."""
    from lodsprite.distributed.pool.jobs import JobMessage, decode_pool, job_key
    from lodsprite.distributed.pool.render_process import SceneCache
    from lodsprite.distributed.render import keyframe_scene_bytes

    loads = [LoadArgs(terrain=f"fractal:64:{i}", size=(64, 64), lod=16) for i in (1, 2, 3)]
    each = keyframe_scene_bytes(loads[0], (65, 65), None)
    scenes = SceneCache(None, 8, max_mb=2.5 * each / 2**20)  # room for two
    try:
        for i, load in enumerate(loads):
            msg, _ = decode_pool(scenes.render(JobMessage(POOL_VERSION, job(i, load), "raw")))
            assert msg.ok, msg.error
        assert list(scenes.scenes) == [job_key(loads[1]), job_key(loads[2])]
        assert sum(scenes.bytes.values()) <= scenes.max_bytes
        big = LoadArgs(terrain="fractal:1024:1", size=(64, 64), lod=16)
        msg, _ = decode_pool(scenes.render(JobMessage(POOL_VERSION, job(9, big), "raw")))
        assert not msg.ok and msg.refused and "a renderer holds at most" in msg.error
        assert "\n" not in msg.error
        msg, _ = decode_pool(scenes.render(JobMessage(POOL_VERSION, job(10), "raw")))
        assert msg.ok, msg.error
    finally:
        for r in scenes.scenes.values():
            r.release()
        if scenes.gl is not None:
            scenes.gl.release()
