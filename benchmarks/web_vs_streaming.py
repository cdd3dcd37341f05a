"""The browser LOD-sprite client against remote image streaming, over emulated links.

Two ways to show a path in a browser (Debian's chromium, headless, SwiftShader WebGL2,
driven by selenium through the system chromedriver):

* ``sprite``: the lodsprite page (``lodsprite serve --web``) draws every display frame
  itself from the coarse level and the last keyframe, and asks for keyframes ahead;
* ``stream``: the remote view of trame / Pixel Streaming: the page sends each frame's
  viewpoint, the server renders the newest one at full resolution with lodsprite's real
  renderer (:class:`~lodsprite.distributed.render.KeyframeService`) and sends a JPEG,
  which the page draws (``--role stream``: a small aiohttp server in this file).

Links: two network namespaces joined by a veth pair, rate-limited with tbf
(:mod:`lodsprite.distributed.netns`: 10 or 100 Mbit/s).  The kernel here has no netem,
so the round trip is added by a user-space delay proxy in the client namespace that
holds every chunk RTT/2 in each direction (TCP then sees the proxy's short hop, not
the RTT: its window grows faster than on a real long link).  Without root (or ``ip
netns``) the links are skipped with the reason and both run over loopback through the
proxy.  Per link and mode: frame interval median and p99 (ms between frames shown),
bytes/s received, in an untimed replay the image error (RMSE, grey levels) of sampled
shown frames against the full-resolution render of the viewpoint the viewer is at, and
input-to-frame latency, measured alike for both: after the path, ``--presses`` real key
presses (selenium's, trusted events), each from its event's timestamp to the display
frame (``requestAnimationFrame``) after the first frame drawn from a camera that
includes it: the page moves its flying camera and draws it on its next frame; streaming
sends the moved viewpoint at once and draws the image rendered from it on arrival.
``viewpoint_to_image_ms`` is streaming's viewpoint sent to its image drawn during the
path (the figure published as its input-to-frame latency before).

    sudo python benchmarks/web_vs_streaming.py [--links 0:100,50:100,150:100,0:10,...]
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
TOKEN = "web-vs-streaming"
WEB_PORT, STREAM_PORT, ZMQ_PORT = 8080, 8081, 5555
HERE = Path(__file__).resolve()
STREAM_PAGE = Path(__file__).with_name("web_stream_page.html")


# ------------------------------------------------------------------ the delay proxy

class DelayProxy:
    """TCP ``listen`` -> ``target`` holding every chunk ``delay_s`` each way; counts the
    bytes the server sends (``down``)."""

    def __init__(self, port: int, target: tuple[str, int], delay_s: float) -> None:
        self.port, self.target, self.delay_s, self.down = port, target, delay_s, 0

    async def start(self) -> None:
        await asyncio.start_server(self._serve, "127.0.0.1", self.port)

    async def _serve(self, reader, writer) -> None:
        try:
            up_r, up_w = await asyncio.open_connection(*self.target)
        except OSError:
            writer.close()
            return
        await asyncio.gather(self._pump(reader, up_w, False), self._pump(up_r, writer, True),
                             return_exceptions=True)

    async def _pump(self, reader, writer, down: bool) -> None:
        q: asyncio.Queue = asyncio.Queue()

        async def send() -> None:
            while (item := await q.get()) is not None:
                due, data = item
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                writer.write(data)
                await writer.drain()
            writer.close()

        task = asyncio.create_task(send())
        while data := await reader.read(65536):
            if down:
                self.down += len(data)
            q.put_nowait((time.monotonic() + self.delay_s, data))
        q.put_nowait(None)
        await task


# ------------------------------------------------------------------ stream server

def stream_server(args) -> None:
    """The streaming baseline's server: renders the newest viewpoint, sends a JPEG."""
    import io
    from concurrent.futures import ThreadPoolExecutor

    from aiohttp import web
    from PIL import Image

    from lodsprite.distributed.protocol import LoadArgs, viewpoint_from_wire
    from lodsprite.distributed.render import KeyframeService
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene

    hf = load_scene(args.terrain, "terrain", None, 1.0).hf
    path = [vp.to_dict() for vp in get_path(args.path, hf, args.frames).viewpoints]
    gl = ThreadPoolExecutor(1)  # the GL context lives on one thread
    r = gl.submit(KeyframeService, LoadArgs(terrain=args.terrain, size=(args.size,) * 2,
                                            lod=args.lod)).result()

    def render(vp: dict) -> bytes:
        kf = r.render(viewpoint_from_wire(vp), 0, 0.0)
        out = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(kf.color)).save(out, "JPEG", quality=85)
        return out.getvalue()

    async def page(_):
        return web.Response(text=STREAM_PAGE.read_text(), content_type="text/html")

    async def path_json(_):
        return web.json_response(path)

    async def ws_handler(request):
        ws = web.WebSocketResponse()
        await ws.prepare(request)
        latest, wake = [None], asyncio.Event()

        async def renderer() -> None:
            loop = asyncio.get_running_loop()
            while True:
                await wake.wait()
                wake.clear()
                k, vp = latest[0]
                jpeg = await loop.run_in_executor(gl, render, vp)
                await ws.send_bytes(int(k).to_bytes(4, "little") + jpeg)

        task = asyncio.create_task(renderer())
        async for msg in ws:
            m = json.loads(msg.data)
            latest[0] = (m["k"], m["vp"])
            wake.set()
        task.cancel()
        return ws

    app = web.Application()
    app.router.add_get("/", page)
    app.router.add_get("/path", path_json)
    app.router.add_get("/ws", ws_handler)
    web.run_app(app, host=args.host, port=args.port, print=None)


# ------------------------------------------------------------------ the client side

WAIT_JS = """const done = arguments[arguments.length - 1];
const get = () => window.lodsprite || window.stream;
const go = () => get() ? get().%s.then(() => done(true), (e) => done(String(e)))
                       : setTimeout(go, 20);
go();"""
SAMPLE_JS = {
    "sprite": "const l = window.lodsprite; return {k: l.pathIndex() - 1, "
              "p: l.pixels(), flip: true};",
    "stream": "return window.stream.sample();",
}


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    profile = tempfile.mkdtemp(prefix="lodsprite-chromium-")
    for arg in ("--headless=new", "--no-sandbox", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--disable-background-networking",
                "--no-first-run", f"--user-data-dir={profile}"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    driver.set_script_timeout(120)
    return driver, profile


def wait_port(host: str, port: int, timeout_s: float = 90.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise SystemExit(f"nothing listens on {host}:{port}") from None
            time.sleep(0.2)


def play(driver, url: str, mode: str, proxy: DelayProxy, samples: int, frames: int) -> dict:
    """One run of ``mode``: timed figures, or with ``samples`` the shown frames sampled."""
    driver.get(url)
    assert driver.execute_async_script(WAIT_JS % "ready") is True
    b0, t0 = proxy.down, time.monotonic()
    shots = []
    for _ in range(samples):  # spread over the path's play (a frame each 1/60 s)
        time.sleep(frames / 60.0 / (samples + 1))
        shots.append(driver.execute_script(SAMPLE_JS[mode]))
    assert driver.execute_async_script(WAIT_JS % "finished") is True
    seconds = time.monotonic() - t0
    stats = driver.execute_script("return (window.lodsprite || window.stream).stats()")
    return {"stats": stats, "bytes_per_s": (proxy.down - b0) / seconds, "shots": shots}


def press(driver, presses: int, timeout_s: float = 60.0) -> dict:
    """``presses`` key presses ('w', held 0.2 s, 0.6 s apart) into the page after its
    path; its input-to-pixels figures once every press has been drawn (or the deadline:
    those drawn by then)."""
    from selenium.webdriver.common.action_chains import ActionChains

    stats = "return (window.lodsprite || window.stream).stats()"
    for _ in range(presses):
        ActionChains(driver).key_down("w").pause(0.2).key_up("w").perform()
        time.sleep(0.4)
    deadline = time.monotonic() + timeout_s
    while (s := driver.execute_script(stats))["inputs"] < presses:
        if time.monotonic() > deadline:
            break
        time.sleep(0.1)
    return s


def image_error(shots: list, reference) -> float | None:
    errs = []
    for s in shots:
        if s["k"] < 0:
            continue
        p = s["p"]
        img = np.frombuffer(base64.b64decode(p["rgba"]), np.uint8)
        img = img.reshape(p["height"], p["width"], 4)[..., :3].astype(np.float64)
        ref = reference(s["k"])
        ref = ref[::-1] if s.get("flip") else ref  # readPixels rows are bottom-up
        errs.append(np.sqrt(np.mean((img - ref) ** 2)))
    return float(np.mean(errs)) if errs else None


def client(args) -> None:
    from lodsprite.distributed.protocol import LoadArgs
    from lodsprite.distributed.render import KeyframeService
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene

    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True).start()
    delay = args.rtt_ms / 2000.0
    proxies = {"sprite": DelayProxy(18080, (args.server, WEB_PORT), delay),
               "stream": DelayProxy(18081, (args.server, STREAM_PORT), delay)}
    for p in proxies.values():
        asyncio.run_coroutine_threadsafe(p.start(), loop).result()
    for port in (WEB_PORT, STREAM_PORT):
        wait_port(args.server, port)
    q = (f"token={TOKEN}&terrain={args.terrain}&size={args.size}x{args.size}&lod={args.lod}"
         f"&epsilon={args.epsilon}&path={args.path}&frames={args.frames}")
    urls = {"sprite": f"http://127.0.0.1:18080/?{q}", "stream": "http://127.0.0.1:18081/"}
    hf = load_scene(args.terrain, "terrain", None, 1.0).hf
    path = get_path(args.path, hf, args.frames).viewpoints
    r = KeyframeService(LoadArgs(terrain=args.terrain, size=(args.size,) * 2, lod=args.lod))
    cache: dict[int, np.ndarray] = {}

    def reference(k: int) -> np.ndarray:  # top-down rows, as a canvas's getImageData
        if k not in cache:
            cache[k] = np.array(r.render(path[k], 0, 0.0).color, np.float64)
        return cache[k]

    driver, profile = browser()
    out = {}
    try:
        for mode in ("sprite", "stream"):
            # The sampled replay first: it also warms up (the renderer loads its scene).
            replay = play(driver, urls[mode], mode, proxies[mode], args.samples, args.frames)
            timed = play(driver, urls[mode], mode, proxies[mode], 0, args.frames)
            s, i = timed["stats"], press(driver, args.presses)
            out[mode] = {"frame_ms_median": s["median_ms"], "frame_ms_p99": s["p99_ms"],
                         "input_to_frame_ms": i["input_ms"],
                         "input_to_frame_ms_p99": i["input_ms_p99"], "inputs": i["inputs"],
                         "bytes_per_s": timed["bytes_per_s"],
                         "frames": s["frames"], "keyframes": s.get("keyframes"),
                         "keyframe_latency_ms": s["latency_ms"] if mode == "sprite" else None,
                         "viewpoint_to_image_ms": s["latency_ms"] if mode == "stream" else None,
                         "image_rmse": image_error(replay["shots"], reference)}
            if mode == "stream":  # the shown image against its own viewpoint: JPEG only
                own = [{**x, "k": x["shown"]} for x in replay["shots"]]
                out[mode]["image_rmse_own_view"] = image_error(own, reference)
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
        r.release()
    Path(args.json).write_text(json.dumps(out))


# ------------------------------------------------------------------ orchestration

def python(role: str, args, **extra) -> list[str]:
    cmd = [sys.executable, str(HERE), "--role", role, "--terrain", args.terrain, "--size",
           str(args.size), "--lod", str(args.lod), "--epsilon", str(args.epsilon), "--path",
           args.path, "--frames", str(args.frames), "--samples", str(args.samples),
           "--presses", str(args.presses)]
    for k, v in extra.items():
        cmd += [f"--{k.replace('_', '-')}", str(v)]
    return cmd


def web_server(host: str) -> list[str]:
    return [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve",
            "--bind", f"{host}:{ZMQ_PORT}", "--web", f"{host}:{WEB_PORT}", "--token", TOKEN,
            "--renderers", "1", "--rate", "100000", "--allow-remote"]


def one_link(args, rtt_ms: int, mbit: int | None, hosts) -> dict:
    """Servers in the server namespace (or here), the browser in the client one."""
    wrap_s = hosts.server if hosts else (lambda c: c)
    wrap_c = hosts.client if hosts else (lambda c: c)
    server_ip = "10.213.0.2" if hosts else "127.0.0.1"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    servers = [subprocess.Popen(wrap_s(c), env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
               for c in (web_server(server_ip), python("stream", args, host=server_ip,
                                                        port=STREAM_PORT))]
    out = Path(tempfile.mkdtemp(prefix="lodsprite-wvs-")) / "client.json"
    try:
        subprocess.run(wrap_c(python("client", args, server=server_ip, rtt_ms=rtt_ms,
                                     json=out)), env=env, check=True, timeout=900)
        got = json.loads(out.read_text())
    finally:
        for p in servers:
            p.terminate()
            p.wait(timeout=20)
        shutil.rmtree(out.parent, ignore_errors=True)
    return {"rtt_ms": rtt_ms, "mbit": mbit, **got}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", choices=("main", "stream", "client"), default="main")
    ap.add_argument("--links", default="0:100,50:100,150:100,0:10,50:10,150:10",
                    help="RTT_MS:MBIT, comma separated")
    ap.add_argument("--terrain", default="fractal:256")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--lod", type=int, default=32)
    ap.add_argument("--epsilon", type=float, default=2.0)
    ap.add_argument("--path", default="chen1999")
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--samples", type=int, default=6)
    ap.add_argument("--presses", type=int, default=10,
                    help="key presses timed input to pixels, per mode")
    ap.add_argument("--out", type=Path, default=Path("out/web_vs_streaming"))
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=STREAM_PORT)
    ap.add_argument("--server", default="127.0.0.1")
    ap.add_argument("--rtt-ms", type=float, default=0.0)
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    if args.role == "stream":
        return stream_server(args)
    if args.role == "client":
        return client(args)
    from lodsprite.distributed.netns import available, two_hosts

    why = available()
    links = [tuple(int(x) for x in spec.split(":")) for spec in args.links.split(",")]
    rows = []
    if why is not None:
        print(f"links skipped: {why}; both modes over loopback (RTT by the delay proxy, "
              "no rate limit)")
        links = [(rtt, None) for rtt in sorted({rtt for rtt, _ in links})]
    for rtt, mbit in links:
        if why is None:
            with two_hosts(f"{mbit}mbit") as hosts:
                rows.append(one_link(args, rtt, mbit, hosts))
        else:
            rows.append(one_link(args, rtt, mbit, None))
        print(json.dumps(rows[-1]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
