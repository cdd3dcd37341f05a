"""The kernel side of a notebook widget: the web server's hub and sessions, carried over
the widget's messages instead of WebSockets.

One :class:`WidgetCore` per widget.  It owns a render pool of local renderer processes
(:class:`~lodsprite.distributed.pool.LocalPool`: keyframes are rendered in the kernel's
process tree, never in the kernel's own thread, so the kernel stays responsive) and a
:class:`~lodsprite.distributed.web.hub.Hub` on the kernel's event loop.  Each view of the
widget (each output showing it) is one :class:`~lodsprite.distributed.web.sessions.Session`,
made when the view's first message arrives (at most :data:`MAX_VIEWS`); its messages go
through :meth:`Session.handle`, the web server's validation, and its replies, scene and
keyframes come back as binary buffers through the session's writer.

Everything here runs on the kernel's event loop (ipykernel 6 and later run one): the
hub's tasks progress between cells and while a cell awaits, so ``await
w.screenshot()`` and ``await w.played()`` let the widget's messages in.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.protocol import LoadArgs, ProtocolError
from lodsprite.distributed.web.hub import Hub
from lodsprite.distributed.web.sessions import Caps, Session
from lodsprite.errors import LodspriteError
from lodsprite.notebook.messages import (
    Closed,
    Failed,
    Played,
    Shot,
    Status,
    Wire,
    decode_front,
)

log = logging.getLogger("lodsprite.notebook")

__all__ = ["MAX_VIEWS", "WidgetCore", "WidgetHub"]

MAX_VIEWS = 8
"""Views of one widget served at once (each a session); another is not served."""


class WidgetHub(Hub):
    """A hub that loads one scene only: the widget's own (``named``), as Python named
    it; a ``load`` from the browser naming another terrain or texture is refused."""

    def __init__(self, pool: Any, datasets: Datasets, named: LoadArgs, **kw: Any) -> None:
        super().__init__(pool, datasets, **kw)
        self.named = named

    def load(self, session: Session, args: LoadArgs, seq: int) -> None:
        if (args.terrain, args.texture) != (self.named.terrain, self.named.texture):
            session.reply(seq, False, f"load: this widget shows {self.named.terrain} "
                                      f"with {self.named.texture} only")
            return
        super().load(session, args, seq)


class WidgetCore:
    """Pool, hub and sessions of one widget.  ``send(content, buffers)`` sends one custom
    message to the front end.  Create it inside the kernel's running event loop; raises
    :class:`LodspriteError` without one."""

    def __init__(self, named: LoadArgs, data_dir: Any, send: Callable[[dict, list], None],
                 codec: str = "zlib", renderers: int = 1, caps: Caps | None = None) -> None:
        from lodsprite.distributed.pool import LocalPool

        try:
            self.loop = asyncio.get_running_loop()
        except RuntimeError:
            raise LodspriteError("a lodsprite widget runs in a Jupyter kernel (or inside a "
                                 "running asyncio event loop)") from None
        self.send = send
        self.pool = LocalPool(codec, data_dir)
        try:
            self.pool.spawn_local(renderers)
            self.hub = WidgetHub(self.pool, Datasets(data_dir), named,
                                 caps=caps or Caps(rate=1000.0), codec=codec)
            self.hub.start()
        except BaseException:
            self.pool.close()
            raise
        self.views: dict[str, tuple[Session, asyncio.Task]] = {}
        self.status: Status | None = None
        self.error = ""
        self.counts = {"rejected": 0, "views_refused": 0}
        self.shots: dict[int, asyncio.Future] = {}
        self.played: asyncio.Future | None = None
        self.closed = False

    # -------------------------------------------------------------------- in

    def handle(self, content: Any, buffers: list | None) -> None:
        """Take one custom message from a front end; never raises."""
        try:
            msg, data = decode_front(content, buffers)
        except ProtocolError as exc:
            self.counts["rejected"] += 1
            log.warning("widget: rejected a message: %s", exc)
            return
        try:
            self._dispatch(msg, data)
        except Exception as exc:  # noqa: BLE001 - a bug must not break the kernel's loop
            log.error("widget: internal error handling a message: %r", exc)

    def _dispatch(self, msg: Any, data: bytes | None) -> None:
        if isinstance(msg, Wire):
            session = self._session(msg.view)
            if session is not None:
                session.handle(data)
        elif isinstance(msg, Status):
            if msg.view in self.views:
                self.status = msg
        elif isinstance(msg, Played):
            if self.played is not None and not self.played.done():
                self.played.set_result(msg.frames)
        elif isinstance(msg, Failed):
            self.error = msg.error.splitlines()[0] if msg.error else "failed"
            if self.played is not None and not self.played.done():
                self.played.set_exception(LodspriteError(f"widget: {self.error}"))
        elif isinstance(msg, Shot):
            future = self.shots.pop(msg.id, None)
            if future is not None and not future.done():
                future.set_result(data)
        elif isinstance(msg, Closed):
            self._drop(msg.view)

    def _session(self, view: str) -> Session | None:
        """The session of ``view``, made on its first message (None: too many views)."""
        if view in self.views:
            return self.views[view][0]
        if self.closed or len(self.views) >= MAX_VIEWS:
            self.counts["views_refused"] += 1
            return None
        session = self.hub.open_session()

        async def send(data: bytes) -> None:
            self.send({"kind": "wire", "view": view}, [data])

        writer = self.loop.create_task(session.run_writer(send))
        writer.add_done_callback(lambda task: self._writer_done(view, task))
        self.views[view] = (session, writer)
        return session

    def _writer_done(self, view: str, task: asyncio.Task) -> None:
        """A writer that failed ends its view's session (logged once), as a WebSocket's
        does on the web server."""
        if task.cancelled() or task.exception() is None:
            return
        log.warning("widget: view %s stopped: %r", view, task.exception())
        self._drop(view)

    def _drop(self, view: str) -> None:
        entry = self.views.pop(view, None)
        if entry is not None:
            session, writer = entry
            self.hub.close_session(session)
            writer.cancel()

    # ------------------------------------------------------------------- out

    def command(self, content: dict) -> None:
        """Send a command (play, stop, camera) to every view."""
        if self.closed:
            raise LodspriteError("this widget is closed")
        self.send(content, [])

    async def screenshot(self, timeout: float) -> bytes:
        """A PNG of what a view shows (the first to answer); raises
        :class:`LodspriteError` with no view or no answer within ``timeout`` s."""
        if not self.views:
            raise LodspriteError("no view shows this widget: display it (its cell's "
                                 "value) first")
        shot = max(self.shots, default=0) + 1
        future = self.loop.create_future()
        self.shots[shot] = future
        self.command({"kind": "shot", "id": shot})
        try:
            return await asyncio.wait_for(future, timeout)
        except TimeoutError:
            raise LodspriteError(f"no screenshot within {timeout:g} s") from None
        finally:
            self.shots.pop(shot, None)

    def close(self) -> None:
        """End the sessions, the hub and the renderer processes (idempotent)."""
        if self.closed:
            return
        self.closed = True
        for view in list(self.views):
            self._drop(view)
        with contextlib.suppress(Exception):
            self.hub.close()
        self.pool.close()
        for future in [*self.shots.values(), self.played]:
            if future is not None and not future.done():
                future.cancel()
