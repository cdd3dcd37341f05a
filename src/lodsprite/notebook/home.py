"""A widget's home: the event loop (and so the thread) it was made on, where everything
it does runs.

JupyterLab 4 and Notebook 7 send widget messages to a kernel subshell when the kernel has
subshells (ipykernel 7): the comm handlers, traitlets observers and jupyter_rfb's draws
they trigger then run on the subshell's thread, beside the cell's.  A future resolved
there never wakes the cell awaiting it (asyncio is not thread-safe), and a draw there
uses a GL context made on another thread.  So a widget hands each message from the
front end to its home loop (:func:`at_home`); without a loop (a plain script) it runs
where it is called.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

__all__ = ["at_home", "home_loop"]

log = logging.getLogger(__name__)


def home_loop() -> asyncio.AbstractEventLoop | None:
    """The running event loop of the calling thread (a kernel's), or None."""
    try:
        return asyncio.get_running_loop()
    except RuntimeError:
        return None


def at_home(loop: asyncio.AbstractEventLoop | None, fn: Callable[..., Any], *args: Any) -> None:
    """Call ``fn(*args)`` on ``loop``'s thread: at once when called there (or without a
    loop), else soon, through :meth:`~asyncio.loop.call_soon_threadsafe`.  A loop that
    has closed (the kernel shutting down) drops the call."""
    if loop is None or home_loop() is loop:
        fn(*args)
        return
    try:
        loop.call_soon_threadsafe(fn, *args)
    except RuntimeError:  # the loop is closed: nothing is listening any more
        log.debug("widget: dropped a message after its loop closed")
