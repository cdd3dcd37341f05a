"""``lodsprite serve --web``: the LOD server for web pages (Swan et al. 2002's server, its
client a WebGL2 page), an aiohttp application beside the ZeroMQ server.

Routes: ``GET /?token=T&...`` the page (``static/index.html``; 401 without the token),
``GET /static/...`` its modules and ``GET /options.json`` the technique options its query
takes, as declared (:data:`PAGE_OPTIONS`; no token: they hold no data), ``GET /ws?token=T`` the
WebSocket (403 without the token or for a foreign ``Origin``).  Every request whose
``Host`` does not name this server gets 421 first (:mod:`.security`).  Each WebSocket is
a :class:`~.sessions.Session` of the :class:`~.hub.Hub`, which renders its keyframes on
the render pool.  Messages: :mod:`.wire`.

:func:`serve_web` runs it until a signal; :class:`WebServer` starts and stops it inside a
running event loop (tests, benchmarks).  Stopping (SIGTERM, SIGINT, :meth:`WebServer.stop`)
refuses new WebSockets (503), closes the open ones with a close frame of code 1001 (going
away; each given :data:`CLOSE_S` s, a page that stopped reading is cut off after it), ends
the sessions, then the HTTP server (requests still running get :data:`SHUTDOWN_S` s), then
the render pool (its local renderer processes are told to stop, terminated after 2 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import ssl
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aiohttp import WSCloseCode, WSMsgType, web

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.web.hub import Hub
from lodsprite.distributed.web.security import (
    check_host,
    check_origin,
    token_ok,
)
from lodsprite.distributed.web.sessions import Caps
from lodsprite.distributed.web.wire import MAX_PAGE_MESSAGE

log = logging.getLogger("lodsprite.web")

__all__ = ["STATIC_DIR", "WebConfig", "WebServer", "make_pool", "serve_web"]

STATIC_DIR = Path(__file__).parent / "static"
HEARTBEAT_S = 20.0
CLOSE_S = 2.0
"""Seconds a WebSocket's close handshake may take when the server stops."""
SHUTDOWN_S = 3.0
"""Seconds HTTP requests still running get when the server stops."""
MAX_SESSIONS = 256
"""WebSockets served at once; one more is answered 503."""
#: The technique options the page takes from its query string, each parsed and checked by
#: its declaration (:class:`~lodsprite.techniques.Option`), served as ``/options.json``.
PAGE_OPTIONS = ("lod", "epsilon", "visibility", "proxy", "pair")
#: What the page draws of the ``proxy`` choices (WebGL2 has no geometry shader for the
#: refined mesh; the search is not ported), and its default: the keyframe's own depth,
#: as a store's spriteframes in the library.
PAGE_PROXIES = ("geometry", "depth")
PAGE_DEFAULTS = {"proxy": "depth", "pair": False}


def page_options() -> list[dict]:
    """The declarations of :data:`PAGE_OPTIONS` (``proxy`` narrowed to
    :data:`PAGE_PROXIES`); a default the terrain decides is :data:`PAGE_DEFAULTS`' or the
    in-memory terrain's (:data:`~lodsprite.techniques.defaults.MEMORY_DEFAULTS`)."""
    from dataclasses import replace

    from lodsprite import techniques
    from lodsprite.techniques.defaults import MEMORY_DEFAULTS

    known = techniques.all_options(("terrain",))
    known["proxy"] = replace(known["proxy"], choices=PAGE_PROXIES)
    return [known[n].declaration(PAGE_DEFAULTS.get(n, MEMORY_DEFAULTS.get(n)))
            for n in PAGE_OPTIONS]


async def _options(request: web.Request) -> web.StreamResponse:
    return web.json_response(page_options(), headers=NO_STORE)


CSP = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
       "img-src 'self' data: blob:; connect-src 'self' ws: wss:; worker-src 'self' blob:; "
       "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
"""The page's Content-Security-Policy: its own modules only (no inline or foreign
script), WebSockets, and no framing by another site."""
NO_STORE = {"Cache-Control": "no-store", "Referrer-Policy": "no-referrer",
            "X-Content-Type-Options": "nosniff"}


@dataclass
class WebConfig:
    """What ``serve --web`` was given: ``host``/``port`` (0: any free port), the
    ``token``, ``data_dir``, ``renderers`` local renderer processes, per-session ``caps``,
    keyframe ``codec``, an optional TLS context, the ``public_hosts`` names a reverse
    proxy serves the page under (accepted as ``Host``), and ``ray``, the address of a
    Ray cluster whose actors are the ``renderers``
    (:class:`~lodsprite.distributed.pool.ray_pool.RayPool`), each with
    ``gpus_per_renderer`` GPUs (None: local renderer processes)."""

    host: str = "127.0.0.1"
    port: int = 0
    token: str = ""
    data_dir: Path | None = None
    renderers: int = 1
    caps: Caps = field(default_factory=Caps)
    codec: str = "raw"
    tls: ssl.SSLContext | None = None
    public_hosts: tuple[str, ...] = ()
    ray: str | None = None
    gpus_per_renderer: float = 0.0


class WebServer:
    """The aiohttp application, its hub and pool.  ``pool``: an object with the local pool's
    interface (None: :func:`make_pool`, a :class:`~lodsprite.distributed.pool.LocalPool`
    with ``config.renderers`` local renderer processes or, with ``config.ray``, a
    :class:`~lodsprite.distributed.pool.ray_pool.RayPool`; raises
    :class:`~lodsprite.errors.LodspriteError` when its endpoint cannot be bound or the
    Ray cluster reached)."""

    def __init__(self, config: WebConfig, pool: Any = None) -> None:
        """``pool``: see the class; None: :func:`make_pool`."""
        self.config = config
        self.datasets = Datasets(config.data_dir)
        self._own_pool = pool is None
        self.pool = make_pool(config) if pool is None else pool
        self.hub: Hub | None = None
        self._runner: web.AppRunner | None = None
        self._sockets: set[web.WebSocketResponse] = set()
        self._stopping = False
        self.port: int | None = None

    @property
    def url(self) -> str:
        """The page's full URL (token included)."""
        scheme = "https" if self.config.tls is not None else "http"
        host = self.config.host
        host = f"[{host}]" if ":" in host else host
        return f"{scheme}://{host}:{self.port}/?token={self.config.token}"

    def app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_PAGE_MESSAGE, middlewares=[self._host])
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/favicon.ico", _no_icon)
        app.router.add_get("/options.json", _options)
        app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False,
                              show_index=False)
        return app

    async def start(self) -> str:
        """Bind and start serving (inside the running loop); the page's URL."""
        self.hub = Hub(self.pool, self.datasets, self.config.caps, self.config.codec)
        self.hub.start()
        self._runner = web.AppRunner(self.app(), access_log=None, shutdown_timeout=SHUTDOWN_S)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.config.host, self.config.port,
                           ssl_context=self.config.tls)
        await site.start()
        self.port = site._server.sockets[0].getsockname()[1]  # the bound port (0: chosen)
        return self.url

    async def stop(self) -> None:
        """Close the WebSockets (code 1001), the sessions, the HTTP server and the pool
        (idempotent; at most about CLOSE_S + SHUTDOWN_S + 2 s)."""
        if self._stopping:
            return
        self._stopping = True
        await asyncio.gather(*(_going_away(ws) for ws in list(self._sockets)))
        if self.hub is not None:
            await self.hub.stop()
        if self._runner is not None:
            await self._runner.cleanup()
        if self._own_pool:
            await asyncio.to_thread(self.pool.close)

    # ---------------------------------------------------------------------- routes

    @web.middleware
    async def _host(self, request: web.Request, handler) -> web.StreamResponse:
        """421 for a request whose ``Host`` is not one of this server's names (DNS
        rebinding), before any route: page, static files and WebSocket alike."""
        if not check_host(request.headers.get("Host"), self.config.host,
                          self.config.public_hosts):
            return web.Response(status=421, text="unknown host", headers=NO_STORE)
        return await handler(request)

    async def _index(self, request: web.Request) -> web.StreamResponse:
        if not token_ok(request.query.get("token"), self.config.token):
            return web.Response(status=401, text="a valid ?token= is required",
                                headers=NO_STORE)
        return web.FileResponse(STATIC_DIR / "index.html",
                                headers={**NO_STORE, "Content-Security-Policy": CSP})

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if not token_ok(request.query.get("token"), self.config.token):
            return web.Response(status=403, text="a valid ?token= is required")
        if not check_origin(request.headers.get("Origin"), request.host):
            return web.Response(status=403, text="foreign origin")
        if self._stopping:
            return web.Response(status=503, text="server stopping")
        if len(self.hub.sessions) >= MAX_SESSIONS:
            return web.Response(status=503, text="too many sessions")
        ws = web.WebSocketResponse(max_msg_size=MAX_PAGE_MESSAGE, heartbeat=HEARTBEAT_S,
                                   compress=False, timeout=CLOSE_S)
        await ws.prepare(request)
        self._sockets.add(ws)
        hub = self.hub
        session = hub.open_session()
        writer = asyncio.get_running_loop().create_task(session.run_writer(ws.send_bytes))
        writer.add_done_callback(lambda t: _closed_on_error(t, ws))
        try:
            async for msg in ws:
                if msg.type == WSMsgType.BINARY:
                    session.handle(msg.data)
                elif msg.type == WSMsgType.TEXT:
                    session.handle(b"")  # counted and refused: the wire is binary only
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            self._sockets.discard(ws)
            hub.close_session(session)
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await writer
        return ws


def make_pool(config: WebConfig) -> Any:
    """The render pool ``config`` asks for: ``config.renderers`` Ray actors with
    ``config.ray`` (Ray imported only then), else a
    :class:`~lodsprite.distributed.pool.LocalPool` with that many renderer processes."""
    if config.ray is not None:
        from lodsprite.distributed.pool.ray_pool import RayPool

        return RayPool(config.ray, config.renderers, config.data_dir, config.codec,
                       config.gpus_per_renderer)
    from lodsprite.distributed.pool import LocalPool

    pool = LocalPool(config.codec, config.data_dir)
    pool.spawn_local(config.renderers)
    return pool


async def _no_icon(request: web.Request) -> web.Response:
    """No icon (204), so a browser's console stays free of a 404."""
    return web.Response(status=204)


async def _going_away(ws: web.WebSocketResponse) -> None:
    """Close ``ws`` with code 1001 (going away); a peer that does not answer within
    :data:`CLOSE_S` s (or stopped reading) has its connection cut."""
    try:
        await asyncio.wait_for(ws.close(code=WSCloseCode.GOING_AWAY,
                                        message=b"server stopping"), CLOSE_S)
    except (TimeoutError, ConnectionError, RuntimeError):
        pass  # aiohttp closed the transport (a timeout) or it was gone already


def _closed_on_error(task: asyncio.Task, ws: web.WebSocketResponse) -> None:
    """A writer that failed (a page that stopped reading for too long, a broken
    connection) closes its WebSocket."""
    if task.cancelled() or task.exception() is None:
        return
    log.info("closing a session: %r", task.exception())
    asyncio.get_running_loop().create_task(ws.close())


async def _serve(config: WebConfig, on_url, stopped) -> None:
    server = WebServer(config)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    try:
        on_url(await server.start())
        from lodsprite.distributed.web.scene import warm_imports

        # the first page's imports, now (an error there is the first load's to report)
        loop.run_in_executor(None, warm_imports).add_done_callback(
            lambda f: f.cancelled() or f.exception())
        while not stopped():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.2)
                return
    finally:
        await server.stop()


def serve_web(config: WebConfig, on_url=log.info, stopped=lambda: False) -> None:
    """Serve until SIGINT or SIGTERM, or until ``stopped()`` (polled) says so;
    ``on_url(url)`` is called once serving."""
    asyncio.run(_serve(config, on_url, stopped))
