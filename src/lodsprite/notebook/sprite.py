"""``lodsprite.widget(...)``: a Jupyter widget (anywidget) that flies a terrain with
spriteframes drawn in the browser and keyframes rendered in the kernel's process tree.

Swan et al. 2002's client and server, in a notebook cell: the browser runs the web page's
client (``static/app.js``: WebGL2 spriteframes from the coarse level and the last
keyframe, requests ahead of the viewer) and the kernel runs the web server's hub, whose
renderer processes answer each request with a keyframe, sent as binary buffers over the
widget's messages (:mod:`.kernel`).  Only keyframes cross the wire, never every frame, so
a slow kernel or network costs image error, not frame rate.

From Python: :meth:`SpriteWidget.play`, :meth:`~SpriteWidget.stop`,
:attr:`~SpriteWidget.camera` (read and set), :attr:`~SpriteWidget.stats` (synced from the
browser four times a second), ``await`` :meth:`~SpriteWidget.screenshot` (a PNG of what
the browser shows) and :meth:`~SpriteWidget.played`, :meth:`~SpriteWidget.close`.
"""

from __future__ import annotations

import weakref
from pathlib import Path
from typing import Any

import anywidget
import numpy as np
import traitlets

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.notebook.bundle import widget_css, widget_esm
from lodsprite.notebook.home import at_home
from lodsprite.notebook.kernel import WidgetCore
from lodsprite.notebook.messages import STATS_KEYS, viewpoint_row
from lodsprite.notebook.source import check_path, path_played, resolve_source

__all__ = ["SpriteWidget"]


def _row(camera: Viewpoint | Any) -> list[float]:
    """A viewpoint (or 12 numbers: axes x, y, z, then the eye) as the wire's 12 numbers;
    raises :class:`InputError` unless the axes are orthonormal and all finite."""
    from lodsprite.distributed.protocol import ProtocolError, WireViewpoint, viewpoint_from_wire

    if isinstance(camera, Viewpoint):
        row = np.concatenate([camera.x, camera.y, camera.z, camera.o])
    else:
        try:
            row = np.asarray(camera, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InputError("camera: a Viewpoint or 12 numbers (x, y, z axes, eye)") from None
    if row.shape != (12,) or not np.all(np.isfinite(row)):
        raise InputError("camera: a Viewpoint or 12 finite numbers (x, y, z axes, eye)")
    r = row.tolist()
    try:
        viewpoint_from_wire(WireViewpoint(x=r[0:3], y=r[3:6], z=r[6:9], o=r[9:12]))
    except ProtocolError as exc:
        raise InputError(f"camera: {exc}") from None
    return r


class SpriteWidget(anywidget.AnyWidget):
    """A terrain flown in a notebook cell; see :func:`lodsprite.widget`."""

    _esm = widget_esm()
    _css = widget_css()
    options = traitlets.Dict().tag(sync=True)
    """What each view loads and plays (terrain name, size, lod, epsilon, visibility, proxy,
    grid, path, frames); set by the constructor and :meth:`play`."""

    def __init__(self, terrain: str | Path = "jacksboro", *, texture: str | Path = "terrain",
                 path: str | None = None, frames: int | None = None,
                 size: tuple[int, int] = (640, 480), lod: int | None = None,
                 epsilon: float | None = None, visibility: str | None = None,
                 proxy: str | None = None, grid: int | None = None, codec: str = "zlib",
                 renderers: int = 1) -> None:
        from lodsprite.distributed.web.server import page_options

        declared = {o["name"]: o for o in page_options()}
        defaults = {name: o["default"] for name, o in declared.items()}
        proxy = proxy or defaults["proxy"]
        if proxy not in declared["proxy"]["choices"]:
            raise InputError(f"proxy: got {proxy!r}, allowed: {declared['proxy']['allowed']}")
        source = resolve_source(terrain, texture, size=size, grid=grid,
                                lod=lod or defaults["lod"],
                                epsilon=epsilon or defaults["epsilon"],
                                visibility=visibility or defaults["visibility"])
        if path is not None:
            check_path(path, frames)
        a = source.load
        options = {"terrain": a.terrain, "texture": a.texture, "size": list(a.size),
                   "lod": a.lod, "epsilon": a.epsilon, "visibility": a.visibility,
                   "proxy": proxy, "grid": a.grid, "path": path, "frames": frames}
        super().__init__(options=options)
        self._core = WidgetCore(a, source.data_dir, self._to_front, codec, renderers)
        if path is not None:
            self._core.played = self._core.loop.create_future()
        self._finalizer = weakref.finalize(self, self._core.close)
        self.on_msg(self._on_front)

    # ------------------------------------------------------------------ plumbing

    def _to_front(self, content: dict, buffers: list) -> None:
        if self.comm is not None:
            self.send(content, buffers=buffers or None)

    def _on_front(self, _widget: Any, content: Any, buffers: list) -> None:
        at_home(self._core.loop, self._core.handle, content, buffers)  # maybe a subshell's

    # ---------------------------------------------------------------------- API

    def play(self, path: str = "chen1999", frames: int | None = None) -> None:
        """Play the built-in camera ``path`` (chen1999, swan2002, flyover[:...],
        patrol[:...], bank[:...]) over ``frames`` viewpoints (None: the path's own
        count), one a display frame, then hold its last view; raises
        :class:`InputError` for an unknown path."""
        check_path(path, frames)
        core = self._core
        core.played = core.loop.create_future()
        self.options = {**self.options, "path": path, "frames": frames}
        core.command({"kind": "play", "spec": path, "frames": frames})

    async def played(self, timeout: float = 120.0) -> int:
        """Wait (``await w.played()``) until the path :meth:`play` started has played
        and its held view's keyframe shows; the frames drawn.  Raises
        :class:`LodspriteError` when the view fails or ``timeout`` s pass."""
        return await path_played(self._core.played, timeout)

    def stop(self) -> None:
        """Stop a playing path where it is; the view is then flown by hand."""
        self._core.command({"kind": "stop"})

    @property
    def camera(self) -> Viewpoint | None:
        """The viewpoint the browser shows (as of its last status, at most 0.25 s old;
        None before one); set it to a :class:`~lodsprite.camera.Viewpoint` (or 12
        numbers) to move the view there."""
        status = self._core.status
        row = viewpoint_row(status.camera) if status is not None else None
        if row is None:
            return None
        return Viewpoint(np.array(row[0:3]), np.array(row[3:6]), np.array(row[6:9]),
                         np.array(row[9:12]))

    @camera.setter
    def camera(self, value: Viewpoint | Any) -> None:
        self._core.command({"kind": "camera", "viewpoint": _row(value)})

    @property
    def stats(self) -> dict[str, float | int | None]:
        """The browser's figures (at most 0.25 s old): ``frames``, ``keyframes`` shown,
        ``median_ms`` and ``p99_ms`` frame time, ``error_px`` (the shown frame's
        estimate) and ``error_px_mean`` (over the frames drawn), ``latency_ms`` (request
        to keyframe shown, median), ``input_ms`` (a key press to the frame showing it),
        and ``state`` (the view's status line)."""
        status = self._core.status
        got = status.stats if status is not None else {}
        out: dict[str, Any] = {k: got.get(k) for k in STATS_KEYS}
        for k in ("frames", "keyframes", "inputs"):
            out[k] = int(out[k] or 0)
        out["state"] = status.state if status is not None else "not shown"
        return out

    def reset_stats(self) -> None:
        """Start the browser's figures again (frames, keyframes, times, errors), e.g.
        once the first keyframe shows, to measure a path without the start-up."""
        self._core.status = None
        self._core.command({"kind": "reset"})

    @property
    def error(self) -> str:
        """The last failure a view reported (one line; empty: none)."""
        return self._core.error

    async def screenshot(self, timeout: float = 10.0) -> bytes:
        """A PNG (bytes) of what the browser shows (``await w.screenshot()``); raises
        :class:`LodspriteError` when no view shows the widget or none answers."""
        return await self._core.screenshot(timeout)

    def close(self) -> None:
        """Close the views, the sessions, the renderer processes (their GL contexts)
        and the widget; idempotent."""
        finalizer = getattr(self, "_finalizer", None)  # None: __init__ failed before it
        if finalizer is not None:
            finalizer()
        super().close()
