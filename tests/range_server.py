"""A static file server on loopback that answers HTTP range requests (aiohttp's static
route), counting the body bytes it sends: ``GET /_stats`` gives ``{"bytes", "requests"}``
since the last ``GET /_reset``.  Run as ``python range_server.py FOLDER``; prints its port.
For the remote-data tests and benchmarks (a real server, not a mock)."""

from __future__ import annotations

import asyncio
import sys

from aiohttp import web


def make_app(root: str) -> web.Application:
    sent = {"bytes": 0, "requests": 0}

    async def prepared(request: web.Request, response: web.StreamResponse) -> None:
        if request.path.startswith("/_"):
            return
        sent["requests"] += 1
        if request.method == "GET":
            sent["bytes"] += response.content_length or 0

    async def stats(request: web.Request) -> web.Response:
        return web.json_response(sent)

    async def reset(request: web.Request) -> web.Response:
        sent.update(bytes=0, requests=0)
        return web.json_response(sent)

    app = web.Application()
    app.on_response_prepare.append(prepared)
    app.router.add_get("/_stats", stats)
    app.router.add_get("/_reset", reset)
    app.router.add_static("/", root, show_index=False)
    return app


async def main(root: str) -> None:
    runner = web.AppRunner(make_app(root))
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    sys.stdout.write(f"{site._server.sockets[0].getsockname()[1]}\n")
    sys.stdout.flush()
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1]))
