"""A terrain store's tiles read by a process of their own, collected without waiting by
the thread that draws.

Zarr v3 reads a window through its asyncio event-loop thread and a codec pool: one read
of a 65² node hands the GIL between threads some twenty times.  While the frame's thread
holds the GIL (moderngl keeps it through each draw call, for the whole llvmpipe
rasterisation), every hand-off waits for the draw to end: a read taking 1.9 ms alone took
113 ms beside a busy Python thread, and a loader *thread* fed the adaptive renderer about
one tile a frame.  So the reads run in a separate process (its own GIL), and the frame's
own thread sends requests and collects answers with non-blocking pipe I/O: no thread
hand-off at all, and a frame never waits.

The process is ``python -m lodsprite.terrain.reader STORE EXAGGERATION`` (not
``multiprocessing``, whose spawn re-imports the caller's main script).  Requests on its
stdin are five little-endian int64 ``k, r0, r1, c0, c1``; each answer on its stdout is a
header of three int64 ``status, a, b`` then, for status 0, ``a * b`` float32 samples, else
an error text of ``a`` bytes.
"""

from __future__ import annotations

import fcntl
import logging
import os
import struct
import subprocess
import sys

import numpy as np

log = logging.getLogger(__name__)

MAX_WINDOW = 4097 * 4097  # samples: no request may ask for more
PIPE_BYTES = 1 << 20      # answers the process can write ahead of the frame collecting them
_REQ = struct.Struct("<5q")
_HEAD = struct.Struct("<3q")
_F_SETPIPE_SZ = 1031


def _read_exact(f, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = f.read(n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return bytes(buf)


def serve(path: str, exaggeration: float, fin, fout) -> None:
    """The process: answer requests from ``fin`` on ``fout`` (binary) until ``fin`` closes."""
    from lodsprite.terrain.store import TerrainStore

    store = TerrainStore(path, exaggeration)
    while True:
        try:
            k, r0, r1, c0, c1 = _REQ.unpack(_read_exact(fin, _REQ.size))
        except EOFError:
            return
        try:
            if not (0 <= r0 <= r1 and 0 <= c0 <= c1 and (r1 - r0) * (c1 - c0) <= MAX_WINDOW):
                raise ValueError(f"bad window {r0}:{r1}, {c0}:{c1}")
            a = np.ascontiguousarray(store.read(k, r0, r1, c0, c1), np.float32)
            fout.write(_HEAD.pack(0, *a.shape) + a.tobytes())
        except Exception as exc:  # the store's own error, returned to the loader
            text = f"{type(exc).__name__}: {exc}".encode()[:4096]
            fout.write(_HEAD.pack(1, len(text), 0) + text)
        fout.flush()


class ReaderProcess:
    """One reader process: :meth:`send` a window, :meth:`poll` for the answers that have
    arrived (in the order sent); :attr:`dead` once its output has closed (and
    :meth:`send` raises :class:`OSError`)."""

    def __init__(self, path, exaggeration: float = 1.0) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "lodsprite.terrain.reader", str(path),
             repr(float(exaggeration))],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self._out = self.proc.stdout.fileno()
        self._in = self.proc.stdin.fileno()
        try:
            fcntl.fcntl(self._out, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:  # a smaller pipe only means fewer answers written ahead
            pass
        os.set_blocking(self._out, False)
        self._buf = bytearray()
        self.dead = False  # its stdout closed: the answers before that are still given

    def send(self, k: int, r0: int, r1: int, c0: int, c1: int) -> None:
        """Ask for a window (a 40-byte write: the caller bounds what is in flight)."""
        os.write(self._in, _REQ.pack(k, r0, r1, c0, c1))

    def poll(self) -> list[np.ndarray | str]:
        """The answers complete so far: samples ``(a, b) float32``, or an error text."""
        while True:
            try:
                chunk = os.read(self._out, PIPE_BYTES)
            except BlockingIOError:
                break
            if not chunk:
                self.dead = True
                break
            self._buf += chunk
        out: list[np.ndarray | str] = []
        while len(self._buf) >= _HEAD.size:
            status, a, b = _HEAD.unpack_from(self._buf)
            n = a * b * 4 if status == 0 else a
            if len(self._buf) < _HEAD.size + n:
                break
            body = bytes(self._buf[_HEAD.size:_HEAD.size + n])
            del self._buf[:_HEAD.size + n]
            out.append(np.frombuffer(body, np.float32).reshape(a, b) if status == 0
                       else body.decode(errors="replace"))
        return out

    def peak_mb(self) -> float:
        """The process's peak resident memory (``VmHWM``) in MB; 0 when unknown."""
        try:
            with open(f"/proc/{self.proc.pid}/status") as f:
                for line in f:
                    if line.startswith("VmHWM:"):
                        return int(line.split()[1]) / 1024.0
        except OSError:
            pass
        return 0.0

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


if __name__ == "__main__":
    serve(sys.argv[1], float(sys.argv[2]), sys.stdin.buffer, sys.stdout.buffer)
