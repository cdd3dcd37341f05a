"""``lodsprite render-worker``: a render worker joining a web server's pool from any host."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.errors import InputError


def render_worker(
    connect: Annotated[str, typer.Option(
        "--connect", help="the pool's address, tcp://HOST:PORT (the web server's "
                          "--workers-bind)")],
    server_key: Annotated[Path | None, typer.Option(
        "--server-key", help="the server's public key file (server.key from `lodsprite "
                             "keys`): encrypt with CURVE")] = None,
    client_key: Annotated[Path | None, typer.Option(
        "--client-key", help="this worker's key pair (a .key_secret file whose public "
                             "half the server admits; default: client.key_secret beside "
                             "--server-key)")] = None,
    data: Annotated[Path | None, typer.Option(
        "--data", help="folder whose terrain and texture files jobs may name (relative "
                       "to it); without it only built-ins are rendered")] = None,
    cache: Annotated[int, typer.Option(
        "--cache", help="scenes kept loaded (least recently used dropped)", min=1,
        max=16)] = 2,
) -> None:
    """A render worker: renders keyframes for a `lodsprite serve --web` pool until
    SIGTERM or SIGINT (it then leaves the pool, finishes the render in progress, releases
    GL and exits 0); reconnects with backoff when the server goes away."""
    import logging

    from lodsprite.distributed.keys import ClientKeys
    from lodsprite.distributed.pool.render_worker import Worker, stop_on_signals

    if not connect.startswith(("tcp://", "ipc://")):
        raise InputError(f"--connect must be tcp://HOST:PORT, got {connect!r}")
    keys = None
    if server_key is not None:
        secret = client_key if client_key is not None else server_key.parent / "client.key_secret"
        keys = ClientKeys.from_files(secret, server_key)
    elif client_key is not None:
        raise InputError("--client-key needs --server-key")
    logging.basicConfig(level=logging.INFO, format="lodsprite render-worker: %(message)s")
    worker = Worker(connect, keys, data, cache, name=f"{_host()}-{_pid()}")
    stop_on_signals(worker)
    logging.info("rendering for %s%s", connect, " (CURVE)" if keys else "")
    worker.run()
    logging.info("stopped")


def _host() -> str:
    import socket

    return socket.gethostname()[:200]


def _pid() -> int:
    import os

    return os.getpid()
