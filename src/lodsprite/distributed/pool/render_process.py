"""A renderer: the GL in a process of its own (a :class:`~lodsprite.workers.ProcessWorker`
the local pool (:mod:`.local_pool`) starts, one a renderer).

Why a process: moderngl holds the GIL through each call, and a large scene holds it for
long stretches (a 4096² scene's colour texture upload and mipmaps: up to 1.3 s measured on
a loaded 2-core machine, beside draws of 33 M triangles); the pool's thread, the web
server's event loop and the kernel beside it must not wait on that.  A process also
contains a driver crash: the pool sees its pipe end, puts its job back in the queue and
starts another.

:func:`handler` is the process's factory: the request's meta is a
:class:`~.jobs.JobMessage` (msgpack), the answer's meta the lengths of the result's
frames (msgpack list) and its data those frames joined: the ``result`` header, then on
success the keyframe message's frames (:func:`~lodsprite.distributed.protocol.
encode_keyframe`).  Scenes are kept by their ``load`` arguments, least recently used
dropped first, all sharing the process's one GL context.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import msgspec

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.pool.jobs import (
    POOL_VERSION,
    JobMessage,
    PrepareMessage,
    ReleaseMessage,
    ResultMessage,
    encode_pool,
    job_key,
)
from lodsprite.distributed.protocol import LoadArgs
from lodsprite.distributed.served import OBJECT_KINDS
from lodsprite.procs import lower_priority

FACTORY = "lodsprite.distributed.pool.render_process:handler"


RENDERER_MB = 2048
"""Memory a renderer's scenes may hold together (their estimates,
:func:`~lodsprite.distributed.render.keyframe_scene_bytes`): the least recently used are
dropped to make room, and a scene over it alone is refused."""


def resolve_load(load: LoadArgs, datasets: Datasets, sizes: dict | None = None) -> LoadArgs:
    """``load`` with terrain and texture resolved to loader specs by ``datasets``' rule;
    raises :class:`~lodsprite.errors.InputError` for a name it refuses or a scene this
    machine cannot hold.  An absolute path inside the data folder is taken as the name
    relative to it (and checked again, symlinks included).  ``sizes``: a dict given gets
    ``bytes``, what drawing its keyframes holds (the estimate)."""
    from lodsprite.distributed.render import check_scene_memory, keyframe_scene_bytes
    from lodsprite.errors import InputError

    local = datasets.local_name
    named = datasets.scene(local(load.terrain))  # confined to the data folder, capped
    if named.kind in OBJECT_KINDS:
        from lodsprite.distributed.render import scene_file_bytes

        if sizes is not None:
            sizes["bytes"] = scene_file_bytes(load)
        return msgspec.structs.replace(load, terrain=named.spec)
    if named.terrain is None:
        raise InputError(f"{load.terrain!r} is a {named.kind} scene: renderers draw "
                         "terrains, scene files and crowds")
    terrain = named.terrain
    texture = datasets.texture(local(load.texture))
    resolved = msgspec.structs.replace(load, terrain=terrain.spec, texture=texture.spec)
    reason = check_scene_memory(resolved, terrain.shape, texture.shape, who="this worker")
    if reason is not None:
        raise InputError(reason)
    if sizes is not None:
        sizes["bytes"] = keyframe_scene_bytes(resolved, terrain.shape, texture.shape)
    return resolved


def pack(frames: list) -> tuple[bytes, bytes]:
    """A result's frames as a process answer: (msgpack list of lengths, frames joined)."""
    parts = [bytes(f) for f in frames]
    return msgspec.msgpack.encode([len(p) for p in parts]), b"".join(parts)


def unpack(meta: bytes, data: bytes | memoryview) -> list[bytes]:
    """The frames :func:`pack` packed."""
    out, at = [], 0
    for n in msgspec.msgpack.decode(meta, type=list[int]):
        out.append(bytes(data[at:at + n]))
        at += n
    return out


class SceneCache:
    """The process's scenes (keyframe services, :func:`~..render.keyframe_service`) and GL
    context: at most ``cache`` scenes and ``max_mb`` MB of them (their estimates), the
    least recently used dropped first."""

    def __init__(self, data_dir: str | None, cache: int, keyframes: str = "auto",
                 max_mb: float = RENDERER_MB) -> None:
        self.datasets = Datasets(data_dir)
        self.keyframes = keyframes
        self.cache = cache
        self.max_bytes = int(max_mb * 2**20)
        self.scenes: OrderedDict[bytes, object] = OrderedDict()
        self.bytes: dict[bytes, int] = {}  # each scene's estimate
        self.gl = None

    def _drop_oldest(self) -> None:
        key, r = self.scenes.popitem(last=False)
        self.bytes.pop(key, None)
        r.release()

    def render(self, msg: JobMessage) -> list:
        """The result frames of one job, with the time it took (``render_ms``); never
        raises."""
        from lodsprite.distributed.protocol import encode_keyframe, viewpoint_from_wire
        from lodsprite.errors import InputError

        start = time.perf_counter()
        job = msg.job
        key = job_key(job.load)
        try:
            r = self._scene(key, job.load)
            kf = r.render(viewpoint_from_wire(job.viewpoint), job.job, job.t)  # read back
            frames = encode_keyframe(kf, msg.codec)
            took = 1e3 * (time.perf_counter() - start)
            return encode_pool(ResultMessage(POOL_VERSION, job.job, True, render_ms=took),
                               *frames)
        except Exception as exc:  # noqa: BLE001 - MemoryError, GL errors: reported, not fatal
            self.release(key)
            error = f"{type(exc).__name__}: {exc}"[:4000]
            took = 1e3 * (time.perf_counter() - start)
            return encode_pool(ResultMessage(POOL_VERSION, job.job, False, error,
                                             refused=isinstance(exc, InputError),
                                             render_ms=took))

    def prepare(self, load: LoadArgs) -> bool:
        """Open the scene of ``load`` (held as a job's would be) without drawing; whether
        it did (a scene refused or failing here is the job's to report)."""
        key = job_key(load)
        try:
            self._scene(key, load)
        except Exception:  # noqa: BLE001 - the job that follows says why
            self.release(key)
            return False
        return True

    def release(self, key: bytes) -> bool:
        """Drop the scene ``key`` (its GL objects and caches); whether it was held."""
        r = self.scenes.pop(key, None)
        self.bytes.pop(key, None)
        if r is not None:
            r.release()
        return r is not None

    def _scene(self, key: bytes, load: LoadArgs):
        from lodsprite.distributed.render import keyframe_service
        from lodsprite.errors import InputError
        from lodsprite.gl.context import GLContext

        r = self.scenes.pop(key, None)
        if r is None:
            sizes: dict = {}
            resolved = resolve_load(load, self.datasets, sizes)
            need = sizes["bytes"]
            if need > self.max_bytes:
                raise InputError(f"the scene needs about {need / 2**20:.0f} MiB, a renderer "
                                 f"holds at most {self.max_bytes / 2**20:.0f} MiB")
            while self.scenes and (len(self.scenes) >= self.cache or
                                   sum(self.bytes.values()) + need > self.max_bytes):
                self._drop_oldest()
            self.bytes[key] = need
            if self.gl is None:
                self.gl = GLContext()
            # A pool worker renders what it is asked for and never paces: the submitter
            # decides when a keyframe is due, so the pacer's per-keyframe reprojection
            # (the exact metric's C', ~20% of a 256² keyframe's time) is not computed.
            r = keyframe_service(msgspec.structs.replace(resolved, pace="continuous"), self.gl,
                                 self.keyframes, self.datasets.data_dir)
        self.scenes[key] = r  # most recently used last
        return r


def warm_imports() -> None:
    """Import the modules that open and draw a scene (keyframe services, the adaptive
    renderer, terrain stores and Zarr, the scene model, the resampling)."""
    import skimage.transform  # noqa: F401
    import zarr  # noqa: F401

    import lodsprite.distributed.render  # noqa: F401
    import lodsprite.scene.model  # noqa: F401
    import lodsprite.techniques.adaptive_worker  # noqa: F401
    import lodsprite.terrain.store  # noqa: F401


def handler(data_dir: str | None, cache: int, keyframes: str = "auto",
            max_mb: float = RENDERER_MB, nice: int = 0
            ) -> Callable[[bytes, bytes], tuple[bytes, bytes]]:
    """The render process's request handler (:mod:`lodsprite.workers`' factory);
    ``keyframes``: how they are drawn (:func:`~lodsprite.distributed.render.
    keyframe_service`); ``max_mb``: what its scenes may hold together; ``nice``: how
    much it lowers its priority before it makes its GL context.  It imports what opening a
    scene needs now (the renderers start with the server, before any page: about 0.5 s of
    a first keyframe here)."""
    lower_priority(nice)
    warm_imports()
    scenes = SceneCache(str(Path(data_dir)) if data_dir is not None else None, cache,
                        keyframes, max_mb)

    def answer(meta: bytes, data: bytes) -> tuple[bytes, bytes]:
        msg = msgspec.msgpack.decode(meta, type=JobMessage | ReleaseMessage | PrepareMessage)
        if isinstance(msg, ReleaseMessage):  # answered: whether it held the scene
            return msgspec.msgpack.encode(scenes.release(msg.key)), b""
        if isinstance(msg, PrepareMessage):  # answered: whether it opened the scene
            return msgspec.msgpack.encode(scenes.prepare(msg.load)), b""
        return pack(scenes.render(msg))

    return answer
