"""`lodsprite serve --web` as a user runs it (a subprocess on 127.0.0.1): token and Origin,
load -> scene and request -> keyframe decoded with the protocol, sessions that do not see
each other's scene, a stalled page that does not stall another, a live fuzz after which a
page still gets keyframes, and the ZeroMQ client's server in the same process."""

import asyncio
import json
import os
import queue
import socket
import struct
import subprocess
import sys
import threading
import time

import aiohttp
import numpy as np
import pytest
import zmq

from hostile import hostile_frames
from lodsprite.distributed.protocol import (
    ProtocolError,
    Reply,
    SceneMessage,
    decode_keyframe,
    decode_message,
    encode,
)
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.server import endpoints
from lodsprite.distributed.web.client import WebPage
from lodsprite.distributed.web.client import connect as web_connect
from lodsprite.distributed.web.wire import MAX_PAGE_MESSAGE, MAX_PARTS, pack
from lodsprite.scene import load_scene

TOKEN = "test-token"
DEADLINE_S = 30.0
LOAD = {"terrain": "fractal:64:1", "size": [64, 64], "lod": 8, "grid": 64}
VP = {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.6, 0.8], "z": [0.0, -0.8, 0.6],
      "o": [0.0, -1500.0, 1200.0]}


SESSION_JOBS = 2
"""The server's ``--session-jobs`` here (not the default: the load reply must carry it)."""


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("data")
    np.save(data / "hill.npy", load_scene("fractal:64:5", "terrain", 64, 1.0).hf.heights)
    (data.parent / "outside.off").write_text("OFF\n0 0 0\n")  # beside, not inside
    (data / "walk.toml").write_text('[terrain]\nsource = "hill.npy"\n[[objects]]\n'
                                    'mesh = "../outside.off"\nheight_m = 2.0\n')
    # hostile scene files: an absolute mesh, a symlink out, a glTF whose buffer lies out
    (data / "abs.toml").write_text('[terrain]\nsource = "hill.npy"\n[[objects]]\n'
                                   'mesh = "/etc/passwd"\nheight_m = 2.0\n')
    os.symlink(data.parent / "outside.off", data / "link.off")
    (data / "link.toml").write_text('[terrain]\nsource = "hill.npy"\n[[objects]]\n'
                                    'mesh = "link.off"\nheight_m = 2.0\n')
    (data / "ext.gltf").write_text(json.dumps({"asset": {"version": "2.0"},
                                               "buffers": [{"uri": "../secret.bin",
                                                            "byteLength": 4}]}))
    (data / "ext.toml").write_text('[terrain]\nsource = "hill.npy"\n[[objects]]\n'
                                   'mesh = "ext.gltf"\n')
    (data.parent / "secret.bin").write_bytes(b"\0" * 4)
    (data / "bad.npy").write_bytes(b"not a NumPy file")  # a scene file's broken terrain
    (data / "badterrain.toml").write_text('[terrain]\nsource = "bad.npy"\n')
    (data / "lf").mkdir()  # a light field's folder: a kind the page does not draw
    (data / "lf" / "lumigraph.json").write_text("{}")
    (data.parent / "out.toml").write_text('[terrain]\nsource = "fractal:64:1"\n')
    # a scene file the page draws: walkers over hill.npy among standing trees
    (data / "crowd.toml").write_text(
        '[terrain]\nsource = "hill.npy"\n[[objects]]\nmesh = "ogre"\nheight_m = 20.0\n'
        'count = 30\nwalk_mps = 5.0\n[[objects]]\nmesh = "tree"\nheight_m = 30.0\n'
        'count = 5\n')
    zport = free_ports()
    proc = subprocess.Popen(
        [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve",
         "--web", "127.0.0.1:0", "--bind", f"127.0.0.1:{zport}", "--token", TOKEN,
         "--rate", "100000", "--renderers", "1", "--data", str(data),
         "--session-jobs", str(SESSION_JOBS)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    try:
        line = lines.get(timeout=DEADLINE_S)
        assert line.startswith("web page: http://127.0.0.1:"), line
        port = int(line.split(":")[3].split("/")[0])
        yield {"port": port, "zmq": zport, "proc": proc}
    finally:
        proc.terminate()
        proc.wait(timeout=15)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, DEADLINE_S))


def ws_url(server, token=TOKEN) -> str:
    return f"http://127.0.0.1:{server['port']}/ws" + (f"?token={token}" if token else "")


async def connect(http, server, **kw) -> WebPage:
    return await web_connect(http, f"http://127.0.0.1:{server['port']}", TOKEN, **kw)


async def loaded(page: WebPage, args: dict):
    scene = await page.load(args)
    assert scene.header.seq == page.seq
    assert page.jobs == SESSION_JOBS  # the load reply says how many it may keep in flight
    return scene


async def keyframe(page: WebPage, t=1.25):
    kf = await page.keyframe(VP, t)
    assert kf.seq == page.seq and kf.t0 == t
    return kf


def test_token_origin_and_host_are_checked(server):
    async def go():
        base = f"http://127.0.0.1:{server['port']}"
        async with aiohttp.ClientSession() as http:
            statuses = []
            for url, headers in [(f"{base}/", {}), (f"{base}/?token=wrong", {}),
                                 (f"{base}/?token={TOKEN}", {}),
                                 (f"{base}/?token={TOKEN}", {"Host": "evil.example"}),
                                 (f"{base}/static/index.html", {})]:
                async with http.get(url, headers=headers) as r:
                    statuses.append(r.status)
            for token, headers in [(None, {}), ("wrong", {}),
                                   (TOKEN, {"Origin": "http://evil.example"}),
                                   (TOKEN, {"Origin": f"http://localhost:{server['port']}"}),
                                   (TOKEN, {"Host": "evil.example"})]:
                with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                    await http.ws_connect(ws_url(server, token), headers=headers)
                statuses.append(err.value.status)
            ws = await http.ws_connect(ws_url(server),
                                       headers={"Origin": f"http://127.0.0.1:{server['port']}"})
            await ws.close()
            return statuses

    assert run(go()) == [401, 401, 200, 421, 200, 403, 403, 403, 403, 421]


def test_the_page_s_query_options_are_the_techniques_declarations(server):
    from lodsprite.distributed.web.server import PAGE_OPTIONS

    async def go():
        async with aiohttp.ClientSession() as http:
            url = f"http://127.0.0.1:{server['port']}/options.json"
            async with http.get(url) as r:
                return r.status, await r.json()

    status, declared = run(go())
    assert status == 200 and [o["name"] for o in declared] == list(PAGE_OPTIONS)
    by = {o["name"]: o for o in declared}
    assert by["lod"]["default"] == 16 and by["epsilon"]["above"] and by["epsilon"]["min"] == 0
    assert set(by["visibility"]["choices"]) == {"coarse", "triangle", "fragment"}


def test_load_gives_the_scene_and_a_request_a_keyframe(server):
    async def go():
        async with aiohttp.ClientSession() as http:
            page = await connect(http, server)
            return await loaded(page, LOAD), await keyframe(page), await page.stats()

    scene, kf, stats = run(go())
    hf = load_scene("fractal:64:1", "terrain", 64, 1.0).hf
    assert isinstance(scene.header, SceneMessage) and scene.header.coarse == 8
    np.testing.assert_array_equal(scene.heights, hf.heights[::8, ::8][::-1])
    assert scene.header.origin == (-hf.width / 2, -hf.depth / 2)
    assert scene.texture.shape == (65, 65, 3)
    assert kf.color.shape == (64, 64, 3) and kf.depth.shape == (64, 64)
    assert kf.color.std() > 1.0 and 0.0 <= kf.depth.min() <= kf.depth.max() <= 1.0
    assert stats["session"]["keyframes_sent"] == 1 and stats["server"]["workers"] == 1
    # the scene the session loaded, by the name the page gave, and how its keyframes are drawn
    assert (stats["session"]["scene"], stats["session"]["keyframes"]) == ("fractal:64:1", "whole")
    assert stats["server"]["per_session"][0]["scene"] == "fractal:64:1"


def test_sessions_do_not_see_each_other_s_scene(server):
    other = {**LOAD, "terrain": "fractal:64:7"}

    async def go():
        async with aiohttp.ClientSession() as http:
            a, b = await connect(http, server), await connect(http, server)
            sa = await loaded(a, LOAD)
            ka1 = await keyframe(a)
            sb = await loaded(b, other)
            kb = await keyframe(b)
            return sa, sb, ka1, kb, await keyframe(a)

    sa, sb, ka1, kb, ka2 = run(go())
    assert not np.array_equal(sa.heights, sb.heights)
    np.testing.assert_array_equal(ka1.color, ka2.color)  # b's load left a's scene alone
    assert np.abs(ka1.color.astype(int) - kb.color.astype(int)).mean() > 1.0


def test_pages_name_files_by_the_data_rule(server):
    async def go():
        async with aiohttp.ClientSession() as http:
            page = await connect(http, server)
            refused = []
            for name in ("../hill.npy", "/etc/passwd", "missing.npy", "lf",
                         "crowd:100000000", "http://example.com/dem.tif", "walk.toml",
                         "abs.toml", "link.toml", "ext.toml", "../out.toml",
                         "badterrain.toml"):
                with pytest.raises(ProtocolError) as err:
                    await page.load({**LOAD, "terrain": name})
                refused.append(str(err.value))
            return refused, await loaded(page, {**LOAD, "terrain": "hill.npy"}), \
                await keyframe(page)

    refused, scene, kf = run(go())
    assert all(r.startswith("load:") and "\n" not in r for r in refused), refused
    assert not any("/tmp" in r or "pytest" in r for r in refused), refused  # no server path
    assert "a page draws terrains" in refused[3] and "a crowd of" in refused[4]
    assert "a URL is refused" in refused[5]
    assert "leads outside the data folder" in refused[6]  # the scene file's mesh
    assert "absolute paths are refused" in refused[7]
    assert "outside the data folder" in refused[8]  # the symlink's target
    assert "outside the data folder" in refused[9]  # the glTF's buffer
    assert "outside the data folder" in refused[10] or "'..'" in refused[10], refused[10]
    assert scene.heights.shape == (9, 9) and kf.color.std() > 1.0
    assert server["proc"].poll() is None  # still serving


def test_a_page_loads_a_scene_file_with_its_walkers_and_gets_its_static_layers(server):
    """A scene file over the wire: the scene message carries its walkers (the moving
    ones only), its keyframes the static layers with their full z-buffer, and the
    session's figures name the scene."""
    async def go():
        async with aiohttp.ClientSession() as http:
            page = await connect(http, server)
            scene = await loaded(page, {"terrain": "crowd.toml", "size": [64, 64],
                                        "lod": 8, "visibility": "fragment"})
            return scene, await keyframe(page), await page.stats()

    scene, kf, stats = run(go())
    w = scene.walkers
    assert w is not None and len(w["xy0"]) == 30 and set(w["type"].tolist()) == {0}
    assert [t["name"] for t in w["types"]] == ["ogre"]  # the trees stand: in the keyframe
    levels = w["types"][0]["levels"]
    assert len(levels) >= 2 and len(levels[0][1]) > len(levels[-1][1])  # finest first
    assert w["ground"].shape == (513, 513) and (w["speed"] == 5.0).all()  # the working grid
    assert kf.zbuffer == "full" and kf.depth.shape == (64, 64) and kf.color.std() > 1.0
    assert stats["session"]["scene"] == "crowd.toml"
    assert stats["session"]["keyframes"] == "scene"


def test_a_page_loads_a_crowd_as_its_world_on_the_ground(server):
    """``crowd:N`` over the wire: the crowd's flat ground in the scene message, every
    member among its walkers at speed 0 (the page draws them each frame), the keyframes
    the ground and the trees with their full z-buffer."""
    async def go():
        async with aiohttp.ClientSession() as http:
            page = await connect(http, server)
            scene = await loaded(page, {"terrain": "crowd:50:5", "size": [64, 64],
                                        "lod": 8})
            return scene, await keyframe(page), await page.stats()

    scene, kf, stats = run(go())
    w = scene.walkers
    assert w is not None and len(w["xy0"]) == 50 and (w["speed"] == 0).all()
    assert [t["name"] for t in w["types"]] == ["ogre"]  # the trees stand in the keyframes
    assert scene.heights.shape == (9, 9) and not scene.heights.any()  # flat
    assert kf.zbuffer == "full" and kf.color.std() > 1.0
    assert stats["session"]["scene"] == "crowd:50:5"


def stalled_page(port: int, stop: threading.Event) -> socket.socket:
    """A raw WebSocket client with a tiny receive buffer that loads a large keyframe size,
    asks for keyframes until ``stop`` and never reads."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.settimeout(DEADLINE_S)
    sock.connect(("127.0.0.1", port))
    sock.sendall((f"GET /ws?token={TOKEN} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                  "Upgrade: websocket\r\nConnection: Upgrade\r\n"
                  "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                  "Sec-WebSocket-Version: 13\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert head.startswith(b"HTTP/1.1 101"), head

    def frame(header: dict) -> bytes:
        payload = np.frombuffer(pack(encode(header)), np.uint8)
        mask = np.frombuffer(os.urandom(4), np.uint8)
        n = payload.size
        size = bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
        return b"\x82" + size + mask.tobytes() + (payload ^ np.resize(mask, n)).tobytes()

    sock.sendall(frame({"kind": "control", "seq": 1, "op": "load",
                        "args": {**LOAD, "size": [256, 256]}}))

    def ask():
        seq = 2
        while not stop.wait(0.01):
            try:
                sock.sendall(frame({"kind": "request", "seq": seq, "t": 0.0, "viewpoint": VP}))
            except OSError:  # closed by the test
                return
            seq += 1

    threading.Thread(target=ask, daemon=True).start()
    return sock


def test_a_page_that_stops_reading_does_not_stall_another(server):
    stop = threading.Event()
    stalled = stalled_page(server["port"], stop)

    async def go():
        async with aiohttp.ClientSession() as http:
            page = await connect(http, server)
            await loaded(page, LOAD)
            while True:  # until the stalled page's queue overflows (its writer is blocked)
                await keyframe(page)
                rows = (await page.stats())["server"]["per_session"]
                if any(r["keyframes_dropped"] > 0 for r in rows):
                    break
            return [await keyframe(page) for _ in range(3)], rows

    try:
        kfs, rows = run(go())
    finally:
        stop.set()
        stalled.close()
    assert len(kfs) == 3
    assert max(r["keyframes_dropped"] for r in rows) > 0


def test_a_live_fuzz_leaves_a_server_that_still_serves(server):
    rng = np.random.default_rng(24)

    async def go():
        async with aiohttp.ClientSession() as http:
            fuzzer = await connect(http, server)
            for i in range(3000):
                frames = hostile_frames("web", rng)
                data = pack(frames) if len(frames) <= MAX_PARTS else b"".join(frames)
                if i % 7 == 0:  # wire-level damage too
                    data = data[:int(rng.integers(0, len(data) + 1))] + rng.bytes(3)
                if len(data) <= MAX_PAGE_MESSAGE:  # larger ones close the connection: below
                    await fuzzer.ws.send_bytes(data)
            await fuzzer.ws.send_str("text frames are refused")
            stats = await fuzzer.stats()  # the fuzzing session itself still answers
            # (unread replies waited in the page's buffers and the session's bounded queue)
            big = await connect(http, server)  # over max_msg_size: that connection closes
            await big.ws.send_bytes(b"\x00" * (MAX_PAGE_MESSAGE + 1))
            closed = await big.ws.receive()
            page = await connect(http, server)
            await loaded(page, LOAD)
            return stats, closed, await keyframe(page)

    stats, closed, kf = run(go())
    assert stats["session"]["rejected"] > 1000 and stats["session"]["internal"] == 0
    assert closed.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
    assert kf.color.shape == (64, 64, 3) and server["proc"].poll() is None


def test_the_zeromq_client_s_server_runs_beside_it(server):
    ctl_ep, vp_ep, kf_ep = endpoints(f"127.0.0.1:{server['zmq']}", bind=False)
    client = "c" * 16
    ctx = zmq.Context()
    try:
        req, pub, dealer = ctx.socket(zmq.REQ), ctx.socket(zmq.PUB), ctx.socket(zmq.DEALER)
        dealer.setsockopt(zmq.IDENTITY, client.encode())
        for sock, ep in ((req, ctl_ep), (pub, vp_ep), (dealer, kf_ep)):
            sock.setsockopt(zmq.LINGER, 0)
            sock.connect(ep)
        for op, args in (("load", {**LOAD, "pace": "continuous"}), ("start", {})):
            req.send_multipart(encode({"kind": "control", "seq": 1, "op": op, "args": args,
                                       "client": client}))
            assert req.poll(DEADLINE_S * 1000), f"no reply to {op}"
            reply, _ = decode_message(req.recv_multipart())
            assert isinstance(reply, Reply) and reply.ok, reply
        deadline = time.monotonic() + DEADLINE_S
        while not dealer.poll(50):
            pub.send_multipart(encode({"kind": "viewpoint", "seq": 1, "t": time.monotonic(),
                                       "viewpoint": VP, "client": client}))
            assert time.monotonic() < deadline, "no keyframe from the ZeroMQ server"
        kf = decode_keyframe(dealer.recv_multipart())
        assert kf.color.shape == (64, 64, 3)
    finally:
        ctx.destroy(linger=0)


def test_the_web_benchmark_calls_only_what_the_page_exposes():
    """benchmarks/web_vs_streaming.py drives the page through window.lodsprite: every
    member its scripts use must be one of the page's api (a page change broke it once)."""
    import importlib.util
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    spec = importlib.util.spec_from_file_location(
        "web_vs_streaming", root / "benchmarks" / "web_vs_streaming.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    app = (root / "src/lodsprite/distributed/web/static/app.js").read_text()
    api = app[app.index("  const api = {"):app.index("  return api;")]
    exposed = set(re.findall(r"^\s+(\w+)(?:\(|:|,$)", api, re.M))  # name(), name: or name,
    exposed |= set(re.findall(r"^\s+api\.(\w+) =", api, re.M))
    exposed |= set(re.findall(r"^\s+get (\w+)\(\)", api, re.M))
    used = set(re.findall(r"\bl\.(\w+)", bench.SAMPLE_JS["sprite"]))
    used |= set(re.findall(r"get\(\)\.(\w+)", bench.WAIT_JS)) - {"%s"}
    used |= {"ready", "finished", "stats"}  # WAIT_JS's % arguments and play()'s stats()
    assert used and used <= exposed, used - exposed
