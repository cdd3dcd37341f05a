"""Receiving one ZeroMQ message frame by frame, keeping at most the frames expected.

``zmq.MAXMSGSIZE`` bounds each frame of a message, not the number of frames: a message of
40,000 small frames passes it.  ``recv_multipart`` would then hand Python all of them
(copied, with ``copy=True``).  :func:`recv_frames` takes the frames one at a time
(``copy=False``) and keeps only the first ``keep``, dropping the rest as they come; a
message that had more is refused by :func:`check_frames` (a :class:`ProtocolError`, which
the handlers count as rejected).

libzmq itself still holds a multipart message whole before delivering its first frame:
that buffering is not bounded here (see :mod:`.server`).
"""

from __future__ import annotations

import zmq

from lodsprite.distributed.protocol import ProtocolError


class Frames(list):
    """The frames kept of one message (``zmq.Frame``); ``total``: how many it had."""

    total: int = 0


def recv_frames(sock: zmq.Socket, keep: int, flags: int = zmq.NOBLOCK) -> Frames:
    """One whole message from ``sock``: its first ``keep`` frames, the rest received and
    dropped.  Raises ``zmq.Again`` (with ``zmq.NOBLOCK``) when no message is waiting; the
    frames after the first never wait (ZeroMQ delivers a message whole)."""
    frame = sock.recv(flags, copy=False)
    out = Frames([frame])
    out.total = 1
    while frame.more:
        frame = sock.recv(copy=False)
        out.total += 1
        if len(out) < keep:
            out.append(frame)
    return out


def check_frames(frames: list) -> None:
    """Raise :class:`ProtocolError` when ``frames`` (from :func:`recv_frames`) are not the
    whole message: it had more frames than its receiver keeps."""
    total = getattr(frames, "total", len(frames))
    if total > len(frames):
        raise ProtocolError(f"{total} frames in one message, expected at most {len(frames)}")
