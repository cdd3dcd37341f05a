"""``lodsprite serve``, ``keys`` and ``client``: the distributed LOD server and client."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import (
    BorderOpt,
    EpsOpt,
    ExagOpt,
    FramesOpt,
    GridOpt,
    GroundTruthOpt,
    LodOpt,
    MaxErrorOpt,
    PaceOpt,
    PathOpt,
    QualityStrideOpt,
    SizeOpt,
    TerrainOpt,
    TextureOpt,
    VisOpt,
    out,
    progress_bar,
)
from lodsprite.errors import InputError
from lodsprite.terrain import DEFAULT_EXAGGERATION


def serve(
    bind: Annotated[str, typer.Option("--bind", help="HOST:PORT; the three connections use "
                                                     "PORT, PORT+1, PORT+2")] = "127.0.0.1:5555",
    predictor: Annotated[str, typer.Option("--predictor", help="linear | kalman")] = "linear",
    codec: Annotated[str, typer.Option("--codec", help="raw | zlib (keyframe images)")] = "raw",
    allow_remote: Annotated[bool, typer.Option(
        "--allow-remote", help="allow binding an address other than loopback")] = False,
    keys: Annotated[Path | None, typer.Option(
        "--keys", help="folder from `lodsprite keys`: encrypt with CURVE and accept only "
                       "clients whose public key is there")] = None,
    data: Annotated[str | None, typer.Option(
        "--data", help="folder whose terrain and texture files clients may name (relative "
                       "to it), or an http(s):// URL of one whose terrain stores (*.zarr) "
                       "and COGs are read in place; without it only built-ins (jacksboro, "
                       "fractal:SIZE:SEED, terrain, checker) are served")] = None,
    allow_shutdown: Annotated[bool, typer.Option(
        "--allow-shutdown", help="carry out a `shutdown` message from the client holding "
                                 "the server (refused otherwise)")] = False,
    web: Annotated[str | None, typer.Option(
        "--web", help="[HOST:]PORT: also serve the web page and its WebSocket there "
                      "(host 127.0.0.1 unless given; PORT 0: any free port)")] = None,
    renderers: Annotated[int, typer.Option(
        "--renderers", help="renderer processes for web sessions", min=1, max=64)] = 1,
    token: Annotated[str | None, typer.Option(
        "--token", help="the web page's access token, at least 16 characters beyond "
                        "loopback (default: a random one, printed in the page's URL)")
    ] = None,
    cert: Annotated[Path | None, typer.Option(
        "--cert", help="TLS certificate (PEM) for the web page: serve https and wss")] = None,
    key: Annotated[Path | None, typer.Option(
        "--key", help="TLS private key (PEM) matching --cert")] = None,
    session_jobs: Annotated[int, typer.Option(
        "--session-jobs", help="keyframe renders in flight per web session (the page "
                               "keeps as many requests in flight)", min=1, max=16)] = 1,
    session_queue: Annotated[int, typer.Option(
        "--session-queue", help="keyframes queued per web session; when full the oldest "
                                "is dropped", min=1, max=64)] = 2,
    rate: Annotated[float, typer.Option(
        "--rate", help="messages a second a web session may send; excess dropped",
        min=1.0, max=100000.0)] = 240.0,
    ray: Annotated[str | None, typer.Option(
        "--ray", help="run the web page's --renderers as Ray actors on a Ray cluster: "
                      "auto (the one running on this machine), ray://HOST:PORT (Ray "
                      "Client), HOST:PORT (a head node) or local (one started here); needs "
                      "the ray extra")] = None,
    gpus_per_renderer: Annotated[float, typer.Option(
        "--gpus-per-renderer", help="GPUs Ray reserves for each renderer actor (--ray; "
                                    "0: none)", min=0.0, max=64.0)] = 0.0,
    public_host: Annotated[list[str] | None, typer.Option(
        "--public-host", help="a name users reach the page by (a DNS name, a reverse "
                              "proxy's), accepted in Host and Origin besides loopback "
                              "names, the bound host and IP addresses; repeat for "
                              "several")] = None,
) -> None:
    """The LOD server: renders keyframes for LOD clients; driven entirely by messages."""
    import logging

    from lodsprite.distributed.keys import ServerKeys
    from lodsprite.distributed.server import LodServer

    server_keys = ServerKeys.load(keys) if keys is not None else None
    config = None
    if web is not None:  # every web option checked before anything starts
        config = _web_config(web, allow_remote, token, data, renderers, codec, cert, key,
                             (session_jobs, session_queue, rate), public_host)
        config.ray, config.gpus_per_renderer = _ray_options(ray, gpus_per_renderer)
    elif ray is not None:
        raise InputError("--ray runs the web page's renderers: give --web too")
    server = LodServer(bind, predictor, codec, server_keys, data_dir=data,
                       allow_remote=allow_remote, allow_shutdown=allow_shutdown)
    logging.basicConfig(level=logging.INFO, format="lodsprite serve: %(message)s")
    if server_keys is None and allow_remote:
        logging.warning("serving beyond loopback without --keys: anyone who can reach "
                        "the port can drive this server")
    if config is None:
        server.run()
    else:
        _serve_both(server, config)


def _web_config(web, allow_remote, token, data, renderers, codec, cert, key, caps,
                public_host):
    """The web server's configuration from ``serve``'s options (raises InputError)."""
    from lodsprite.distributed.datasets import Datasets
    from lodsprite.distributed.web.security import (
        LOOPBACK_NAMES,
        make_token,
        parse_web_address,
        tls_context,
    )
    from lodsprite.distributed.web.server import WebConfig
    from lodsprite.distributed.web.sessions import Caps

    host, port = parse_web_address(web, allow_remote)
    remote = allow_remote or host not in LOOPBACK_NAMES
    Datasets(data)  # a missing data folder: one line before anything starts
    return WebConfig(host, port, make_token(token, remote), data, renderers, Caps(*caps), codec,
                     tls_context(cert, key), tuple(public_host or ()))


def _ray_options(ray: str | None, gpus: float) -> tuple:
    """``--ray`` and ``--gpus-per-renderer`` checked (Ray installed, an address of a
    known form); raises InputError."""
    if ray is None:
        if gpus > 0:
            raise InputError("--gpus-per-renderer places Ray actors: give --ray too")
        return None, 0.0
    from lodsprite.distributed.pool.ray_pool import check_address, require_ray

    require_ray()
    check_address(ray)
    return ray, gpus


def _say_url(url: str) -> None:
    out.print(f"web page: {url}", soft_wrap=True, highlight=False)
    out.file.flush()  # a script reading our stdout through a pipe waits for this line


def _serve_both(server, config) -> None:
    """The ZeroMQ server on a thread, the web server on this one, until a signal; a
    ZeroMQ server that cannot start (its ports taken) stops both, with its reason."""
    import threading

    from lodsprite.distributed.web.server import serve_web
    from lodsprite.errors import LodspriteError

    failed: list[LodspriteError] = []

    def run_zmq() -> None:
        try:
            server.run()
        except LodspriteError as exc:
            failed.append(exc)  # the web server's loop stops on it

    zmq_thread = threading.Thread(target=run_zmq, daemon=True, name="zmq-server")
    zmq_thread.start()
    try:
        serve_web(config, _say_url, lambda: bool(failed))
    finally:
        server.shutdown()
        zmq_thread.join(timeout=5.0)
    if failed:
        raise failed[0]


def keys_command(
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("keys"),
) -> None:
    """Make CURVE key pairs for a LOD server and a client (server.key*, client.key*)."""
    from lodsprite.distributed.keys import make_keys
    from lodsprite.files import writable_folder

    writable_folder(out_dir)  # before any work: one line if it cannot be

    for path in make_keys(out_dir):
        out.print(str(path))


def client(
    server: Annotated[list[str] | None, typer.Option(
        "--server", help="HOST:PORT of a LOD server (default 127.0.0.1:5555); repeat for "
                         "several")] = None,
    terrain: TerrainOpt = "jacksboro",
    texture: TextureOpt = "terrain",
    path: PathOpt = "swan2002",
    frames: FramesOpt = None,
    size: SizeOpt = "512x512",
    lod: LodOpt = 16,
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path("out/client"),
    grid: GridOpt = None,
    exaggeration: ExagOpt = DEFAULT_EXAGGERATION,
    visibility: VisOpt = "coarse",
    epsilon: EpsOpt = 1.0,
    border: BorderOpt = True,
    pace: PaceOpt = "needed",
    adopt: Annotated[str, typer.Option(
        "--adopt", help="newest: take every newer keyframe (the paper); better: once its "
                        "error metric here is lower than the shown one's; needed: when the "
                        "shown one's reaches ε/2")] = "newest",
    max_error: MaxErrorOpt = None,
    ground_truth: GroundTruthOpt = False,
    quality_stride: QualityStrideOpt = 1,
    keys: Annotated[Path | None, typer.Option(
        "--keys", help="folder holding client.key_secret and server.key (CURVE)")] = None,
) -> None:
    """The LOD client: draws a scripted path with keyframes from LOD servers."""
    import logging

    from lodsprite.distributed.keys import ClientKeys
    from lodsprite.distributed.run import check_client_options, parse_max_error, run_client
    from lodsprite.files import writable_folder
    from lodsprite.run import RenderConfig, parse_size

    writable_folder(out_dir)  # before any work: one line if it cannot be
    logging.basicConfig(level=logging.WARNING, format="lodsprite client: %(message)s")
    bound = check_client_options(pace, adopt, parse_max_error(max_error))
    config = RenderConfig(terrain=terrain, texture=texture, path=path, mode="sprite",
                          lod=lod, size=parse_size(size), frames=frames, grid=grid,
                          exaggeration=exaggeration, visibility=visibility, epsilon=epsilon,
                          border=border, ground_truth=ground_truth,
                          quality_stride=quality_stride)
    with progress_bar("client") as update:
        s = run_client(config, list(server or ["127.0.0.1:5555"]), out_dir, update,
                       adopt=adopt, keys=ClientKeys.load(keys) if keys is not None else None,
                       pace=pace, max_error=bound)
    out.print(f"{s['frames']} frames: median {s['median_ms']:.2f} ms, mean {s['mean_ms']:.2f}, "
              f"σ {s['std_ms']:.2f}, p99 {s['p99_ms']:.2f}; {s['keyframes_received']} keyframes "
              f"received, {s['local_keyframes']} own keyframes, {s['rejected_keyframes']} "
              f"rejected; δt {s['delta_t_ms_mean']:.0f} ms")
    out.print(f"wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")
