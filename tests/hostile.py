"""Hostile traffic for a LOD server: random and mutated messages on its three sockets.

Used by the fuzz tests (``test_fuzz.py`` and the web, bounds and browser tests) and the
fuzz benchmark (``benchmarks/fuzz_server.py``); test-only, so kept out of the package.
:func:`hostile_frames` makes one multipart message for a socket: random bytes, random
msgpack structures, valid messages with one field mutated, removed or added, wrong
versions, extra frames, deep nesting, or frames over the socket's ``zmq.MAXMSGSIZE``.
:func:`flood` sends a number of them to a live server.

``shutdown`` is among the ops: a server started without ``allow_shutdown`` (as the fuzz
runs do) must refuse it from anyone, holder or not, and go on serving.
"""

from __future__ import annotations

import time

import msgspec
import numpy as np
import zmq

from lodsprite.distributed.protocol import (
    MAX_CONTROL_BYTES,
    PROTOCOL_VERSION,
    decode,
)
from lodsprite.distributed.server import endpoints

SOCKETS = ("control", "viewpoint", "keyframe")
_OPS = ("start", "stop", "load", "stats", "ping", "release", "shutdown")
_KEYS = ("v", "kind", "seq", "op", "args", "client", "t", "viewpoint", "shown", "terrain",
         "texture", "grid", "size", "lod", "visibility", "slot", "slots", "x", "o", "eye")


def _pick(rng: np.random.Generator, items: list):
    return items[int(rng.integers(0, len(items)))]


def random_value(rng: np.random.Generator, depth: int = 0):
    """A random msgpack-encodable value (nested lists and maps up to depth 3)."""
    choice = int(rng.integers(0, 12 if depth < 3 else 9))
    if choice == 0:
        return None
    if choice == 1:
        return bool(rng.integers(0, 2))
    if choice == 2:
        return int(rng.integers(-2**63, 2**63 - 1, dtype=np.int64))
    if choice == 3:
        return _pick(rng, [0, 1, -1, 2**20, 2**31, 2**64 - 1, 16, 64, 4096, 8192])
    if choice == 4:
        return _pick(rng, [np.nan, np.inf, -np.inf, 0.5, 1e300, -1e-300, 3.0])
    if choice == 5:
        return _pick(rng, ["", "jacksboro", "fractal:64:1", "/etc/passwd", "../../x",
                               "fractal:1048576", "checker:0", "coarse", "zlib", "a" * 300])
    if choice == 6:
        return rng.bytes(int(rng.integers(0, 64)))
    if choice == 7:
        return float(rng.normal() * 10 ** rng.integers(0, 12))
    if choice == 8:
        return _pick(rng, _KEYS)
    if choice in (9, 10):
        return [random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 5)))]
    return {_pick(rng, _KEYS) if rng.random() < 0.8 else random_value(rng, 3):
            random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 5)))}


def _viewpoint(rng: np.random.Generator) -> dict:
    o = (rng.normal(size=3) * 1000).tolist()
    return {"x": [1.0, 0.0, 0.0], "y": [0.0, 1.0, 0.0], "z": [0.0, 0.0, 1.0], "o": o}


def valid_header(kind: str, rng: np.random.Generator, client: str = "") -> dict:
    """A valid header for socket ``kind`` (control requests, viewpoints,
    acknowledgements), light enough for any server to carry out (``shutdown`` only by a
    server that allows it)."""
    seq = int(rng.integers(0, 2**31))
    if kind == "control":
        op = str(rng.choice(_OPS))
        args = ({"terrain": "fractal:64:1", "size": [64, 64], "lod": 8, "grid": 64}
                if op == "load" else {})
        return {"v": PROTOCOL_VERSION, "kind": "control", "seq": seq, "op": op,
                "args": args, "client": client}
    if kind == "viewpoint":
        h = {"v": PROTOCOL_VERSION, "kind": "viewpoint", "seq": seq, "t": float(rng.random()),
             "viewpoint": _viewpoint(rng), "client": client}
        if rng.random() < 0.5:
            h["shown"] = {"eye": [0.0, 0.0, 100.0], "slot": int(rng.integers(0, 3))}
        return h
    if kind == "request":
        return {"v": PROTOCOL_VERSION, "kind": "request", "seq": seq,
                "t": float(rng.random()), "viewpoint": _viewpoint(rng), "client": client}
    return {"v": PROTOCOL_VERSION, "kind": "ack", "seq": seq, "t": float(rng.random())}


def mutate(header: dict, rng: np.random.Generator) -> dict:
    """``header`` with one field (or one nested field) replaced, removed or added."""
    h = dict(header)
    target = h
    nested = [k for k, v in h.items() if isinstance(v, dict) and v]
    if nested and rng.random() < 0.5:
        key = _pick(rng, nested)
        target = h[key] = dict(h[key])
    keys = list(target)
    action = rng.random()
    if keys and action < 0.6:
        target[_pick(rng, keys)] = random_value(rng)
    elif keys and action < 0.8:
        del target[_pick(rng, keys)]
    else:
        target[_pick(rng, _KEYS)] = random_value(rng)
    return h


def _pack(value) -> bytes:
    try:
        return msgspec.msgpack.encode(value)
    except (TypeError, ValueError, OverflowError):
        return b"\xc1"  # never valid msgpack


def hostile_frames(kind: str, rng: np.random.Generator, max_bytes: int = MAX_CONTROL_BYTES
                   ) -> list[bytes]:
    """One hostile multipart message for socket ``kind`` (control, viewpoint, keyframe, or
    web: the parts of one web-page WebSocket message, :mod:`lodsprite.distributed.web`)."""
    sort = int(rng.integers(0, 10))
    if sort == 0:
        return [rng.bytes(int(rng.integers(0, 200)))]
    if sort == 1:
        return [_pack(random_value(rng))]
    if sort == 2:  # deep nesting
        return [b"\x91" * int(rng.integers(100, 5000)) + b"\xc0"]
    if sort == 3:  # a valid header of another socket's kind, or another version
        other = valid_header(str(rng.choice(["control", "viewpoint", "ack", "request"])), rng)
        if rng.random() < 0.5:
            other["v"] = int(rng.choice([0, PROTOCOL_VERSION - 1, PROTOCOL_VERSION + 1, -1]))
        return [_pack(other)]
    if sort == 4:  # extra frames
        return [_pack(valid_header(_kind(kind, rng), rng)),
                *[rng.bytes(int(rng.integers(0, 100))) for _ in range(int(rng.integers(1, 4)))]]
    if sort == 5 and rng.random() < 0.05:  # over the socket's size cap
        return [b"\x00" * (max_bytes + 1)]
    header = valid_header(_kind(kind, rng), rng)
    for _ in range(int(rng.integers(1, 4))):
        header = mutate(header, rng)
    try:
        return [_pack(header)]
    except (TypeError, ValueError, OverflowError):
        return [rng.bytes(16)]


def _kind(socket: str, rng: np.random.Generator) -> str:
    if socket == "web":  # a web page's one WebSocket carries every page-to-server kind
        return _pick(rng, ["control", "viewpoint", "ack", "request"])
    return {"control": "control", "viewpoint": "viewpoint", "keyframe": "ack"}[socket]


def flood(address: str, counts: dict[str, int], seed: int = 0,
          reply_timeout_ms: int = 200) -> dict:
    """Send ``counts[socket]`` hostile messages to the server at ``HOST:PORT`` on each
    socket (control requests wait up to ``reply_timeout_ms`` for their reply, the REQ
    socket made afresh when none comes).  Returns what was sent and answered:
    ``sent`` per socket, ``replies`` (ok true / false), ``unanswered``."""
    rng = np.random.default_rng(seed)
    ctl_ep, vp_ep, kf_ep = endpoints(address, bind=False)
    ctx = zmq.Context()
    out = {"sent": dict.fromkeys(SOCKETS, 0), "replies": {"ok": 0, "refused": 0},
           "unanswered": 0}
    try:
        pub = ctx.socket(zmq.PUB)
        pub.setsockopt(zmq.LINGER, 0)
        pub.connect(vp_ep)
        dealers = []
        for i in range(3):
            d = ctx.socket(zmq.DEALER)
            d.setsockopt(zmq.LINGER, 0)
            if i:
                d.setsockopt(zmq.IDENTITY, rng.bytes(8).hex().encode())
            d.connect(kf_ep)
            dealers.append(d)
        time.sleep(0.3)  # let the subscription reach the publisher
        req = None
        order = [s for s in SOCKETS for _ in range(counts.get(s, 0))]
        rng.shuffle(order)
        for i, socket in enumerate(order):
            frames = hostile_frames(socket, rng)
            if socket == "control":
                if req is None:
                    req = ctx.socket(zmq.REQ)
                    req.setsockopt(zmq.LINGER, 0)
                    req.connect(ctl_ep)
                req.send_multipart(frames)
                if req.poll(reply_timeout_ms):
                    try:
                        header, _ = decode(req.recv_multipart())
                        out["replies"]["ok" if header.get("ok") else "refused"] += 1
                    except Exception:  # a reply we cannot read is still an answer
                        out["replies"]["refused"] += 1
                else:
                    out["unanswered"] += 1
                    req.close(linger=0)
                    req = None
            elif socket == "viewpoint":
                try:
                    pub.send_multipart(frames, flags=zmq.NOBLOCK)
                except zmq.Again:
                    pass
            else:
                try:
                    dealers[i % len(dealers)].send_multipart(frames, flags=zmq.NOBLOCK)
                except zmq.Again:
                    pass
            out["sent"][socket] += 1
            if i % 200 == 199:
                time.sleep(0.005)  # let the server's queues drain a little
        if req is not None:
            req.close(linger=0)
    finally:
        ctx.destroy(linger=0)
    return out
