"""Dispatch overhead per keyframe of the two render pools, apart from the load: one job at
a time through the local pool (:class:`~lodsprite.distributed.pool.LocalPool`, a
renderer process) and through Ray (:class:`~lodsprite.distributed.pool.ray_pool.RayPool`,
a renderer actor on a local Ray instance), each driven as the web hub drives it (an
asyncio loop woken by the pool's descriptor; the Ray pool on that loop).

A job's overhead is its round trip at the submitter (submit to the result in hand) less
the renderer's own time on it (``render_ms``: decode, render with the read-back,
encode), so what is left is the pool's: queueing, transport of the job and of the
keyframe (a 256² keyframe is about 0.26 MB raw), the hops to the submitter's loop.
Both pools are measured in the same run, alternately in rounds, after the same warm-up.
Then, in a second Ray instance with Ray's default ``max_direct_call_object_size``
(100 KB), the Ray pool again (``ray_object_store``): a keyframe larger than that goes
through the object store rather than inline in the actor's reply.

    python benchmarks/pool_overhead.py --jobs 200 --size 256
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time

import numpy as np

from lodsprite.camera import look_at
from lodsprite.distributed.pool import Job, LocalPool
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint


async def one(pool, job: Job, ready: asyncio.Event) -> tuple[float, float]:
    """(round trip ms, the renderer's render_ms) of one job."""
    ready.clear()
    t0 = time.perf_counter()
    pool.submit(job)
    while True:
        for r in pool.poll():
            if r.job == job.job:
                if not r.ok:
                    raise SystemExit(f"job failed: {r.error}")
                return 1e3 * (time.perf_counter() - t0), r.render_ms
        await ready.wait()
        ready.clear()


async def rounds(pools: dict, load: LoadArgs, jobs: int, warm: int, rounds_n: int) -> dict:
    loop = asyncio.get_running_loop()
    events = {}
    for name, pool in pools.items():
        start = getattr(pool, "start", None)
        if start is not None:
            start(loop)
        ev = events[name] = asyncio.Event()
        loop.add_reader(pool.fileno(), ev.set)
    for pool in pools.values():
        while not pool.workers():
            await asyncio.sleep(0.02)
    eye = (0.0, -900.0, 500.0)
    views = [WireViewpoint(**look_at((eye[0] + 3.0 * k, eye[1], eye[2]),
                                     (0.0, 0.0, 0.0)).to_dict()) for k in range(jobs)]
    out = {name: {"round_ms": [], "render_ms": []} for name in pools}
    ids = iter(range(1, 10**9))
    for name, pool in pools.items():  # the same warm-up: the scene loaded, code paths hot
        for k in range(warm):
            await one(pool, Job(next(ids), "w", load, views[k % jobs], 0.0), events[name])
    per = max(1, jobs // rounds_n)
    for r in range(rounds_n):  # alternate, so a change of the machine's load hits both
        for name, pool in pools.items():
            for k in range(per):
                rt, render = await one(pool, Job(next(ids), "b", load, views[(r * per + k)
                                                                            % jobs], 0.0),
                                       events[name])
                out[name]["round_ms"].append(rt)
                out[name]["render_ms"].append(render)
    for pool in pools.values():
        loop.remove_reader(pool.fileno())
    return out


def summary(got: dict) -> dict:
    rt, render = np.asarray(got["round_ms"]), np.asarray(got["render_ms"])
    over = rt - render
    return {"jobs": len(rt), "overhead_ms_p50": float(np.median(over)),
            "overhead_ms_p90": float(np.percentile(over, 90)),
            "round_ms_p50": float(np.median(rt)), "render_ms_p50": float(np.median(render))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=200)
    ap.add_argument("--warm", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--size", type=int, default=256, help="keyframe side, px")
    ap.add_argument("--terrain", default="fractal:256")
    args = ap.parse_args()
    import ray

    from lodsprite.distributed.pool.ray_pool import INLINE_BYTES, RayPool

    load = LoadArgs(terrain=args.terrain, size=(args.size, args.size), lod=32)
    got = {}
    for inline in (True, False):
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 _system_config={"max_direct_call_object_size": INLINE_BYTES} if inline
                 else {})
        pools = {"ray" if inline else "ray_object_store": RayPool("auto", 1)}
        if inline:
            pools = {"local": LocalPool(), **pools}
            pools["local"].spawn_local(1)
        try:
            got.update(asyncio.run(rounds(pools, load, args.jobs, args.warm, args.rounds)))
        finally:
            for pool in pools.values():
                pool.close()
            ray.shutdown()
    results = {name: summary(g) for name, g in got.items()}
    print(json.dumps({"terrain": args.terrain, "size": args.size, **results}, indent=1))


if __name__ == "__main__":
    main()
