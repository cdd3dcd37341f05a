"""A worker process driven from the frame's thread without waiting: requests and
answers over :mod:`multiprocessing.connection` pipes, bulk answers through slots of
:mod:`multiprocessing.shared_memory` (the one process mechanism: :mod:`lodsprite.procs`,
which says why a process and never a thread).

Every message, request or answer, is one ``send_bytes``: a header of three little-endian
int64 ``status, len(meta), len(data)``, then the two byte strings.  A request's status
names its slot (-1: none); an answer's is :data:`OK`, :data:`ERROR` (the handler's error
pickled, the process goes on) or :data:`IN_SLOT` (the data are in the request's slot of
the shared memory, only the header and meta came through the pipe); a process says
:data:`READY` once its handler is made, or :data:`START_FAILED` and why.  Slots matter
for large answers: 512² lumigraph nodes (768 KiB) through a 1 MiB pipe came about one a
frame, 8-10 nodes/s beside a busy draw loop, against 32-99 through slots.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import secrets
import signal
import struct
import time
from collections import deque
from collections.abc import Callable, Hashable
from multiprocessing import shared_memory
from multiprocessing.util import Finalize

from lodsprite.procs import (
    STOP_S,
    Child,
    HandlerError,
    WorkerDied,
    WorkerError,
    WorkerUnavailable,
    error_message,
    handler_error,
    load_factory,
)

__all__ = ["HandlerError", "ProcessWorker", "WorkerDied", "WorkerError",
           "WorkerUnavailable", "peak_rss_mb", "ready", "vm_hwm_mb"]

log = logging.getLogger(__name__)

HEAD = struct.Struct("<3q")  # status (a request: its slot), len(meta), len(data)
OK, ERROR, IN_SLOT, READY, START_FAILED = 0, 1, 2, 3, 4
PIPE_BYTES = 1 << 20        # answers a process can write ahead of the frame collecting them
MAX_REQUEST = 1024          # bytes; in flight at most in_flight of them: 64 KiB pipes never fill
READY_S = 60.0              # a process not ready this long after its start counts as dead
_F_SETPIPE_SZ = 1031

Handler = Callable[[bytes, bytes], tuple[bytes, bytes]]
Answer = tuple[bytes, bytes]


def _serve_main(factory: str, args: dict, requests, answers, shm_name: str | None,
                slot_bytes: int) -> None:
    """A :class:`ProcessWorker` process: make the handler, say ready, answer requests
    until the request pipe closes (its owner stopped or died)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C: the owner decides
    shm = None
    try:
        try:
            handler = load_factory(factory)(**args)
        except Exception as exc:  # noqa: BLE001 - reported to the owner: requests fail
            answers.send_bytes(HEAD.pack(START_FAILED, 0, 0) + error_message(exc))
            return
        shm = shared_memory.SharedMemory(shm_name) if shm_name else None
        answers.send_bytes(HEAD.pack(READY, 0, 0))
        _serve(handler, requests, answers, shm, slot_bytes)
    except (OSError, EOFError):  # the owner closed its ends (stopped, or gone): done
        pass
    finally:
        if shm is not None:
            shm.close()


def _serve(handler: Handler, requests, answers, shm, slot_bytes: int) -> None:
    while True:
        msg = requests.recv_bytes()
        slot, n_meta, _ = HEAD.unpack_from(msg)
        meta, data = msg[HEAD.size:HEAD.size + n_meta], msg[HEAD.size + n_meta:]
        try:
            out_meta, out_data = handler(meta, data)
        except Exception as exc:  # noqa: BLE001 - the handler's error, answered
            answers.send_bytes(HEAD.pack(ERROR, 0, 0) + error_message(exc))
            continue
        n = len(out_data)
        if shm is not None and slot >= 0 and n <= slot_bytes:
            shm.buf[slot * slot_bytes:slot * slot_bytes + n] = out_data
            answers.send_bytes(HEAD.pack(IN_SLOT, len(out_meta), n) + out_meta)
        else:
            answers.send_bytes(b"".join((HEAD.pack(OK, len(out_meta), n), out_meta,
                                         out_data)))


_LEN, _LONG_LEN = struct.Struct("!i"), struct.Struct("!Q")


def read_messages(fd: int, buf: bytearray) -> tuple[list[bytes], bool]:
    """The whole messages a :class:`multiprocessing.connection.Connection` wrote to the
    non-blocking pipe ``fd`` so far (its wire format, kept stable since Python 3.7: a
    big-endian int32 length, or -1 and a uint64 length, then the bytes), read in large
    chunks without waiting; a partial message stays in ``buf``.  Also whether the pipe
    has ended (the writer exited).  ``Connection.poll`` and ``recv_bytes`` cost a
    ``select`` and two reads a message, and ``recv_bytes`` waits for a message's end."""
    ended = False
    while True:
        try:
            chunk = os.read(fd, PIPE_BYTES)
        except BlockingIOError:
            break
        except OSError:
            ended = True
            break
        if not chunk:
            ended = True
            break
        buf += chunk
    out, at = [], 0
    with memoryview(buf) as view:
        while len(buf) - at >= _LEN.size:
            n, head = _LEN.unpack_from(buf, at)[0], _LEN.size
            if n == -1:
                if len(buf) - at < _LEN.size + _LONG_LEN.size:
                    break
                n = _LONG_LEN.unpack_from(buf, at + _LEN.size)[0]
                head += _LONG_LEN.size
            if len(buf) - at < head + n:
                break
            out.append(bytes(view[at + head:at + head + n]))
            at += head + n
    del buf[:at]
    return out, ended


class ProcessWorker:
    """A worker process driven from the frame's thread: :meth:`submit` a request under a
    key, :meth:`poll` for ``(key, answer)`` pairs in the order submitted (an answer is
    ``(meta, data)`` bytes, or a :class:`WorkerError`).  Neither ever waits.

    ``factory``: ``"module:name"``; in the process ``name(**args)`` makes the handler,
    ``handler(meta: bytes, data: bytes) -> (meta, data)``, called once per request.  At
    most ``in_flight`` requests are outstanding (:attr:`full`); the caller keeps the rest.
    With ``slot_bytes``, this object owns a shared-memory segment of ``in_flight`` slots
    of that size: each request in flight holds one, the process writes an answer's data
    that fits into it (the pipe carries the header and meta only), :meth:`poll` copies it
    out (the bytes are the caller's) and frees the slot; :meth:`close` unlinks the
    segment after the process is joined, and a dead process's slots stay this object's.
    A process that dies is started again, at most ``restarts`` times: the request it died
    on fails (:class:`WorkerDied`), the others are sent to the new process.  A process
    not ready within ``ready_s`` counts as dead.  ``max_request``: bytes a request may
    carry (``in_flight`` of them should fit the 64 KiB request pipe)."""

    def __init__(self, factory: str, args: dict, in_flight: int = 48, restarts: int = 3,
                 name: str = "worker", slot_bytes: int = 0,
                 max_request: int = MAX_REQUEST, ready_s: float = READY_S) -> None:
        self.factory, self.args, self.name = factory, dict(args), name
        self.in_flight, self.restarts = max(1, int(in_flight)), int(restarts)
        self.max_request, self.ready_s = int(max_request), float(ready_s)
        self.slot_bytes = max(0, int(slot_bytes))
        self.deaths = 0
        self.ready = False
        self._sent: deque[tuple[Hashable, bytes, bytes, int]] = deque()
        self._done: list[tuple[Hashable, Answer | WorkerError]] = []  # not yet polled
        self._gone: WorkerError | None = None  # why no process runs any more
        self.shm, self._free = None, [-1]
        if self.slot_bytes:
            self.shm = shared_memory.SharedMemory(
                f"lodsprite-{os.getpid()}-{secrets.token_hex(4)}", create=True,
                size=self.in_flight * self.slot_bytes)
            self._free = list(range(self.in_flight - 1, -1, -1))
        self._child: Child | None = None
        self._finalizer = Finalize(self, ProcessWorker._release_all,
                                   (self.__dict__,), exitpriority=20)
        self._start()

    def _start(self) -> None:
        ctx = mp.get_context("spawn")
        req_r, self._req = ctx.Pipe(duplex=False)
        self._ans, ans_w = ctx.Pipe(duplex=False)
        try:
            self._child = Child(_serve_main, (
                self.factory, self.args, req_r, ans_w,
                self.shm.name if self.shm is not None else None, self.slot_bytes),
                f"lodsprite-{self.name}".replace(" ", "-"))
        except OSError as exc:
            self._child = None
            self._gone = WorkerUnavailable(f"no {self.name} process ({exc})")
            log.error("%s process cannot start (%s): its requests fail", self.name, exc)
        finally:
            req_r.close()
            ans_w.close()
        with contextlib.suppress(OSError):  # a smaller pipe: fewer answers written ahead
            import fcntl

            fcntl.fcntl(self._ans.fileno(), _F_SETPIPE_SZ, PIPE_BYTES)
        os.set_blocking(self._ans.fileno(), False)  # read by read_messages alone
        self._buf = bytearray()
        self.ready, self._ready_by = False, time.monotonic() + self.ready_s

    @property
    def alive(self) -> bool:
        """Whether a process runs (requests can be answered)."""
        return self._child is not None

    @property
    def gone(self) -> WorkerError | None:
        """Why no process runs any more (its factory failed, it was not ready in time,
        it died more often than it may be restarted, it was closed); None while one may."""
        return self._gone

    @property
    def pid(self) -> int | None:
        return self._child.pid if self._child is not None else None

    @property
    def child(self) -> Child | None:
        """The process now (``pid``, ``is_alive()``); None while none runs."""
        return self._child

    @property
    def pending(self) -> list[Hashable]:
        """The keys of the requests in flight, oldest first."""
        return [k for k, _, _, _ in self._sent]

    @property
    def full(self) -> bool:
        return len(self._sent) >= self.in_flight

    def fileno(self) -> int:
        """The answer pipe's descriptor (readable when :meth:`poll` has something)."""
        return self._ans.fileno()

    def submit(self, key: Hashable, meta: bytes, data: bytes = b"", _slot: int | None = None
               ) -> bool:
        """Send a request (``meta + data`` at most ``max_request`` bytes); False, and
        nothing sent, while :attr:`full`."""
        if len(meta) + len(data) > self.max_request:
            raise ValueError(f"a worker request of {len(meta) + len(data)} bytes")
        if self.full:
            return False
        if self._child is None:
            if _slot is not None and _slot >= 0:
                self._free.append(_slot)
            self._done.append((key, self._gone or WorkerUnavailable(f"no {self.name}")))
            return True
        slot = _slot if _slot is not None else (self._free.pop() if self.shm else -1)
        self._sent.append((key, meta, data, slot))
        try:
            self._req.send_bytes(HEAD.pack(slot, len(meta), len(data)) + meta + data)
        except OSError as exc:
            self._died(f"its pipe broke ({exc})")
        return True

    def wait_ready(self, timeout: float) -> bool:
        """Wait (setup only) until the process is ready or ``timeout`` s pass."""
        deadline = time.monotonic() + timeout
        while not self.ready and self._child is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            if self._ans.poll(min(left, 0.1)):
                got = self.poll()
                self._done = got + self._done
        return self.ready

    def poll(self) -> list[tuple[Hashable, Answer | WorkerError]]:
        """What has been answered since the last call, in the order submitted."""
        out, self._done = self._done, []
        if self._child is not None:
            msgs, ended = read_messages(self._ans.fileno(), self._buf)
            for msg in msgs:
                self._message(msg)
            if ended and self._child is not None:
                self._died(f"it exited (code {self._child.exitcode})")
        if self._child is not None and not self.ready and time.monotonic() > self._ready_by:
            self._died(f"not ready in {self.ready_s:.0f} s")
        out += self._done
        self._done = []
        return out

    def _message(self, msg: bytes) -> None:
        status, n_meta, n_data = HEAD.unpack_from(msg)
        if status == READY:
            self.ready = True
            return
        if status == START_FAILED:
            err = handler_error(msg[HEAD.size:])
            self._stop_child()
            self._gone = WorkerUnavailable(f"the {self.name} process cannot start: {err}")
            log.error("%s", self._gone)
            self._resend()
            return
        key, _, _, slot = self._sent.popleft()
        answer: Answer | WorkerError
        if status == ERROR:
            answer = handler_error(msg[HEAD.size:])
        elif status == IN_SLOT:
            at = slot * self.slot_bytes
            answer = (msg[HEAD.size:HEAD.size + n_meta], bytes(self.shm.buf[at:at + n_data]))
        else:
            answer = (msg[HEAD.size:HEAD.size + n_meta], msg[HEAD.size + n_meta:])
        if slot >= 0:
            self._free.append(slot)
        self._done.append((key, answer))

    def _resend(self) -> None:
        resend, self._sent = list(self._sent), deque()
        for key, meta, data, slot in resend:
            self.submit(key, meta, data, _slot=slot)

    def _stop_child(self) -> None:
        self._req.close()
        self._ans.close()
        if self._child is not None:
            self._child.stop(STOP_S)
            self._child = None

    def _died(self, why: str) -> None:
        self._stop_child()
        self.deaths += 1
        if self._sent:  # the request it died on fails; the others are sent again
            key, _, _, slot = self._sent.popleft()
            if slot >= 0:
                self._free.append(slot)
            self._done.append((key, WorkerDied(f"the {self.name} process died on it "
                                                 f"({why})")))
        again = self.deaths <= self.restarts
        log.warning("%s process stopped (%s)%s", self.name, why,
                    ": started again" if again else "")
        if again:
            self._start()
        else:
            self._gone = WorkerUnavailable(f"no {self.name} process (it died {self.deaths} "
                                           f"times; last: {why})")
        self._resend()

    def peak_mb(self) -> float:
        """The process's peak resident memory (``VmHWM``) in MB; 0 when unknown."""
        peak = vm_hwm_mb(self._child.pid) if self._child is not None else None
        return 0.0 if peak is None else peak

    def close(self) -> None:
        """End the process (it finishes the request in hand, else it is terminated) and
        unlink the shared memory; what is in flight is lost.  Idempotent."""
        self._finalizer()

    @staticmethod
    def _release_all(state: dict) -> None:
        for c in ("_req", "_ans"):
            if c in state:
                state[c].close()
        if state.get("_child") is not None:
            state["_child"].stop(STOP_S)
            state["_child"] = None
        state["_gone"] = state.get("_gone") or WorkerUnavailable("closed")
        state["_sent"].clear()
        if state["shm"] is not None:
            state["shm"].close()
            state["shm"].unlink()
            state["shm"] = None


def ready(sockets: list, poller=None) -> list:
    """The ZeroMQ sockets of ``sockets`` with a message waiting, at once (a zero-timeout
    poll: the frame's thread never waits on the network).  ``poller``: a ``zmq.Poller``
    holding them, reused from call to call."""
    import zmq

    if poller is None:
        poller = zmq.Poller()
        for s in sockets:
            poller.register(s, zmq.POLLIN)
    return [s for s, _ in poller.poll(0)]


def vm_hwm_mb(pid: int | str = "self") -> float | None:
    """Peak resident memory (``VmHWM`` of ``/proc/PID/status``) in MB; None where there
    is no such file (another system, a process gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_rss_mb() -> float:
    """This process's peak resident memory in MB: ``VmHWM``, which starts afresh at
    ``exec`` (``getrusage``'s ``ru_maxrss`` keeps the peak of the process that forked it),
    else ``ru_maxrss``."""
    peak = vm_hwm_mb()
    if peak is not None:
        return peak
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KB on Linux
