"""Benchmark: a worker process's round trip (issue 31, must-have 6).

Requests through :class:`lodsprite.workers.ProcessWorker` answered by a handler that
returns a payload of the requested size (no reading, no decoding: the mechanism alone):
a 65² float32 tile (16.9 KiB) through the pipe, as the terrain's tile reader sends them,
and through a shared slot; a 512² RGB lumigraph node (768 KiB) through a slot.  Prints,
for each, the median round trip of one request in flight (ms, over ``--n``), the
throughput with ``--window`` in flight (answers/s, MB/s, and the caller's time in ``poll``
per answer collected: what the frame's thread pays) and the start-up time to the first
answer.  It runs against whichever ``lodsprite`` is on the path, so the same
script measures an older mechanism too::

    PYTHONPATH=src python benchmarks/worker_roundtrip.py [--n 400] [--window 48]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def payload(size: int):
    """The child's handler factory: answers ``meta`` (an int64 byte count) with that
    many bytes."""
    block = bytes(range(256)) * (size // 256 + 1)

    def handle(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        return meta, block[:int.from_bytes(meta, "little")]

    return handle


def drain(w, n: int, deadline: float) -> list:
    out = []
    while len(out) < n and time.monotonic() < deadline:
        out += w.poll()
    return out


def case(nbytes: int, slots: bool, n: int, window: int) -> dict:
    from lodsprite.workers import ProcessWorker

    meta = nbytes.to_bytes(8, "little")
    t0 = time.perf_counter()
    w = ProcessWorker("worker_roundtrip:payload", {"size": nbytes}, in_flight=window,
                      name="bench", slot_bytes=nbytes if slots else 0)
    try:
        w.submit("first", meta)
        got = drain(w, 1, time.monotonic() + 60)
        start_ms = (time.perf_counter() - t0) * 1e3
        assert got and len(got[0][1][1]) == nbytes, got
        rtt = []
        for i in range(n):  # one in flight: latency
            t = time.perf_counter()
            w.submit(i, meta)
            while not (a := w.poll()):
                pass
            rtt.append((time.perf_counter() - t) * 1e3)
            assert len(a[0][1][1]) == nbytes
        sent = done = 0
        in_poll = 0.0  # the caller's time in the polls that collected answers
        t = time.perf_counter()
        while done < n:  # the window full: throughput
            while sent < n and w.submit(sent, meta):
                sent += 1
            t1 = time.perf_counter()
            got = len(w.poll())
            if got:
                in_poll += time.perf_counter() - t1
                done += got
        s = time.perf_counter() - t
    finally:
        w.close()
    return {"bytes": nbytes, "slots": slots, "median_rtt_ms": statistics.median(rtt),
            "answers_per_s": n / s, "mb_per_s": n * nbytes / s / 1e6,
            "poll_us_per_answer": in_poll / n * 1e6,
            "start_ms": start_ms}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--window", type=int, default=48)
    args = ap.parse_args()
    # the child finds this module by sys.path (a spawned one) or PYTHONPATH (a command)
    os.environ["PYTHONPATH"] = os.pathsep.join(
        [str(HERE), *filter(None, [os.environ.get("PYTHONPATH")])])
    sys.path.insert(0, str(HERE))
    tile, node = 65 * 65 * 4, 512 * 512 * 3
    rows = [case(tile, False, args.n, args.window), case(tile, True, args.n, args.window),
            case(node, True, max(1, args.n // 4), min(args.window, 16))]
    for r in rows:
        print(f"{r['bytes']:>8} B {'slot' if r['slots'] else 'pipe'}: round trip "
              f"{r['median_rtt_ms']:.3f} ms (median), {r['answers_per_s']:.0f} answers/s "
              f"= {r['mb_per_s']:.0f} MB/s, {r['poll_us_per_answer']:.1f} µs of poll an answer, "
              f"first answer after {r['start_ms']:.0f} ms")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
