"""Flood a live LOD server with hostile messages, then check a real client gets keyframes.

Starts ``lodsprite serve`` on free loopback ports, sends ``--messages`` random and mutated
messages spread over its three sockets (control REQ, viewpoint PUB, keyframe DEALERs
with garbage acknowledgements; ``tests/hostile.py``), then runs a real
:class:`~lodsprite.distributed.client.LodClient` on a small fractal and counts the
keyframes it receives.  Prints what was sent per socket, what the server received,
rejected and ignored per kind, its state, and the keyframes received afterwards.

    python benchmarks/fuzz_server.py --messages 12000
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import zmq

from lodsprite.distributed.client import LodClient
from lodsprite.distributed.link import ServerLink, control
from lodsprite.distributed.render import scene_args
from lodsprite.distributed.run import local_server
from lodsprite.run import RenderConfig, prepare
from lodsprite.scene.spec import SceneSpec

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from hostile import flood  # noqa: E402  (test-only traffic, kept with the tests)


def server_stats(address: str) -> tuple[dict, dict]:
    """(ping data, stats) of the server, asked by a client that does not hold it."""
    ctx = zmq.Context()
    link = ServerLink(ctx, address)
    counter = itertools.count(1)
    try:
        ping = control(link, counter, "ping") or {}
        stats = control(link, counter, "stats") or {}
        return ping.get("data", {}), stats.get("data", {})
    finally:
        link.close(release=False)
        ctx.destroy(linger=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=12000, help="hostile messages in all")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--client-seconds", type=float, default=30.0,
                    help="how long the real client runs afterwards")
    a = ap.parse_args()
    third = a.messages // 3
    counts = {"control": third, "viewpoint": third, "keyframe": a.messages - 2 * third}
    cfg = RenderConfig(terrain="fractal:64:2", size=(64, 64), lod=8, frames=60,
                       path="chen1999", mode="sprite")
    scene, path = prepare(cfg)
    with local_server() as address:
        time.sleep(2.0)  # server start-up
        t0 = time.perf_counter()
        sent = flood(address, counts, seed=a.seed)
        flood_s = time.perf_counter() - t0
        ping, stats = server_stats(address)
        client = LodClient(scene, scene_args(SceneSpec(cfg.terrain, cfg.texture, None, 1.0),
                                             cfg.size),
                           [address], cfg.size, cfg.lod, pace="continuous")
        types = []
        try:
            deadline = time.perf_counter() + a.client_seconds
            i = 0
            while time.perf_counter() < deadline:
                types.append(client.frame(path.viewpoints[i % len(path.viewpoints)]).type)
                i += 1
                time.sleep(0.01)
        finally:
            client.close()
        ping_after, stats_after = server_stats(address)
    result = {
        "messages_sent": sum(sent["sent"].values()), "sent_per_socket": sent["sent"],
        "flood_s": round(flood_s, 2), "control_replies": sent["replies"],
        "control_unanswered": sent["unanswered"],
        "server_received": stats.get("received"), "server_rejected": stats.get("rejected"),
        "server_ignored": stats.get("ignored"), "server_refused": stats.get("refused"),
        "state_after_flood": {k: ping.get(k) for k in ("state", "error", "held")},
        "server_still_serving": bool(ping),
        "client_frames": len(types),
        "client_keyframes_received": types.count("keyframe"),
        "server_keyframes_sent_after": (stats_after.get("keyframes_sent", 0)
                                        - stats.get("keyframes_sent", 0)),
        "state_after_client": {k: ping_after.get(k) for k in ("state", "error")},
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
