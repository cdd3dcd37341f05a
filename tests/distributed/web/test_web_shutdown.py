"""`lodsprite serve --web` stopped by a signal while pages are connected: each open
WebSocket gets a close frame with code 1001 (going away), the process exits 0 without a
traceback, and no renderer process outlives it.  SIGTERM goes to the server's process,
SIGINT to its whole process group (what a terminal's Ctrl-C does: the renderer processes
get it too)."""

import asyncio
import os
import queue
import signal
import subprocess
import sys
import threading

import aiohttp
import pytest

from conftest import gone, wait_until
from lodsprite.distributed.run import free_ports
from lodsprite.distributed.web.client import connect as web_connect

TOKEN = "test-token"
DEADLINE_S = 30.0
"""Start-up and a first keyframe on this shared machine (a guard against a hang)."""
STOP_DEADLINE_S = 10.0
"""How long the stopped server may take to exit: a close handshake (2 s), the HTTP
server's end (3 s), the pool's (2 s), with slack.  A guard, not a measure of speed."""
LOAD = {"terrain": "fractal:64:1", "size": [64, 64], "lod": 8, "grid": 64}
VP = {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.6, 0.8], "z": [0.0, -0.8, 0.6],
      "o": [0.0, -1500.0, 1200.0]}


def descendants(pid: int) -> set[int]:
    """The processes below ``pid`` (from /proc's children lists)."""
    found: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for tid in tasks:
            try:
                with open(f"/proc/{p}/task/{tid}/children") as f:
                    kids = {int(x) for x in f.read().split()}
            except OSError:
                continue
            todo += list(kids - found)
            found |= kids
    return found


def start_server() -> tuple[subprocess.Popen, int, queue.Queue]:
    proc = subprocess.Popen(
        [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve",
         "--web", "127.0.0.1:0", "--bind", f"127.0.0.1:{free_ports()}", "--token", TOKEN,
         "--renderers", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    line = lines.get(timeout=DEADLINE_S)
    assert line.startswith("web page: http://127.0.0.1:"), line
    return proc, int(line.split(":")[3].split("/")[0]), lines


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT to the group"])
def test_a_signal_closes_the_websockets_and_leaves_no_process(how: str) -> None:
    proc, port, _ = start_server()
    try:
        renderers = wait_until(lambda: len(descendants(proc.pid)) >= 2 and
                               descendants(proc.pid), DEADLINE_S, "two renderer processes")

        async def session() -> list[aiohttp.WSMessage]:
            async with aiohttp.ClientSession() as http:
                pages = [await web_connect(http, f"http://127.0.0.1:{port}", TOKEN)
                         for _ in range(2)]
                await pages[0].load(LOAD)
                await pages[0].keyframe(VP, 1.0)  # a renderer has worked for it
                if how == "SIGTERM":
                    proc.send_signal(signal.SIGTERM)
                else:
                    os.killpg(proc.pid, signal.SIGINT)
                return await asyncio.gather(*(asyncio.wait_for(p.ws.receive(), STOP_DEADLINE_S)
                                              for p in pages))

        closes = asyncio.run(asyncio.wait_for(session(), DEADLINE_S))
        assert [(m.type, m.data) for m in closes] == [  # the close frame and its code
            (aiohttp.WSMsgType.CLOSE, aiohttp.WSCloseCode.GOING_AWAY)] * 2
        rc = proc.wait(timeout=STOP_DEADLINE_S)
        stderr = proc.stderr.read()
        assert rc == 0, stderr
        assert "Traceback" not in stderr, stderr
        wait_until(lambda: all(gone(p) for p in renderers), STOP_DEADLINE_S,
                   "the renderer processes exiting")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
