"""Work beside the draws, driven from the frame's own thread without waiting.

moderngl holds the GIL through each draw call (the whole llvmpipe rasterisation), so a
Python thread beside the draws runs only between them: a Zarr read of 1.9 ms took 113 ms
beside a busy draw loop, and a lumigraph node loader thread decoded 6.5-31.5 nodes a
second there where it decoded 226-521 alone (its process: 50-101; ``benchmarks/
beside_draws.py``, two runs on a shared 2-core machine).  So nothing runs
beside the draws as a thread.  Work that takes time (reading, decoding) runs in a child
process, with its own GIL, and the frame's thread talks to it through pipes, without
ever waiting: :class:`ProcessWorker`.  I/O that only waits (sockets) is polled without
waiting on the frame's thread itself (:func:`ready`, used by the distributed client).
Both give the same interface: a non-blocking ``poll()`` returning what has arrived.

A worker process is ``python -m lodsprite.workers MODULE:FACTORY ARGS_JSON`` (not
``multiprocessing``, whose spawn re-imports the caller's main script):
``FACTORY(**ARGS)`` makes the handler, called once per request as
``handler(meta: bytes, data: bytes) -> (meta: bytes, data: bytes)``.  Every message on
the pipes, request or answer, is a header of three little-endian int64 ``status,
len(meta), len(data)`` and then the two byte strings; an answer's status is 0, or 1 with
the handler's error as ``meta`` text (the process goes on), or 2: the data are in the
request's slot of memory shared with the caller (``slot_bytes``; the request's status
field names the slot), and only the header and meta came through the pipe.  Slots matter
for large answers: 512² lumigraph nodes (768 KiB) through the 1 MiB pipe came about one
a frame, 8-10 nodes/s beside a busy draw loop, against 32-99 through slots (129-151
alone, against 56-100).
"""

from __future__ import annotations

import fcntl
import importlib
import json
import logging
import mmap
import os
import struct
import subprocess
import sys
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass

log = logging.getLogger(__name__)

HEAD = struct.Struct("<3q")
OK, ERROR, IN_SLOT = 0, 1, 2
PIPE_BYTES = 1 << 20        # answers a process can write ahead of the frame collecting them
MAX_REQUEST = 1024          # bytes; in flight at most in_flight of them: 64 KiB pipes never fill
MAX_ANSWER = 1 << 30
_F_SETPIPE_SZ = 1031

Handler = Callable[[bytes, bytes], tuple[bytes, bytes]]


@dataclass(frozen=True)
class Failure:
    """Why a request got no answer: the handler's error, or the process's death."""

    text: str


def _read_exact(f, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = f.read(n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return bytes(buf)


def serve(handler: Handler, fin, fout, slots: memoryview | None = None,
          slot_bytes: int = 0) -> None:
    """The process's loop: answer requests from ``fin`` on ``fout`` (binary files) until
    ``fin`` closes; an exception of the handler is answered as an error.  With ``slots``
    (shared memory of ``slot_bytes`` a slot), an answer's data that fits goes into the
    slot its request names (the request's status field) and only its header and meta
    through the pipe (status :data:`IN_SLOT`)."""
    while True:
        try:
            slot, n_meta, n_data = HEAD.unpack(_read_exact(fin, HEAD.size))
            meta, data = _read_exact(fin, n_meta), _read_exact(fin, n_data)
        except EOFError:
            return
        try:
            out_meta, out_data = handler(meta, data)
            status = OK
            if slots is not None and 0 <= slot and len(out_data) <= slot_bytes:
                slots[slot * slot_bytes:slot * slot_bytes + len(out_data)] = out_data
                status = IN_SLOT
            fout.write(HEAD.pack(status, len(out_meta), len(out_data)))
            fout.write(out_meta)
            if status == OK:
                fout.write(out_data)
        except Exception as exc:  # the handler's own error, returned to the caller
            text = f"{type(exc).__name__}: {exc}".encode()[:4096]
            fout.write(HEAD.pack(ERROR, len(text), 0) + text)
        fout.flush()


def main(argv: list[str]) -> None:
    """The worker process: ``MODULE:FACTORY ARGS_JSON [SLOTS_FD SLOT_BYTES]``."""
    handler = load_factory(argv[0])(**json.loads(argv[1]))
    slots, slot_bytes = None, 0
    if len(argv) > 3:
        fd, slot_bytes = int(argv[2]), int(argv[3])
        slots = memoryview(mmap.mmap(fd, os.fstat(fd).st_size))
    serve(handler, sys.stdin.buffer, sys.stdout.buffer, slots, slot_bytes)


def load_factory(spec: str) -> Callable[..., Handler]:
    """``"package.module:name"`` -> the callable it names."""
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


class _Pipes:
    """One running process: requests written to its stdin, answers read from its stdout
    without blocking and parsed as they complete; with ``slots`` (an anonymous shared
    mapping of ``slot_bytes`` a slot, passed as a file descriptor) answers' data come
    back through it."""

    def __init__(self, factory: str, args: dict, slots: tuple[int, int] | None) -> None:
        cmd = [sys.executable, "-m", "lodsprite.workers", factory, json.dumps(args)]
        if slots is not None:
            cmd += [str(slots[0]), str(slots[1])]
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            pass_fds=(slots[0],) if slots is not None else ())
        self._in, self._out = self.proc.stdin.fileno(), self.proc.stdout.fileno()
        try:
            fcntl.fcntl(self._out, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:  # a smaller pipe only means fewer answers written ahead
            pass
        os.set_blocking(self._out, False)
        self._buf = bytearray()
        self.dead = False  # its stdout closed: the answers before that are still given

    def send(self, slot: int, meta: bytes, data: bytes) -> None:
        os.write(self._in, HEAD.pack(slot, len(meta), len(data)) + meta + data)

    def answers(self) -> list[tuple[int, bytes, int | bytes]]:
        """``(status, meta, data)`` complete so far; for :data:`IN_SLOT` ``data`` is the
        length of what the slot holds."""
        while True:
            try:
                chunk = os.read(self._out, PIPE_BYTES)
            except BlockingIOError:
                break
            if not chunk:
                self.dead = True
                break
            self._buf += chunk
        out: list[tuple[int, bytes, int | bytes]] = []
        while len(self._buf) >= HEAD.size:
            status, n_meta, n_data = HEAD.unpack_from(self._buf)
            if not (0 <= n_meta <= MAX_ANSWER and 0 <= n_data <= MAX_ANSWER):
                self.dead = True  # a garbled stream: nothing more of it can be trusted
                break
            end = HEAD.size + n_meta + (0 if status == IN_SLOT else n_data)
            if len(self._buf) < end:
                break
            meta = bytes(self._buf[HEAD.size:HEAD.size + n_meta])
            data = n_data if status == IN_SLOT else bytes(self._buf[HEAD.size + n_meta:end])
            del self._buf[:end]
            out.append((status, meta, data))
        return out

    def peak_mb(self) -> float:
        peak = vm_hwm_mb(self.proc.pid)
        return 0.0 if peak is None else peak

    def close(self) -> None:
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=2.0)


class ProcessWorker:
    """A worker process driven from the frame's thread: :meth:`submit` a request under a
    key, :meth:`poll` for ``(key, answer)`` pairs in the order submitted (an answer is
    ``(meta, data)`` bytes, or a :class:`Failure`).  Neither ever waits.

    At most ``in_flight`` requests are outstanding (:attr:`full`); the caller keeps the
    rest.  With ``slot_bytes``, each request in flight holds a slot of that many bytes of
    memory shared with the process, and answers' data that fit come back through it (the
    pipe carries headers only, so a frame that collects late never stalls the process on
    a full pipe).  A process that dies is started again, at most ``restarts`` times: the
    request it died on fails, the others are sent to the new process.  After that, or
    when no process can start, every request fails at once ("no worker process").
    ``max_request``: bytes a request may carry; ``in_flight`` of them should fit the
    process's 64 KiB stdin pipe (beyond it :meth:`submit` waits for the process to read)."""

    def __init__(self, factory: str, args: dict, in_flight: int = 48, restarts: int = 3,
                 name: str = "worker", slot_bytes: int = 0,
                 max_request: int = MAX_REQUEST) -> None:
        self.factory, self.args, self.name = factory, dict(args), name
        self.in_flight, self.restarts = max(1, int(in_flight)), int(restarts)
        self.max_request = int(max_request)
        self.slot_bytes = max(0, int(slot_bytes))
        self.deaths = 0
        self._sent: deque[tuple[Hashable, bytes, bytes, int]] = deque()
        self._failed: list[tuple[Hashable, Failure]] = []
        self._fd, self._map, self._free = -1, None, [-1]
        if self.slot_bytes:
            self._fd = os.memfd_create(f"lodsprite-{name}".replace(" ", "-"))
            os.ftruncate(self._fd, self.in_flight * self.slot_bytes)
            self._map = mmap.mmap(self._fd, self.in_flight * self.slot_bytes)
            self._free = list(range(self.in_flight - 1, -1, -1))
        self._pipes = self._start()

    def _start(self) -> _Pipes | None:
        try:
            return _Pipes(self.factory, self.args,
                          (self._fd, self.slot_bytes) if self._map is not None else None)
        except OSError as exc:
            log.error("%s process cannot start (%s): its requests fail", self.name, exc)
            return None

    @property
    def alive(self) -> bool:
        """Whether a process runs (requests can be answered)."""
        return self._pipes is not None

    @property
    def pid(self) -> int | None:
        return self._pipes.proc.pid if self._pipes is not None else None

    @property
    def pending(self) -> list[Hashable]:
        """The keys of the requests in flight, oldest first."""
        return [k for k, _, _, _ in self._sent]

    @property
    def full(self) -> bool:
        return len(self._sent) >= self.in_flight

    def submit(self, key: Hashable, meta: bytes, data: bytes = b"", _slot: int | None = None
               ) -> bool:
        """Send a request (``meta + data`` at most ``max_request`` bytes); False, and
        nothing sent, while :attr:`full`."""
        if len(meta) + len(data) > self.max_request:
            raise ValueError(f"a worker request of {len(meta) + len(data)} bytes")
        if self.full:
            return False
        if self._pipes is None:
            if _slot is not None:
                self._release(_slot)
            self._failed.append((key, Failure(f"no {self.name} process")))
            return True
        slot = _slot if _slot is not None else (self._free.pop() if self._map else -1)
        self._sent.append((key, meta, data, slot))
        try:
            self._pipes.send(slot, meta, data)
        except OSError as exc:
            self._died(exc)
        return True

    def _release(self, slot: int) -> None:
        if slot >= 0:
            self._free.append(slot)

    def _answer(self, status: int, meta: bytes, data, slot: int):
        if status == ERROR:
            return Failure(meta.decode(errors="replace"))
        if status == IN_SLOT:
            data = self._map[slot * self.slot_bytes:slot * self.slot_bytes + data]
        return meta, data

    def poll(self) -> list[tuple[Hashable, tuple[bytes, bytes] | Failure]]:
        """What has been answered since the last call, in the order submitted."""
        out, self._failed = self._failed, []
        if self._pipes is None:
            return out
        for status, meta, data in self._pipes.answers():
            key, _, _, slot = self._sent.popleft()
            out.append((key, self._answer(status, meta, data, slot)))
            self._release(slot)
        if self._pipes.dead:
            self._died(OSError(f"the {self.name} process has stopped"))
            out += self._failed
            self._failed = []
        return out

    def _died(self, exc: Exception) -> None:
        self._pipes.close()
        self.deaths += 1
        if self._sent:  # the request it died on fails; the others are sent again
            key, _, _, slot = self._sent.popleft()
            self._release(slot)
            self._failed.append((key, Failure(f"the {self.name} process died on it ({exc})")))
        again = self.deaths <= self.restarts
        log.warning("%s process stopped (%s)%s", self.name, exc,
                    ": started again" if again else "")
        self._pipes = self._start() if again else None
        resend, self._sent = list(self._sent), deque()
        for key, meta, data, slot in resend:
            self.submit(key, meta, data, _slot=slot)

    def peak_mb(self) -> float:
        """The process's peak resident memory (``VmHWM``) in MB; 0 when unknown."""
        return self._pipes.peak_mb() if self._pipes is not None else 0.0

    def close(self) -> None:
        """End the process (it finishes the request in hand); what is in flight is lost."""
        if self._pipes is not None:
            self._pipes.close()
            self._pipes = None
        for _, _, _, slot in self._sent:
            self._release(slot)
        self._sent.clear()
        if self._map is not None:
            self._map.close()
            os.close(self._fd)
            self._map, self._fd = None, -1


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


if __name__ == "__main__":
    main(sys.argv[1:])
