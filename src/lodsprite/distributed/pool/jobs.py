"""The render pool's messages: what a pool and its renderers say to each other.

Every header is a :class:`msgspec.Struct` tagged by ``kind`` (msgpack), validated here by
:func:`decode_pool` and nothing else:

==========  ======================  ==============================================  =======
kind        direction               fields                                          buffers
==========  ======================  ==============================================  =======
ready       renderer -> pool        ``pid``, ``name``, ``cache`` (scenes it keeps)  0
job         pool -> renderer        ``job`` (:class:`Job`), ``codec``               0
release     pool -> renderer        ``key``: a scene's :func:`job_key` to drop      0
result      renderer -> pool        ``job`` id, ``ok``, ``error``, ``refused``,     0 or 3
                                    ``render_ms``; on success the keyframe
                                    message's frames
                                    (:func:`~lodsprite.distributed.protocol.
                                    encode_keyframe`)
==========  ======================  ==============================================  =======

The public :class:`Job` and :class:`Result` are what the pools take and give (the web
server's interface): :class:`~.local_pool.LocalPool` and :class:`~.ray_pool.RayPool`,
whose renderers answer with the same ``result`` frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
from msgspec import Meta, Struct, field

from lodsprite.distributed.messages import (
    CODECS,
    MAX_KEYFRAME_FRAME_BYTES,
    LoadArgs,
    ProtocolError,
    Seq,
    Time,
    WireViewpoint,
)
from lodsprite.errors import InputError

__all__ = ["MAX_JOB_BYTES", "MAX_RESULT_FRAME_BYTES", "POOL_VERSION", "Job", "JobMessage",
           "PoolMessage", "Ready", "ReleaseMessage", "Result", "ResultMessage", "WorkerInfo",
           "check_job", "decode_pool", "encode_pool", "job_key"]

POOL_VERSION = 5
"""2: ``result`` says whether the worker ``refused`` the job; 3: and how long the worker
took (``render_ms``); 5: no heartbeats and no disconnect (renderers are child processes
or Ray actors, whose deaths their pool sees)."""
MAX_JOB_BYTES = 64 * 1024
"""Largest job header a renderer accepts."""
MAX_RESULT_FRAME_BYTES = MAX_KEYFRAME_FRAME_BYTES
"""Largest frame of a result a pool accepts (a keyframe image)."""
KEYFRAME_PARTS = 3
"""Frames of an encoded keyframe: header, colour, depth."""

SessionId = Annotated[str, Meta(max_length=128)]
Text = Annotated[str, Meta(max_length=4096)]


class Job(Struct, forbid_unknown_fields=True):
    """One keyframe to render: ``job`` id, ``session`` id (the submitter's), the ``load``
    arguments (terrain and texture as names, resolved by the worker's ``--data`` rule, or
    loader specs inside a local worker's data folder), the ``viewpoint`` and ``t`` (the
    submitter's clock, s; the keyframe's ``t0``)."""

    job: Seq
    session: SessionId
    load: LoadArgs
    viewpoint: WireViewpoint
    t: Time


class Result(Struct):
    """A job's outcome: ``ok`` and on success ``parts``, the keyframe message's frames
    (header, colour, depth; :func:`~lodsprite.distributed.protocol.decode_keyframe` reads
    them, their ``seq`` is the job id); otherwise ``error`` says why (the worker's load or
    render error, or a job given up after its workers died) and ``code`` what kind of
    failure: ``refused`` (every worker that tried refused it: a dataset its ``--data``
    lacks, a scene its machine cannot hold), ``failed`` (a worker's render failed) or
    ``lost`` (its workers died); ``worker``: the hex id of the worker that answered (""
    when none did); ``render_ms``: that worker's own time on the job (ms; the rest of
    the round trip is the pool's dispatch overhead)."""

    job: int
    session: str
    ok: bool
    error: str = ""
    parts: list[bytes] = field(default_factory=list)
    worker: str = ""
    code: Literal["", "refused", "failed", "lost"] = ""
    render_ms: float = 0.0


class PoolMessage(Struct, forbid_unknown_fields=True, omit_defaults=True, tag_field="kind"):
    v: Literal[POOL_VERSION]  # type: ignore[valid-type]


class Ready(PoolMessage, tag="ready"):
    pid: Annotated[int, Meta(ge=0, le=2**31)] = 0
    name: Annotated[str, Meta(max_length=256)] = ""
    cache: Annotated[int, Meta(ge=1, le=64)] = 1


class JobMessage(PoolMessage, tag="job"):
    job: Job
    codec: Literal[CODECS] = "raw"  # type: ignore[valid-type]


class ResultMessage(PoolMessage, tag="result"):
    """``refused``: not ok because this worker cannot take the job (its data rule or its
    memory), not because a render failed.  ``render_ms``: the worker's own time on the
    job (decode, scene load, render with the read-back, encode), ms; the rest of a job's
    dispatch-to-answer time is the pool's dispatch overhead."""

    job: Seq
    ok: bool
    error: Text = ""
    refused: bool = False
    render_ms: Annotated[float, Meta(ge=0.0, le=1e9)] = 0.0


class ReleaseMessage(PoolMessage, tag="release"):
    """Drop the scene whose :func:`job_key` is ``key`` (no session uses it any more); the
    renderer answers whether it held it (msgpack ``true`` or ``false``)."""

    key: Annotated[bytes, Meta(max_length=MAX_JOB_BYTES)]


class PrepareMessage(PoolMessage, tag="prepare"):
    """Open the scene of ``load`` (its keyframe source, caches and GL objects) without
    drawing, so that the job that follows finds it open; the renderer answers whether it
    opened it (msgpack ``true`` or ``false``: refused or failed, which the job will say)."""

    load: LoadArgs


ANY_POOL = Ready | JobMessage | ResultMessage | ReleaseMessage | PrepareMessage
_decoder = msgspec.msgpack.Decoder(ANY_POOL)
_encoder = msgspec.msgpack.Encoder()


def encode_pool(msg: PoolMessage, *buffers) -> list:
    """The frames of ``msg`` (then ``buffers`` as they are)."""
    return [_encoder.encode(msg), *buffers]


def decode_pool(frames: list) -> tuple[PoolMessage, list]:
    """The header and buffer frames of one pool message (``bytes`` or ``zmq.Frame``);
    raises :class:`ProtocolError` and nothing else.  A result must carry either no
    buffers (a failure) or the keyframe's three (a success); others none."""
    try:
        if not frames:
            raise ProtocolError("empty message")
        try:
            msg = _decoder.decode(memoryview(frames[0]))
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise ProtocolError(f"pool message: {exc}") from None
        extra = len(frames) - 1
        want = (KEYFRAME_PARTS if msg.ok else 0) if isinstance(msg, ResultMessage) else 0
        if extra != want:
            raise ProtocolError(f"{type(msg).__name__}: {extra} buffers, expected {want}")
        return msg, list(frames[1:])
    except ProtocolError:
        raise
    except (RecursionError, MemoryError, ValueError, TypeError, OverflowError) as exc:
        raise ProtocolError(f"undecodable pool message: {type(exc).__name__}") from None


def job_key(load: LoadArgs) -> bytes:
    """A hashable key of a scene (Structs are not hashable): its msgpack encoding.  Keys
    of loads as a worker decodes them (:func:`check_job`, :func:`check_load`): a load
    built in Python with ``key_scale=2`` encodes another key than its decoded ``2.0``."""
    return _encoder.encode(load)


def check_load(load: LoadArgs) -> LoadArgs:
    """``load`` validated and normalised as a worker will decode it (as
    :func:`check_job` does a job's); raises :class:`InputError`."""
    return _as_decoded(load, LoadArgs, "a scene to open is a LoadArgs", "bad load")


def check_job(job: Job) -> Job:
    """``job`` validated as a worker will decode it (Structs check their constraints only
    when decoded); raises :class:`InputError`."""
    return _as_decoded(job, Job, "submit takes a Job", "bad job")


def _as_decoded(obj, kind: type, wrong_type: str, bad: str):
    """``obj`` (a ``kind``) encoded and decoded back, as a worker receives it."""
    if not isinstance(obj, kind):
        raise InputError(f"{wrong_type}, got {type(obj).__name__}")
    try:
        return _decoders[kind].decode(_encoder.encode(obj))
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise InputError(f"{bad}: {exc}") from None


_decoders = {Job: msgspec.msgpack.Decoder(Job), LoadArgs: msgspec.msgpack.Decoder(LoadArgs)}




@dataclass(frozen=True)
class WorkerInfo:
    """A connected worker: ``id`` (hex id), ``pid``, ``name``, ``job`` (the job id it
    renders, or None)."""

    id: str
    pid: int
    name: str
    job: int | None


