"""Keyframes as a page's renderers draw them: a terrain (a store, a large in-memory grid,
a small one) through the local render pool (``LocalPool``, N renderer processes), jobs
along a path as pages would send them, and the two ways a keyframe can be drawn side by
side on the same jobs: ``adaptive`` (what the pool draws now over a store or a grid above
1024 quads a side) and ``whole`` (the working grid drawn whole at full resolution, what
it drew before), each judged against the band-limited level 0 of the keyframe's view.

Per way: the first keyframe's time after the job was submitted (the scene loaded, its
view's tiles fetched), then keyframes a second per renderer with ``--renderers`` jobs
always in flight (``--jobs`` jobs along ``--path``), the dispatch-to-answer median, and
the keyframes' RMSE against the reference on every ``--judge``-th job (untimed, after the
timed run).  The ways run one after the other in fresh pools, the same warm-up (one job)
before each.

    python benchmarks/served_keyframes.py --terrain /tmp/f16k.zarr --size 640x480 \\
        --renderers 2 --jobs 40 [--ways adaptive whole] [--out DIR]

Writes ``served.json`` to ``--out`` (default a temporary folder) and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from lodsprite.distributed.pool import Job, LocalPool
from lodsprite.distributed.protocol import LoadArgs, WireViewpoint, decode_keyframe


def wait(pool: LocalPool, want: set[int], deadline_s: float) -> dict:
    """The results of the jobs ``want`` (job id: (result, answered at perf_counter))."""
    got: dict = {}
    end = time.monotonic() + deadline_s
    while want - set(got):
        if time.monotonic() > end:
            raise SystemExit(f"no answer to jobs {sorted(want - set(got))} in {deadline_s} s")
        for r in pool.poll():
            got[r.job] = (r, time.perf_counter())
        time.sleep(0.002)
    return got


def run_way(way: str, load: LoadArgs, views: list, renderers: int, deadline_s: float,
            data_dir: Path | None) -> dict:
    """One way's timed run in a fresh pool serving ``data_dir``; its keyframes kept for
    judging."""
    with LocalPool(data_dir=data_dir, keyframes=way) as pool:
        pool.spawn_local(renderers)
        if not pool.wait_workers(renderers, 120.0):
            raise SystemExit("the renderers did not start")
        t0 = time.perf_counter()
        pool.submit(Job(1, "s", load, views[0], 0.0))
        first = wait(pool, {1}, deadline_s)[1]
        if not first[0].ok:
            raise SystemExit(f"{way}: {first[0].error}")
        first_s = first[1] - t0
        sent: dict[int, float] = {}
        answers: dict = {}
        ids = list(range(2, 2 + len(views)))
        start = time.perf_counter()
        nxt = 0
        while len(answers) < len(ids):
            while nxt < len(ids) and len(sent) - len(answers) < renderers:
                jid = ids[nxt]
                sent[jid] = time.perf_counter()  # before: the pool's thread may start it
                pool.submit(Job(jid, "s", load, views[nxt], 0.0))
                nxt += 1
            for r in pool.poll():
                answers[r.job] = (r, time.perf_counter())
            time.sleep(0.001)
        took = time.perf_counter() - start
    failed = [r.error for r, _ in answers.values() if not r.ok]
    if failed:
        raise SystemExit(f"{way}: {failed[0]}")
    latency = [1e3 * (answers[j][1] - sent[j]) for j in ids]
    return {"first_keyframe_s": first_s, "keyframes_per_s_per_renderer":
            len(ids) / took / renderers, "latency_ms_p50": float(np.median(latency)),
            "render_ms_p50": float(np.median([answers[j][0].render_ms for j in ids])),
            "_keyframes": [decode_keyframe(answers[j][0].parts) for j in ids]}


def judge(terrain: str, keyframes: list, stride: int) -> float:
    """Mean RMSE of every ``stride``-th keyframe against the band-limited level 0 of its
    own view and projection (untimed)."""
    from lodsprite.gl.context import GLContext
    from lodsprite.harness import level_zero_reference
    from lodsprite.scene.model import load_scene

    gl = GLContext()
    kf0 = keyframes[0]
    h, w = kf0.color.shape[:2]
    scene = load_scene(terrain, light=True)
    ref = level_zero_reference(gl, scene, (w, h), kf0.projection.fov_y_deg, "auto")
    try:
        errs = []
        for kf in keyframes[::stride]:
            truth = ref.image(kf.viewpoint, kf.projection).astype(float)
            errs.append(float(np.sqrt(np.mean((kf.color.astype(float) - truth) ** 2))))
        return float(np.mean(errs))
    finally:
        ref.release()
        gl.release()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", required=True)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--path", default="chen1999")
    ap.add_argument("--renderers", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=40)
    ap.add_argument("--judge", type=int, default=4, help="judge every K-th keyframe")
    ap.add_argument("--ways", nargs="+", default=["adaptive", "whole"],
                    choices=["adaptive", "whole"])
    ap.add_argument("--deadline", type=float, default=600.0, help="s, against a hang")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    from lodsprite.paths import get_path
    from lodsprite.scene.model import load_scene

    w, h = (int(v) for v in args.size.split("x"))
    scene = load_scene(args.terrain, light=True, textured=False)
    path = get_path(args.path, scene.hf, args.jobs + 1)
    views = [WireViewpoint(**vp.to_dict()) for vp in path.viewpoints]
    file = Path(args.terrain).expanduser()
    data_dir, name = (file.parent, file.name) if file.exists() else (None, args.terrain)
    load = LoadArgs(terrain=name, size=(w, h), lod=16, pace="continuous")
    out = args.out or Path(tempfile.mkdtemp(prefix="served-"))
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for way in args.ways:
        r = run_way(way, load, views, args.renderers, args.deadline, data_dir)
        keyframes = r.pop("_keyframes")
        r["rmse_mean"] = judge(args.terrain, keyframes, args.judge)
        results[way] = r
        print(f"{way:9s} first keyframe {r['first_keyframe_s']:6.2f} s  "
              f"{r['keyframes_per_s_per_renderer']:5.2f} keyframes/s a renderer  "
              f"latency p50 {r['latency_ms_p50']:7.1f} ms  render p50 "
              f"{r['render_ms_p50']:7.1f} ms  RMSE {r['rmse_mean']:5.2f}", flush=True)
    doc = {"terrain": args.terrain, "size": [w, h], "path": args.path,
           "renderers": args.renderers, "jobs": args.jobs, **results}
    (out / "served.json").write_text(json.dumps(doc, indent=1))
    print(f"written: {out / 'served.json'}")


if __name__ == "__main__":
    main()
