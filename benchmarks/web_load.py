"""Many web clients on one server: N simulated pages against ``lodsprite serve --web``
with R renderer processes (issue 24, "16 clients on 2 renderers").

The server runs as its own process (``lodsprite serve --web``), so its CPU time and its
renderers' are measured apart from the clients' (psutil, over the process tree, from
the first load to the end).  The N clients share this process's asyncio loop, each on
its own WebSocket (aiohttp) and its own path (the built-in paths in turn, each started
at its own phase), and each runs the page's logic (``static/predictor.js``; its Python
side is :mod:`lodsprite.distributed.web.estimate`): the linear predictor asks for the
viewpoint one measured keyframe latency ahead once the shown keyframe's error there
reaches ε/2, never with a request in flight.  A frame is shown every 1/fps s of the
clock; a loop that falls behind (a loaded machine) skips frames, so the flight keeps its
speed.  The error of every frame shown is measured after the run (no CPU taken from the
server while it plays): the page's estimate (Chen et al. 1999, Eq. 1-2, ``C'`` cast on
the coarse mesh) and lodsprite's own metric (:mod:`lodsprite.sprite.metric`: the
full-resolution centres).

Writes ``DIR/results.json``: ``keyframes_per_client`` (list), ``most_over_least``,
``latency_ms_p50``, ``latency_ms_p99`` (request sent to keyframe received),
``error_px_mean`` (the page's estimate, over frames that showed a keyframe),
``error_px_exact_mean`` (lodsprite's metric over the same frames),
``error_px_mean_by_path`` (both, per path), ``server_cpu_s``, the render capacity
(``keyframes_per_s`` served, the pool's ``job_ms_p50``/``job_ms_p90`` dispatch to
answer, ``renderer_busy``: the fraction of the play time the renderers rendered),
``play_s``, ``frames_shown``, the dispatch overhead per keyframe (``overhead_ms_p50``/
``overhead_ms_p90``: a job's dispatch to answer less the renderer's own time on it, the
pool's figure) and the set-up.

With ``--ray`` the same load runs twice in one invocation, on the local pool and then on
Ray actors (the server started with ``--ray local``: a Ray instance of this machine's
cores, started by the server), and ``results.json`` holds both (``local``, ``ray``).
``--kill-renderer-at S`` kills a renderer (SIGKILL, one rendering if any: a local pool's
renderer process, a Ray actor) S seconds into each run's play: ``killed_renderer``,
``latency_ms_max`` (what the kill cost the request it held) and the pool's ``pool_dead``,
``pool_requeued`` and ``pool_failed`` over the play say what became of its job.

    python benchmarks/web_load.py --clients 16 --renderers 2 --out out/web_load
    python benchmarks/web_load.py --clients 16 --renderers 2 --ray --out out/web_load_ray
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.distributed.web.estimate import ErrorMetric, Predictor
from lodsprite.paths import get_path
from lodsprite.scene import load_scene
from lodsprite.sprite.metric import ErrorMetric as ExactMetric

PATHS = ("chen1999", "swan2002", "flyover", "patrol", "bank")
_CAST: ErrorMetric | None = None  # in a cast process: the scene's estimate


def _cast_init(scene) -> None:
    global _CAST
    _CAST = ErrorMetric(scene)


def _cast(eye: np.ndarray):
    """``C'`` of a keyframe eye, in a cast process (a page casts it in its own thread
    in a millisecond or two; numpy here takes longer, and 16 pages in one event loop
    would fall behind their frames)."""
    return _CAST.reproject(eye)


async def client(i: int, url: str, token: str, load: dict, path: list[Viewpoint],
                 fps: float, start: asyncio.Event, ready: asyncio.Semaphore,
                 casts: dict) -> dict:
    """One simulated page: loads, plays ``path`` at ``fps``; its keyframes, latencies and
    per-frame errors."""
    import aiohttp

    from lodsprite.distributed.web.client import connect

    async with aiohttp.ClientSession() as http:
        page = await connect(http, url, token)
        scene = await page.load(load)
        metric, pred = ErrorMetric(scene), Predictor(scene, page.jobs)
        if "pool" not in casts:  # the pages load one scene: one pool casts for all
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            casts["pool"] = ProcessPoolExecutor(1, mp.get_context("spawn"),
                                                initializer=_cast_init, initargs=(scene,))
        loop = asyncio.get_running_loop()
        phase = (i * len(path)) // 7 % len(path)
        # Warm-up, untimed: the renderers load the scene (each keeps it) before the clock.
        try:
            first = await asyncio.wait_for(page.keyframe(path[phase].to_dict(), 0.0), 300.0)
        finally:
            ready.release()  # also on failure: gather() then reports it
        await start.wait()
        clock0 = time.monotonic()
        state = {"eye": first.viewpoint.o, "keyframes": 0, "latencies": [], "t0": -np.inf}
        metric.keep(await loop.run_in_executor(casts["pool"], _cast, state["eye"]))

        async def reader() -> None:
            while True:
                header, parts = await page.recv()
                if header.__struct_config__.tag != "keyframe":
                    continue
                now = time.monotonic() - clock0
                if header.t0 < state["t0"]:  # came after a newer one: not shown
                    pred.dropped(header.t0)
                    continue
                state["t0"] = header.t0
                state["keyframes"] += 1
                state["latencies"].append(1000.0 * (now - header.t0))
                eye = state["eye"] = np.array(header.viewpoint.o, np.float64)
                pred.arrived(header.t0, now)
                rep = await loop.run_in_executor(casts["pool"], _cast, eye)
                if state["eye"] is eye:
                    metric.keep(rep)  # what want() measures with, once it is cast

        task = asyncio.create_task(reader())
        shown = []  # (frame, the shown keyframe's eye)
        k = 0
        try:
            while k < len(path):
                await asyncio.sleep(max(0.0, clock0 + k / fps - time.monotonic()))
                t = time.monotonic() - clock0
                k = max(k, int(t * fps))  # a late loop skips frames: the flight keeps
                if k >= len(path):        # its speed whatever this machine's load
                    break
                vp = path[(k + phase) % len(path)]
                pred.sample(t, vp)
                shown.append((k, state["eye"]))  # its error is measured after the run
                k += 1
                want = pred.want(metric, state["eye"], t) if metric.cached(state["eye"]) else None
                if want is not None:
                    pred.sent(t)
                    await page.request(want.to_dict(), t)
        finally:
            task.cancel()
            await page.close()
    return {"keyframes": state["keyframes"], "latencies_ms": state["latencies"],
            "shown_eyes": shown, "phase": phase, "metric": metric, "pred": pred,
            "beta": pred.beta, "proj": pred.proj}


def estimates(got: dict, path: list[Viewpoint]) -> np.ndarray:
    """The page's estimate (what its HUD shows) of every frame a client showed, px."""
    pred, metric = got["pred"], got["metric"]
    return np.asarray([pred.error_px(metric, eye, path[(k + got["phase"]) % len(path)])
                       for k, eye in got["shown_eyes"]], np.float64)


def exact_errors(got: dict, path: list[Viewpoint], exact: ExactMetric) -> np.ndarray:
    """lodsprite's own metric (:mod:`lodsprite.sprite.metric`: the full-resolution
    centres, ``C'`` cast on the coarse level) of every frame a client showed, px."""
    out, rep, last = [], None, None
    for k, eye in got["shown_eyes"]:
        if last is None or not np.array_equal(eye, last):
            rep, last = exact.reproject(eye), eye
        vp = path[(k + got["phase"]) % len(path)]
        out.append(exact.error_px(rep, vp.o, got["proj"] @ vp.view_matrix(), got["beta"]))
    return np.asarray(out, np.float64)


async def pool_stats(url: str, token: str) -> dict:
    """The render pool's figures (the ``stats`` op's ``server.pool``) over a WebSocket
    of its own."""
    import aiohttp

    from lodsprite.distributed.web.client import connect

    async with aiohttp.ClientSession() as http:
        page = await connect(http, url, token)
        try:
            return (await page.stats())["server"]["pool"]
        finally:
            await page.close()


async def kill_renderer(server_pid: int, at_s: float, pool: str = "ray") -> dict | None:
    """SIGKILL one renderer of the server's process tree ``at_s`` seconds into the play,
    one holding a job if there is one: a Ray actor (its process title
    ``ray::RenderActor.render`` while it renders), or one of the local pool's renderer
    processes (the server's ``multiprocessing`` spawned children; the one that took the most CPU
    over 50 ms: the one rendering); its pid and whether it was rendering (None: none
    found)."""
    import psutil

    from lodsprite.distributed.pool.ray_actor import RenderActor

    await asyncio.sleep(at_s)
    if pool == "local":
        found = [p for p in psutil.Process(server_pid).children(recursive=True)
                 if "spawn_main" in _cmdline(p)]  # not the resource tracker
        if not found:
            return None
        for p in found:
            p.cpu_percent(None)
        await asyncio.sleep(0.05)
        usage = {p.pid: p.cpu_percent(None) for p in found}
        victim = max(found, key=lambda p: usage[p.pid])
        victim.kill()
        return {"pid": victim.pid, "rendering": usage[victim.pid] > 20.0, "at_s": at_s,
                "cpu_percent": usage[victim.pid]}
    title = f"ray::{RenderActor.__name__}"  # Ray names an actor's process by its class
    deadline = time.monotonic() + 2.0
    while True:
        found = [(p, cmd) for p in psutil.Process(server_pid).children(recursive=True)
                 for cmd in [_cmdline(p)] if cmd.startswith(title)]
        busy = [p for p, cmd in found if ".render" in cmd]
        if busy or (found and time.monotonic() > deadline):
            victim = (busy or [p for p, _ in found])[0]
            victim.kill()
            return {"pid": victim.pid, "rendering": bool(busy), "at_s": at_s}
        if not found and time.monotonic() > deadline:
            return None
        await asyncio.sleep(0.002)


def _cmdline(p) -> str:
    try:
        return " ".join(p.cmdline())
    except Exception:  # noqa: BLE001 - psutil: gone, or not ours to read
        return ""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(renderers: int, token: str, extra: list[str] = ()) -> tuple:
    """``lodsprite serve --web`` as a process; (Popen, page URL)."""
    port, zport = free_port(), free_port()
    cmd = [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve",
           "--bind", f"127.0.0.1:{zport}", "--web", f"127.0.0.1:{port}", "--renderers",
           str(renderers), "--token", token, *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc, url
        except OSError:
            if proc.poll() is not None:
                raise SystemExit(f"the server exited with {proc.returncode}") from None
            time.sleep(0.1)
    proc.kill()
    raise SystemExit("the server did not start within 60 s")


def stop(proc: subprocess.Popen) -> None:
    """SIGTERM, then SIGKILL after 30 s (the server waits for open WebSockets)."""
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)


def tree_cpu_s(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its live descendants (psutil, else
    /proc of the process itself and its reaped children)."""
    try:
        import psutil
    except ImportError:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rpartition(")")[2].split()
        return sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")
    p = psutil.Process(pid)
    procs = [p, *p.children(recursive=True)]
    total = 0.0
    for q in procs:
        try:
            c = q.cpu_times()
            total += c.user + c.system
        except psutil.Error:
            pass
    return total


def pages_cpu_s(server_pid: int) -> float | None:
    """CPU seconds of the simulated pages: this process and its children other than
    the server's tree (the cast process); None without psutil."""
    try:
        import psutil
    except ImportError:
        return None
    me = psutil.Process()
    total = sum(me.cpu_times()[:2])
    for q in me.children():
        if q.pid != server_pid:
            try:
                total += sum(q.cpu_times()[:2])
            except psutil.Error:
                pass
    return total


async def run(args, pool: str = "local") -> dict:
    token = secrets.token_urlsafe(16)
    proc, url = start_server(args.renderers, token, ["--ray", "local"] if pool == "ray" else [])
    hf = load_scene(args.terrain, "terrain", None, 1.0).hf
    paths = {spec: list(get_path(spec, hf, args.frames).viewpoints)
             for spec in PATHS[:args.clients]}
    load = {"terrain": args.terrain, "size": [args.size, args.size], "lod": args.lod,
            "epsilon": args.epsilon}
    try:
        start, ready, casts = asyncio.Event(), asyncio.Semaphore(0), {}
        tasks = [asyncio.create_task(client(i, url, token, load, paths[PATHS[i % len(PATHS)]],
                                            args.fps, start, ready, casts))
                 for i in range(args.clients)]
        for _ in tasks:  # every page loaded and warmed up
            await asyncio.wait_for(ready.acquire(), 600.0)
        cpu0, pool0 = tree_cpu_s(proc.pid), await pool_stats(url, token)
        own0 = pages_cpu_s(proc.pid)
        t0 = time.monotonic()
        start.set()
        killer = (asyncio.create_task(kill_renderer(proc.pid, args.kill_renderer_at, pool))
                  if args.kill_renderer_at is not None else None)
        got = await asyncio.gather(*tasks)
        killed = await killer if killer is not None else None
        wall = time.monotonic() - t0
        own = pages_cpu_s(proc.pid) - own0
        cpu, pool1 = tree_cpu_s(proc.pid) - cpu0, await pool_stats(url, token)
    finally:
        stop(proc)
        if "pool" in casts:
            casts["pool"].shutdown()
    for i, g in enumerate(got):  # measured after the run: no CPU taken from the server
        g["errors_px"] = estimates(g, paths[PATHS[i % len(PATHS)]])
    lat = np.concatenate([g["latencies_ms"] for g in got]) if got else np.zeros(0)
    err = np.concatenate([g["errors_px"] for g in got])
    shown = err[np.isfinite(err)]
    per = [g["keyframes"] for g in got]
    exact = ExactMetric.for_level(hf, args.lod)
    ex = [exact_errors(g, paths[PATHS[i % len(PATHS)]], exact) for i, g in enumerate(got)]
    exact_all = np.concatenate(ex)
    by_path = {}
    for i, g in enumerate(got):
        e = np.asarray(g["errors_px"], np.float64)
        by_path.setdefault(PATHS[i % len(PATHS)], []).append((e[np.isfinite(e)],
                                                              ex[i][np.isfinite(ex[i])]))
    return {"pool": pool, "clients": args.clients, "renderers": args.renderers,
            "terrain": args.terrain,
            "size": args.size, "lod": args.lod, "epsilon": args.epsilon,
            "frames": args.frames, "fps": args.fps, "keyframes_per_client": per,
            "most_over_least": max(per) / max(1, min(per)),
            "latency_ms_p50": float(np.percentile(lat, 50)) if len(lat) else None,
            "latency_ms_p99": float(np.percentile(lat, 99)) if len(lat) else None,
            "latency_ms_max": float(lat.max()) if len(lat) else None,
            "error_px_mean": float(shown.mean()) if len(shown) else None,
            "frames_without_estimate": int((~np.isfinite(err)).sum()),
            "error_px_exact_mean": _finite_mean(exact_all),
            "error_px_mean_by_path": {
                k: {"estimate": _finite_mean(np.concatenate([a for a, _ in v])),
                    "exact": _finite_mean(np.concatenate([b for _, b in v]))}
                for k, v in by_path.items()},
            "server_cpu_s": cpu, "pages_cpu_s": own,
            # the render capacity (the pool's own measure): keyframes served a second,
            # a job's dispatch-to-answer time, and how busy the renderers were
            "play_s": wall, "keyframes_per_s": sum(per) / wall,
            "frames_shown": sum(len(g["shown_eyes"]) for g in got),
            "job_ms_p50": pool1.get("job_ms_p50"), "job_ms_p90": pool1.get("job_ms_p90"),
            "overhead_ms_p50": pool1.get("overhead_ms_p50"),
            "overhead_ms_p90": pool1.get("overhead_ms_p90"),
            "renderer_busy": (pool1["busy_s"] - pool0["busy_s"]) / (args.renderers * wall)
            if "busy_s" in pool1 else None,
            # --kill-renderer-at: the renderer killed, and what the pool did about it
            "killed_renderer": killed,
            **{f"pool_{k}": pool1[k] - pool0[k] for k in ("dead", "requeued", "failed")
               if k in pool1}}


def _finite_mean(a: np.ndarray) -> float | None:
    a = a[np.isfinite(a)]
    return float(a.mean()) if len(a) else None


def scene_options(ap: argparse.ArgumentParser) -> None:
    """The scene and flight options (also ``web_predictor.py``'s)."""
    ap.add_argument("--terrain", default="fractal:256")
    ap.add_argument("--size", type=int, default=256, help="keyframe side, px")
    ap.add_argument("--lod", type=int, default=32)
    ap.add_argument("--epsilon", type=float, default=2.0)
    ap.add_argument("--frames", type=int, default=300, help="frames of each path")
    ap.add_argument("--fps", type=float, default=30.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=16)
    ap.add_argument("--renderers", type=int, default=2)
    scene_options(ap)
    ap.add_argument("--ray", action="store_true",
                    help="also run the load on Ray actors (the server's --ray local), after "
                         "the local pool")
    ap.add_argument("--kill-renderer-at", type=float, default=None, metavar="S",
                    help="with --ray: SIGKILL a renderer actor S seconds into the play "
                         "(Ray restarts it; its job goes to another)")
    ap.add_argument("--out", type=Path, default=Path("out/web_load"))
    args = ap.parse_args()
    runs = {pool: asyncio.run(run(args, pool)) for pool in (
        ("local", "ray") if args.ray else ("local",))}
    args.out.mkdir(parents=True, exist_ok=True)
    results = runs if args.ray else runs["local"]
    (args.out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    for r in runs.values():
        print(json.dumps({k: v for k, v in r.items() if k != "keyframes_per_client"}))
        print(f"{r['pool']}: keyframes per client:", r["keyframes_per_client"])


if __name__ == "__main__":
    main()
