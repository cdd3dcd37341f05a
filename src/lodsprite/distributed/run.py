"""Running the distributed programs: a client along a scripted path, a local server.

``lodsprite client`` calls :func:`run_client`, which writes ``frames.csv``,
``summary.json``, ``keyframes.json`` and ``server_stats.json`` like ``lodsprite render``;
``lodsprite render --mode distributed`` calls :func:`render_distributed`, which first
starts a server process on free loopback ports (:func:`local_server`).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from lodsprite.distributed.client import (
    DEFAULT_MAX_ERROR,
    LodClient,
    check_max_error,
)
from lodsprite.distributed.keys import ClientKeys
from lodsprite.distributed.pacing import DEFAULT_PACE, PACES
from lodsprite.distributed.render import scene_args
from lodsprite.errors import InputError, LodspriteError
from lodsprite.progress import Progress
from lodsprite.runconfig import RenderConfig, field_of_view, prepare
from lodsprite.scene.spec import SceneSpec
from lodsprite.sprite.adoption import ADOPT_MODES

MAX_ERROR_OFF = ("off", "none")


def parse_max_error(text: str | None) -> float | None:
    """``--max-error``: pixels (a number > 0), ``off`` / ``none`` (no bound), or None
    (not given: :data:`~lodsprite.distributed.client.DEFAULT_MAX_ERROR`)."""
    if text is None:
        return DEFAULT_MAX_ERROR
    if text.strip().lower() in MAX_ERROR_OFF:
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--max-error must be pixels or off, got '{text}'") from None
    return check_max_error(value)


def check_client_options(pace: str, adopt: str, max_error: float | None) -> float | None:
    """Raise :class:`InputError` for a bad pace, adoption rule or bound; the bound."""
    if pace not in PACES:
        raise InputError(f"--pace must be {' or '.join(PACES)}, got '{pace}'")
    if adopt not in ADOPT_MODES:
        raise InputError(f"--adopt must be one of {', '.join(ADOPT_MODES)}, got '{adopt}'")
    return check_max_error(max_error)


def free_ports(count: int = 3, host: str = "127.0.0.1") -> int:
    """A base port with ``count`` consecutive free TCP ports on ``host``."""
    for _ in range(50):
        with socket.socket() as s:
            s.bind((host, 0))
            base = s.getsockname()[1]
        if base + count >= 65535:
            continue
        try:
            socks = []
            for i in range(count):
                t = socket.socket()
                socks.append(t)
                t.bind((host, base + i))
            return base
        except OSError:
            continue
        finally:
            for t in socks:
                t.close()
    raise LodspriteError("found no free consecutive ports on the loopback interface")


def lodsprite_command(*args: str) -> list[str]:
    """The command line running ``lodsprite ARGS`` with this interpreter."""
    return [sys.executable, "-c", "from lodsprite.cli import main; main()", *args]


def pinned(cpus: set[int] | None):
    """A ``preexec_fn`` restricting a child process to ``cpus`` (None: no restriction)."""
    if cpus is None:
        return None
    return lambda: os.sched_setaffinity(0, cpus)


@contextmanager
def local_server(serve_args: Sequence[str] = (), cpus: set[int] | None = None,
                 env: dict | None = None):
    """A LOD server process on free loopback ports (``lodsprite serve`` with extra
    ``serve_args``), optionally pinned to ``cpus`` and with extra environment variables;
    yields its ``HOST:PORT``."""
    address = f"127.0.0.1:{free_ports()}"
    with server_process(lodsprite_command("serve", "--bind", address, *serve_args), cpus, env):
        yield address


@contextmanager
def server_process(cmd: list[str], cpus: set[int] | None = None, env: dict | None = None):
    """Run ``cmd`` (a server) for the duration of the block; stopped on exit."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, **(env or {})}, preexec_fn=pinned(cpus))
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()


def render_distributed(config: RenderConfig, out_dir: Path,
                       progress: Progress | None = None, *,
                       pace: str = DEFAULT_PACE, adopt: str = "newest",
                       max_error: float | None = DEFAULT_MAX_ERROR) -> dict:
    """``lodsprite render --mode distributed``: ``config``'s path (its sprite settings) drawn
    by a client with keyframes from a LOD server started here on free loopback ports;
    writes what :func:`run_client` writes and returns its summary.  Input errors are
    reported before the server starts."""
    config = replace(config, mode="sprite").resolved(store=False)  # the 1999 options
    prepare(config, light=False)
    check_client_options(pace, adopt, max_error)
    with local_server() as address:
        return run_client(config, [address], Path(out_dir), progress, adopt=adopt, pace=pace,
                          max_error=max_error)


def run_client(config: RenderConfig, servers: list[str], out_dir: Path,
               progress: Progress | None = None,
               warmup_s: float = 10.0, adopt: str = "newest",
               keys: ClientKeys | None = None, *, pace: str = DEFAULT_PACE,
               max_error: float | None = DEFAULT_MAX_ERROR) -> dict:
    """Draw ``config``'s path with keyframes from ``servers``; write outputs; return summary.

    ``pace``: when the servers render keyframes (:mod:`lodsprite.distributed.pacing`);
    ``adopt``: when the client takes a newer one; ``max_error``: the client's bound on
    the shown keyframe's error, pixels (None: none, the paper's client), see
    :class:`~lodsprite.distributed.client.LodClient`.  Before the timed frames the client
    waits (up to ``warmup_s``) for a first keyframe, so that server start-up is not
    counted as frames drawn without one.
    """
    from lodsprite.distributed.technique import DistributedTechnique
    from lodsprite.driver import Measure, drive

    config = config.resolved(store=False)  # options not given: the 1999 algorithm's
    max_error = check_client_options(pace, adopt, max_error)
    scene, path = prepare(replace(config, mode="sprite"), light=False)  # the server's grid
    args = scene_args(SceneSpec(config.terrain, config.texture, config.grid,
                                config.exaggeration), config.size, field_of_view(config, path))
    client = LodClient(scene, args, servers, config.size, config.lod, config.visibility,
                       config.epsilon, adopt, keys, config.border, pace, max_error)
    technique = DistributedTechnique.on_client(client, servers)
    technique.warmup_s = warmup_s
    technique.shading = config.shading  # the reference's colouring, as the server's
    ctx = client.terrain_gl.ctx
    try:
        result = drive(technique, path, out_dir, Measure.of(config), progress=progress,
                       finish=ctx.finish, gl_renderer=ctx.info.renderer,
                       summary={"mode": "distributed", "terrain": config.terrain,
                                "path": config.path, "size": list(config.size),
                                "servers": servers, "grid": scene.hf.quads,
                                "lod": config.lod, "adopt": adopt, "pace": pace,
                                "max_error": max_error, "epsilon": config.epsilon})
    finally:
        client.close()
    if result.interrupted:
        raise KeyboardInterrupt
    return result.summary
