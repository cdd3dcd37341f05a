"""The one way to run a process beside the frame loop: the standard library's
``multiprocessing`` (spawn context, :mod:`multiprocessing.connection`,
:mod:`multiprocessing.shared_memory`); this module is its lifecycle and its errors,
:mod:`lodsprite.workers` the request/answer worker built on it.

moderngl holds the GIL through each draw call (the whole llvmpipe rasterisation), so a
Python thread beside the draws runs only between them: a Zarr read of 1.9 ms took 113 ms
beside a busy draw loop, and a lumigraph node loader thread decoded 6.5-31.5 nodes a
second there where it decoded 226-521 alone (its process: 50-101; ``benchmarks/
beside_draws.py``).  So work beside the draws (reading, decoding, rendering elsewhere)
runs in a child process with its own GIL, and I/O that only waits (sockets) is polled
without waiting on the frame's thread itself (:func:`lodsprite.workers.ready`); never in
a Python thread.

Three shapes, one lifecycle (:class:`Child`: started with the spawn context, stopped by
closing its input or telling it, then ``terminate``, then ``kill``, each with a
deadline, and joined: no zombie; stopped at interpreter exit if its owner forgot):

* :class:`~lodsprite.workers.ProcessWorker`: requests and answers (the tile reader, the
  node decoder, a render worker's GL process, the LOD-sprite keyframe worker),
  submitted and polled from the frame's thread without waiting; bulk answers come back
  through a bounded number of shared-memory slots.
* :func:`call_in_child`: one call in a fresh process (a run whose peak memory is its own).
* :func:`start_child`: a long-running process that talks for itself (a pool worker).

The error contract: a request's answer is ``(meta, data)`` or a :class:`WorkerError`,
never a wait: :class:`HandlerError` (the child's code raised; the process goes on),
:class:`WorkerDied` (the process died with the request in hand; noticed by the end of
its pipe) or :class:`WorkerUnavailable` (no process: its factory failed, it was not
ready in time, or it died more often than it may be restarted).

A child never imports the caller's ``__main__`` (spawn's default would run a script's
top level again): its target is a function of a package module.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
import types
from collections.abc import Callable
from multiprocessing.util import Finalize

from lodsprite.errors import LodspriteError

STOP_S = 2.0  # a stopping process has this long to exit by itself

log = logging.getLogger(__name__)


def lower_priority(nice: int) -> None:
    """Raise the nice value of every thread of this process by ``nice`` (Linux threads
    have their own, and threads started later, a GL driver's included, inherit their
    creator's): a child process drawing beside a display (a keyframe worker, a page's
    renderer on the page's machine) yields the CPU to the frames shown.  Call it in the
    child, never in a display's process.  Ignored where the platform has no per-thread
    priority."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [threading.get_native_id()]
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
        except OSError as exc:  # a thread gone meanwhile, or not permitted
            log.debug("could not lower thread %d's priority: %s", tid, exc)


class WorkerError(LodspriteError, RuntimeError):
    """Why a request got no answer (returned by :meth:`lodsprite.workers.ProcessWorker.
    poll`, raised by :func:`call_in_child`); ``text``: one line."""

    @property
    def text(self) -> str:
        return str(self)


class HandlerError(WorkerError):
    """The child's code raised: ``type_name`` and, when it could be carried back,
    ``cause`` (the exception itself)."""

    def __init__(self, text: str, type_name: str = "", cause: BaseException | None = None):
        super().__init__(text)
        self.type_name, self.cause = type_name, cause


class WorkerDied(WorkerError):
    """The process died (was killed, crashed, exited) with the request in hand."""


class WorkerUnavailable(WorkerError):
    """No process to answer: its factory failed, it was not ready within its deadline,
    or it died more often than it may be restarted."""


def load_factory(spec: str) -> Callable:
    """``"package.module:name"`` -> the callable it names."""
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


@contextlib.contextmanager
def _without_main():
    """Spawn's preparation data name the caller's ``__main__`` for the child to import
    again; for the time of a start, the main module is an empty one."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


class Child:
    """One process started with the spawn context running ``target(*args)`` (a
    module-level function; ``args`` picklable: connections included).  :meth:`stop`
    ends it within a deadline; it is stopped at exit if its owner did not."""

    def __init__(self, target: Callable, args: tuple = (), name: str = "lodsprite-child"
                 ) -> None:
        self.name = name
        self.process = mp.get_context("spawn").Process(target=target, args=args, name=name)
        with _without_main():
            self.process.start()
        self.pid: int = self.process.pid
        self._code: int | None = None
        self._finalizer = Finalize(self, _stop_process, (self.process, 0.5), exitpriority=10)

    @property
    def alive(self) -> bool:
        return self._finalizer.still_active() and self.process.is_alive()

    @property
    def exitcode(self) -> int | None:
        """Its exit code (negative: the signal that ended it); None while it runs."""
        return self.process.exitcode if self._finalizer.still_active() else self._code

    def is_alive(self) -> bool:
        return self.alive

    def stop(self, timeout: float = STOP_S) -> None:
        """Wait ``timeout`` s for it to exit (its owner told it to, or closed its input),
        then terminate, then kill; joined either way.  Idempotent."""
        if self._finalizer.still_active():
            self._finalizer.cancel()
            self._code = _stop_process(self.process, timeout)


def _stop_process(p, timeout: float) -> int | None:
    """Join ``p`` (then terminate, then kill it); its exit code."""
    try:
        p.join(timeout)
        for end in (p.terminate, p.kill):
            if p.is_alive():
                end()
                p.join(2.0)
        code = p.exitcode
        if code is not None:
            p.close()
        return code
    except ValueError:  # closed already
        return None


def stop_children(children: list[Child], timeout: float = STOP_S) -> None:
    """Stop ``children`` under one deadline (each was told to exit)."""
    deadline = time.monotonic() + timeout
    for c in children:
        c.stop(max(0.0, deadline - time.monotonic()))


def start_child(target: Callable, args: tuple = (), name: str = "lodsprite-child") -> Child:
    """A long-running process beside this one; stop it with :meth:`Child.stop`."""
    return Child(target, args, name)


def error_message(exc: BaseException) -> bytes:
    """``(text, type name, the exception pickled or None)`` pickled."""
    text = f"{type(exc).__name__}: {exc}"[:4096]
    try:
        carried = pickle.dumps(exc)
        pickle.loads(carried)
    except Exception:  # noqa: BLE001 - not every exception travels
        carried = None
    return pickle.dumps((text, type(exc).__name__, carried))


def handler_error(message: bytes) -> HandlerError:
    text, type_name, carried = pickle.loads(message)
    cause = None
    if carried is not None:
        with contextlib.suppress(Exception):
            cause = pickle.loads(carried)
    return HandlerError(text, type_name, cause)


def _call_main(target: Callable, args: tuple, out) -> None:
    """A :func:`call_in_child` process: the result, or the error, pickled."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        msg = b"R" + pickle.dumps(target(*args))
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the caller
        msg = b"E" + error_message(exc)
    with contextlib.suppress(OSError):  # the caller gone: nobody to tell
        out.send_bytes(msg)
    out.close()


def call_in_child(target: Callable, *args, name: str = "lodsprite-call",
                  timeout: float | None = None):
    """``target(*args)`` in a fresh process (its own memory, its own peak); waits for it.
    Raises the child's own exception (a :class:`HandlerError` when it cannot travel),
    :class:`WorkerDied` if the process ends without an answer or ``timeout`` passes."""
    r, w = mp.get_context("spawn").Pipe(duplex=False)
    child = Child(_call_main, (target, args, w), name)
    w.close()
    try:
        if not r.poll(timeout):
            raise WorkerDied(f"{name}: no answer in {timeout} s")
        msg = r.recv_bytes()
    except EOFError:
        child.stop(1.0)
        raise WorkerDied(f"{name} ended without an answer (exit code "
                         f"{child.exitcode})") from None
    finally:
        r.close()
        child.stop()
    if msg[:1] == b"R":
        return pickle.loads(msg[1:])
    err = handler_error(msg[1:])
    if err.cause is not None:
        raise err.cause from err
    raise err
