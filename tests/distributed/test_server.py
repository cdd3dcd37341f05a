"""The LOD server's edge: typed control requests, holds, datasets, memory, a renderer that
survives bad scenes, keyframes for the holder only, prediction on the client's clock."""

import json
import logging
import threading
import time

import numpy as np
import pytest
import zmq
from zmq.utils.monitor import recv_monitor_message

from conftest import wait_until
from lodsprite.camera import Viewpoint, look_at
from lodsprite.distributed import producer as producer_module
from lodsprite.distributed.datasets import MAX_FRACTAL_SIZE, Datasets
from lodsprite.distributed.protocol import decode, decode_keyframe, encode
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.server import LodServer, endpoints
from lodsprite.errors import InputError
from lodsprite.scene.spec import SceneSpec

A, B = "a" * 16, "b" * 16
SMALL = {"terrain": "fractal:64:1", "size": [64, 64], "lod": 8}


def control(server, op, args=None, client=A, seq=1) -> dict:
    return server._control(encode({"kind": "control", "seq": seq, "op": op,
                                   "args": args or {}, "client": client}))


def viewpoint_frames(vp: Viewpoint, t: float, client=A, seq=1) -> list:
    return encode({"kind": "viewpoint", "seq": seq, "t": t, "viewpoint": vp.to_dict(),
                   "client": client})


@pytest.fixture
def server():
    s = LodServer(bind=f"127.0.0.1:{free_ports()}")
    yield s
    s._ctx.term()


# ------------------------------------------------------------------ typed load requests

@pytest.mark.parametrize("args", [
    {"visibility": ["coarse"]},   # was: TypeError unhashable, the server stopped
    {"visibility": {"a": 1}},
    {"pace": ["needed"]},
    {"grid": 2**20},              # was: accepted; the renderer thread died (zombie)
    {"grid": "512"},              # was: accepted; TypeError killed the renderer thread
    {"grid": 100},                # not a power of two
    {"size": [64, 64.5]},
    {"size": [100000, 64]},
    {"size": [64]},
    {"lod": 0},
    {"lod": 32, "grid": 16},
    {"epsilon": float("nan")},
    {"exaggeration": True},
    {"slot": 2, "slots": 2},
    {"terrain": ["jacksboro"]},
    {"unknown": 1},
])
def test_bad_load_arguments_get_ok_false_and_the_server_goes_on(server, args):
    reply = control(server, "load", {**SMALL, **args})
    assert reply["ok"] is False and reply["error"].startswith("load")
    assert server.stats.rejected["control"] == 1
    assert control(server, "ping")["ok"] is True
    assert control(server, "load", SMALL)["ok"] is True  # a good load after it


def test_anything_on_the_control_socket_gets_a_reply_never_an_exception(server):
    for frames in ([], [b""], [b"\xc1"], [b"\x91" * 100000 + b"\xc0"], [b"\x00" * 70000],
                   encode({"kind": "viewpoint", "seq": 1}),
                   encode({"kind": "control", "seq": 1, "op": "ping", "args": [1]}),
                   encode({"kind": "control", "seq": 1, "op": "ping"}, b"extra")):
        reply = server._control(frames)
        assert reply["ok"] is False and reply["error"]
    assert server.stats.rejected["control"] == 8
    assert server.stats.rejected_messages == 8


# -------------------------------------------------------------------------------- holds

def test_one_client_holds_the_server_until_it_releases(server):
    assert control(server, "load", SMALL, A)["ok"]
    refused = control(server, "load", SMALL, B)
    assert refused["ok"] is False and "held by another client" in refused["error"]
    for op in ("start", "stop", "shutdown"):
        assert control(server, op, client=B)["ok"] is False
    assert not server._stop.is_set()
    ping_a, ping_b = control(server, "ping", client=A), control(server, "ping", client=B)
    assert ping_a["data"]["yours"] is True and ping_b["data"]["yours"] is False
    assert ping_b["data"]["held"] is True
    assert control(server, "start", client=A)["ok"] and server._running.is_set()
    assert control(server, "release", client=A)["ok"]
    assert not server._running.is_set()
    assert control(server, "load", SMALL, B)["ok"]


def test_a_hold_lapses_after_the_lease_without_messages(server):
    clock = [100.0]
    server.now = lambda: clock[0]
    assert control(server, "load", SMALL, A)["ok"]
    assert control(server, "start", client=A)["ok"]
    clock[0] += server.lease_s - 1
    assert control(server, "ping", client=A)["data"]["yours"]  # a message renews it
    clock[0] += server.lease_s - 1
    assert control(server, "load", SMALL, B)["ok"] is False
    clock[0] += server.lease_s + 0.1
    assert control(server, "load", SMALL, B)["ok"] is True
    assert not server._running.is_set()  # the lapsed holder's run ended with its hold


def test_viewpoints_from_a_client_that_does_not_hold_are_ignored_and_counted(server):
    vp = look_at((0.0, -500.0, 300.0), (0.0, 0.0, 0.0))
    assert not server._viewpoints.take(viewpoint_frames(vp, 1.0, A))  # nobody holds it yet
    assert control(server, "load", SMALL, A)["ok"]
    assert not server._viewpoints.take(viewpoint_frames(vp, 1.0, B))
    assert server._viewpoints.take(viewpoint_frames(vp, 1.0, A))
    assert not server._viewpoints.take(viewpoint_frames(vp, 0.5, A))  # older than the last
    assert server.stats.ignored == {"viewpoint_not_holder": 2, "viewpoint_not_newer": 1}
    assert server.stats.rejected["viewpoint"] == 0


# ------------------------------------------------------------------------------ datasets

@pytest.fixture
def data_dir(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    rng = np.random.default_rng(0)
    np.save(data / "dem.npy", rng.random((40, 40)).astype(np.float32) * 100)
    (data / "sub").mkdir()
    np.save(data / "sub" / "dem2.npy", rng.random((40, 40)).astype(np.float32))
    outside = tmp_path / "secret.npy"
    np.save(outside, np.zeros((40, 40), np.float32))
    (data / "link.npy").symlink_to(outside)
    (data / "inner.npy").symlink_to(data / "dem.npy")
    return data


def test_datasets_serve_builtins_and_files_inside_the_data_folder_only(data_dir):
    d = Datasets(data_dir)
    assert d.terrain("jacksboro").spec == "jacksboro"
    assert d.terrain("fractal:64:3").spec == "fractal:64:3"
    assert d.texture("checker:8").builtin and d.texture("terrain").builtin
    assert d.terrain("dem.npy").spec == str((data_dir / "dem.npy").resolve())
    assert d.terrain("sub/dem2.npy").shape == (40, 40)
    assert d.terrain("inner.npy").spec == str((data_dir / "dem.npy").resolve())
    for name in (str(data_dir / "dem.npy"), "/etc/passwd", "../secret.npy",
                 "sub/../../secret.npy", "link.npy", "missing.npy", "sub", "~/x.npy",
                 f"fractal:{2 * MAX_FRACTAL_SIZE}:1", "fractal:100:1", "fractal:x"):
        with pytest.raises(InputError):
            d.terrain(name)
    with pytest.raises(InputError):
        d.texture("../secret.npy")
    with pytest.raises(InputError):
        d.texture("checker:0")
    without = Datasets(None)
    assert without.terrain("fractal:64").builtin
    with pytest.raises(InputError, match="--data"):
        without.terrain("dem.npy")


def test_a_terrain_store_in_the_data_folder_is_served_and_a_linked_one_refused(data_dir):
    import shutil

    from lodsprite.terrain.store import build_store

    build_store("fractal:300x200:1", data_dir / "big.zarr", tile=128, chunk=64)
    d = Datasets(data_dir)
    got = d.terrain("big.zarr")
    assert got.spec == str((data_dir / "big.zarr").resolve()) and got.shape == (300, 200)
    assert d.terrain("big.zarr/").shape == (300, 200)
    with pytest.raises(InputError):
        d.texture("big.zarr")  # a store is a terrain, never a texture file
    # a store whose chunk file is a symlink (to anything) is refused
    shutil.copytree(data_dir / "big.zarr", data_dir / "linked.zarr")
    chunk = next(p for p in (data_dir / "linked.zarr" / "0").rglob("*") if p.is_file())
    chunk.unlink()
    chunk.symlink_to(data_dir.parent / "secret.npy")
    with pytest.raises(InputError, match="symlink"):
        d.terrain("linked.zarr")
    # a store whose build did not finish is refused with the reason
    shutil.copytree(data_dir / "big.zarr", data_dir / "part.zarr")
    meta = json.loads((data_dir / "part.zarr" / "zarr.json").read_text())
    meta["attributes"]["lodsprite"]["complete"] = False
    (data_dir / "part.zarr" / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="did not finish"):
        d.terrain("part.zarr")
    s = LodServer(bind=f"127.0.0.1:{free_ports()}", data_dir=data_dir)
    try:
        assert control(s, "load", {**SMALL, "terrain": "big.zarr", "grid": 64})["ok"] is True
        assert control(s, "load", {**SMALL, "terrain": "linked.zarr"})["ok"] is False
    finally:
        s._ctx.term()


def test_a_load_naming_a_path_is_refused_with_ok_false(data_dir):
    s = LodServer(bind=f"127.0.0.1:{free_ports()}", data_dir=data_dir)
    plain = LodServer(bind=f"127.0.0.1:{free_ports()}")
    try:
        for name in ("/etc/passwd", "../secret.npy", "link.npy"):
            reply = control(s, "load", {**SMALL, "terrain": name})
            assert reply["ok"] is False and "load:" in reply["error"]
        reply = control(s, "load", {**SMALL, "texture": str(data_dir.parent / "secret.npy")})
        assert reply["ok"] is False
        assert control(plain, "load", {**SMALL, "terrain": "dem.npy"})["ok"] is False
        assert control(s, "load", {**SMALL, "terrain": "dem.npy", "grid": 64})["ok"] is True
        assert s._producer.pending.terrain == str((data_dir / "dem.npy").resolve())
    finally:
        s._ctx.term()
        plain._ctx.term()


# ------------------------------------------------------------------------ memory, limits

def test_a_scene_the_machine_cannot_hold_is_refused_before_loading(server, monkeypatch):
    from lodsprite.distributed import render  # the one memory check (server, hub, worker)

    monkeypatch.setattr(render, "memory_available", lambda: 200 * 2**20)
    reply = control(server, "load", {**SMALL, "terrain": "fractal:4096:1", "grid": 4096})
    assert reply["ok"] is False and "MiB" in reply["error"]
    assert server._producer.pending is None and server._producer.state == "idle"
    assert control(server, "load", SMALL)["ok"] is True


def test_sizes_over_the_gl_maximum_texture_size_are_refused(server):
    server._producer.max_texture = 100
    reply = control(server, "load", {**SMALL, "grid": 128})
    assert reply["ok"] is False and "maximum texture size" in reply["error"]
    assert control(server, "load", {**SMALL, "size": [128, 64]})["ok"] is False
    assert control(server, "load", {**SMALL, "texture": "checker"})["ok"] is False
    assert control(server, "load", SMALL)["ok"] is True


def test_the_server_binds_loopback_unless_allowed():
    with pytest.raises(InputError, match="allow_remote"):
        LodServer(bind="0.0.0.0:5999")
    s = LodServer(bind="0.0.0.0:5999", allow_remote=True)  # constructed; not run
    s._ctx.term()
    with pytest.raises(InputError):
        LodServer(bind="127.0.0.1:5999", predictor="psychic")


# ----------------------------------------------------- prediction on the client's clock

def test_samples_arriving_in_a_burst_are_timed_by_the_client_clock(server):
    """Regression: samples were stamped with their arrival time, so a burst (a busy
    network) made the eye's velocity many times too high."""
    clock = [50.0]
    server.now = lambda: clock[0]
    assert control(server, "load", SMALL, A)["ok"]
    start = look_at((0.0, -2000.0, 400.0), (0.0, 0.0, 0.0))
    v = np.array([30.0, 45.0, -5.0])
    for i in range(10):  # client times 1/30 s apart, all arriving at one server instant
        t = 7.0 + i / 30
        vp = Viewpoint(start.x, start.y, start.z, start.o + v * (t - 7.0))
        assert server._viewpoints.take(viewpoint_frames(vp, t, A, seq=i + 1))
    server._transmitter.delta_t = 0.5
    clock[0] += 0.2  # predicted from the newest sample: δt + 0.2 s since it arrived
    predicted, _ = server._producer.predicted_viewpoint()
    np.testing.assert_allclose(predicted.o, vp.o + v * 0.7, atol=1e-6)


# --------------------------------------------------------------- live in-process server

class Live:
    """A server running in a thread, and raw sockets to it."""

    def __init__(self, **kw):
        self.address = f"127.0.0.1:{free_ports()}"
        self.server = LodServer(bind=self.address, **kw)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        self.ctx = zmq.Context()
        self.ctl_ep, self.vp_ep, self.kf_ep = endpoints(self.address, bind=False)
        self.req = self.ctx.socket(zmq.REQ)
        self.req.setsockopt(zmq.RCVTIMEO, 10000)
        self.req.connect(self.ctl_ep)
        self.seq = 0

    def control(self, op, args=None, client=A) -> dict:
        self.seq += 1
        self.req.send_multipart(encode({"kind": "control", "seq": self.seq, "op": op,
                                        "args": args or {}, "client": client}))
        return decode(self.req.recv_multipart())[0]

    def wait_state(self, want, timeout=60.0) -> dict:
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            data = self.control("ping")["data"]
            if data["state"] in want:
                return data
            time.sleep(0.05)
        raise AssertionError(f"state never became {want}: {data}")

    def dealer(self, identity: str | None, connected: bool = False):
        """A DEALER on the keyframe socket; ``connected``: returned once its handshake with
        the server is done (a socket monitor's event, within a deadline)."""
        d = self.ctx.socket(zmq.DEALER)
        if identity:
            d.setsockopt(zmq.IDENTITY, identity.encode())
        mon = d.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED) if connected else None
        d.connect(self.kf_ep)
        if mon is not None:
            try:
                wait_until(lambda: mon.poll(0) and recv_monitor_message(mon)["event"]
                           == zmq.EVENT_HANDSHAKE_SUCCEEDED, 10, "the handshake")
            finally:
                d.disable_monitor()
                mon.close(linger=0)
        return d

    def close(self):
        self.server.shutdown()
        self.thread.join(15)
        self.ctx.destroy(linger=0)


@pytest.fixture
def live():
    lv = Live()
    yield lv
    lv.close()


def _keyframe_for(live, identity, others=(), timeout=30.0):
    """Start ``identity``'s scene, publish its viewpoints until a keyframe comes; returns
    (keyframe, messages the ``others`` sockets received)."""
    pub = live.ctx.socket(zmq.PUB)
    pub.connect(live.vp_ep)
    mine = live.dealer(identity)
    got = [0 for _ in others]
    vp = look_at((0.0, -2500.0, 900.0), (0.0, 0.0, 0.0))
    deadline = time.perf_counter() + timeout
    t = 0.0
    try:
        while time.perf_counter() < deadline:
            t += 0.03
            pub.send_multipart(viewpoint_frames(vp, t, identity))
            for i, o in enumerate(others):
                while o.poll(0):
                    o.recv_multipart()
                    got[i] += 1
            if mine.poll(30):
                frames = mine.recv_multipart(copy=False)
                kf = decode_keyframe(frames)
                mine.send_multipart(encode({"kind": "ack", "seq": kf.seq, "t": t}))
                return kf, got
        raise AssertionError("no keyframe reached the holder")
    finally:
        pub.close(linger=0)
        mine.close(linger=0)


def test_keyframes_go_to_the_holder_only(live):
    """Regression: the keyframe socket was a bound DEALER, which deals messages round
    robin to every connected peer: any stranger could take keyframes."""
    strangers = [live.dealer(None, connected=True), live.dealer(B, connected=True)]
    assert live.control("load", SMALL)["ok"] and live.control("start")["ok"]
    live.wait_state({"ready"})
    kfs = []
    for _ in range(2):  # dealt round robin, two keyframes would reach a stranger
        kf, got = _keyframe_for(live, A, strangers)
        kfs.append(kf)
        assert got == [0, 0]
        live.control("load", {**SMALL, "pace": "continuous"})  # render again at once
    assert kfs[0].color.shape == (64, 64, 3)


def _fail_for(terrain, exc):
    real = producer_module.KeyframeService

    def make(args):
        if args.terrain == terrain:
            raise exc
        return real(args)
    return make


@pytest.mark.parametrize("exc", [MemoryError(), RuntimeError("GL_OUT_OF_MEMORY"),
                                 TypeError("unexpected")])
def test_the_renderer_survives_a_scene_that_fails_and_a_later_load_works(live, monkeypatch,
                                                                          exc):
    """Regression: only LodspriteError and ValueError were caught: anything else (a
    MemoryError, a GL error) killed the renderer thread, and the server answered ping
    but never sent a keyframe again."""
    monkeypatch.setattr(producer_module, "KeyframeService", _fail_for("fractal:32:9", exc))
    assert live.control("load", {**SMALL, "terrain": "fractal:32:9"})["ok"]
    live.control("start")  # refused when the load has failed already, accepted before
    data = live.wait_state({"failed"})
    assert type(exc).__name__ in data["error"] and not data["running"]
    refused = live.control("start")  # a failed scene cannot be started
    assert not refused["ok"] and type(exc).__name__ in refused["error"]
    assert not live.control("ping")["data"]["running"]
    assert live.control("load", SMALL)["ok"] and live.control("start")["ok"]
    assert live.wait_state({"ready"})["error"] == ""
    kf, _ = _keyframe_for(live, A)
    assert kf.color.shape == (64, 64, 3)


def _first_render_fails(monkeypatch, message: str) -> list:
    """Make the server's first keyframe render raise ``RuntimeError(message)``; the list
    of render calls so far."""
    calls: list = []
    real = producer_module.KeyframeService

    class Flaky(real):
        def render(self, *a, **kw):
            calls.append(1)
            if len(calls) == 1:
                raise RuntimeError(message)
            return super().render(*a, **kw)

    monkeypatch.setattr(producer_module, "KeyframeService", Flaky)
    return calls


def test_the_renderer_survives_a_keyframe_that_fails_to_render(live, monkeypatch):
    calls = _first_render_fails(monkeypatch, "GL_INVALID_OPERATION")
    assert live.control("load", SMALL)["ok"] and live.control("start")["ok"]
    pub = live.ctx.socket(zmq.PUB)
    pub.connect(live.vp_ep)
    vp = look_at((0.0, -2500.0, 900.0), (0.0, 0.0, 0.0))
    deadline = time.perf_counter() + 30
    t = 0.0
    while not calls and time.perf_counter() < deadline:
        t += 0.03
        pub.send_multipart(viewpoint_frames(vp, t, A))
        time.sleep(0.03)
    pub.close(linger=0)
    data = live.wait_state({"failed"})
    assert "GL_INVALID_OPERATION" in data["error"]
    assert live.control("load", SMALL)["ok"] and live.control("start")["ok"]
    kf, _ = _keyframe_for(live, A)
    assert len(calls) >= 2 and kf.depth.shape == (64, 64)


def test_a_failed_scene_holds_no_memory_in_the_servers_accounting(live, monkeypatch):
    """Regression: the estimate of a scene that failed stayed credited as held, so the
    next load's memory check counted memory nobody held."""
    release = threading.Event()
    fail = _fail_for("fractal:32:9", MemoryError())

    def held_then_failed(args):
        assert release.wait(30.0)  # hold the load until the figure was read
        return fail(args)

    monkeypatch.setattr(producer_module, "KeyframeService", held_then_failed)
    assert live.control("load", {**SMALL, "terrain": "fractal:32:9"})["ok"]
    try:
        assert live.server._producer.scene_bytes > 0  # asked for, not yet loaded
    finally:
        release.set()
    live.wait_state({"failed"})
    assert live.server._producer.scene_bytes == 0
    assert live.control("load", SMALL)["ok"]
    live.wait_state({"ready"})
    assert live.server._producer.scene_bytes > 0


def test_a_client_gets_keyframes_again_after_a_passing_render_failure(live, monkeypatch,
                                                                     caplog):
    """Regression: after one render failure the client never loaded the scene again and
    the server stayed idle for good.  The client loads a failed scene again after a wait
    (shortened here) that doubles while it keeps failing."""
    from lodsprite.distributed import link as link_module
    from lodsprite.distributed.client import LodClient
    from lodsprite.distributed.render import scene_args
    from lodsprite.run import RenderConfig, prepare

    calls = _first_render_fails(monkeypatch, "GL_OUT_OF_MEMORY")
    monkeypatch.setattr(link_module, "RETRY_FIRST_S", 0.2)
    caplog.set_level(logging.WARNING, logger="lodsprite.client")
    cfg = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=8, frames=5,
                       path="chen1999", mode="sprite")
    scene, path = prepare(cfg)
    client = LodClient(scene, scene_args(SceneSpec(cfg.terrain, cfg.texture, None, 1.0), cfg.size),
                       [live.address], cfg.size, cfg.lod)
    try:
        deadline = time.perf_counter() + 60.0  # a hang guard
        while client.frame(path.viewpoints[0]).type != "keyframe":
            assert time.perf_counter() < deadline, f"no keyframe after {len(calls)} renders"
            time.sleep(0.02)
        # rendered again: the failed renderer was dropped, so the scene was loaded again
        assert len(calls) >= 2
        assert "could not load or render the scene" in caplog.text
    finally:
        client.close()
