"""The ``lodsprite`` command line: parses, calls the library, prints.

One module per command group: :mod:`.render` (info, render, view), :mod:`.lumigraph`,
:mod:`.terrain` (tile), :mod:`.crowd`, :mod:`.scene` (scene check), :mod:`.profile`,
:mod:`.reproduce` (reproduce, demo), :mod:`.distributed` (serve, keys, client);
:mod:`.common` holds what they share.

User errors (bad files, bad options) print one line on stderr and exit with
code 2; an interrupted run exits with 130.  No traceback reaches the user for
either.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli import (
    crowd,
    distributed,
    lumigraph,
    profile,
    render,
    reproduce,
    scene,
    terrain,
)
from lodsprite.cli.common import err, one_line, out
from lodsprite.cli.options import with_technique_options
from lodsprite.errors import GLUnavailableError, LodspriteError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Time-critical rendering of large terrains with LOD geometry and "
                       "image reuse (LOD-sprite).")
for command in (render.info, with_technique_options(render.render),
                with_technique_options(render.view), terrain.tile,
                with_technique_options(crowd.crowd, ("objects",)),
                profile.profile, reproduce.reproduce, reproduce.demo, distributed.serve):
    app.command()(command)


@app.callback()
def _options(
    http_cache: Annotated[Path | None, typer.Option(
        "--http-cache", help="the folder of the HTTP block cache for http(s):// datasets "
                             "(default ~/.cache/lodsprite/http; env LODSPRITE_HTTP_CACHE)")
    ] = None,
    http_cache_mb: Annotated[float | None, typer.Option(
        "--http-cache-mb", help="its size cap in MB (default 2048; env "
                                "LODSPRITE_HTTP_CACHE_MB)")] = None,
) -> None:
    """Options for every command, before its name: lodsprite --http-cache DIR render ..."""
    import os

    from lodsprite.errors import InputError

    if http_cache is not None:  # the environment: render and reader processes inherit it
        os.environ["LODSPRITE_HTTP_CACHE"] = str(http_cache.expanduser())
    if http_cache_mb is not None:
        if not (http_cache_mb > 0 and http_cache_mb < float("inf")):
            raise InputError(f"--http-cache-mb must be a positive number, got {http_cache_mb}")
        os.environ["LODSPRITE_HTTP_CACHE_MB"] = str(http_cache_mb)


app.command(name="keys")(distributed.keys_command)
app.command()(distributed.client)
app.add_typer(lumigraph.lumigraph_app, name="lumigraph")
app.add_typer(scene.scene_app, name="scene")


def _click_error(exc: Exception) -> None:
    """Click's exceptions (vendored by recent typer releases, hence matched by name)."""
    name = type(exc).__name__
    if name == "NoArgsIsHelpError":
        out.print(exc.ctx.get_help(), markup=False, highlight=False)
        sys.exit(0)
    if name == "Abort":
        err.print("lodsprite: interrupted", markup=False)
        sys.exit(130)
    if hasattr(exc, "format_message") and hasattr(exc, "exit_code"):
        one_line(exc.format_message(), 2)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app, turning user errors into one line and exit code 2."""
    try:
        code = app(args=argv, standalone_mode=False, prog_name="lodsprite")
    except GLUnavailableError as exc:
        err.print(str(exc), markup=False, highlight=False, soft_wrap=True)
        sys.exit(2)
    except LodspriteError as exc:
        one_line(str(exc), 2)
    except KeyboardInterrupt:
        err.print("lodsprite: interrupted", markup=False)
        sys.exit(130)
    except Exception as exc:
        _click_error(exc)
        raise
    sys.exit(code if isinstance(code, int) else 0)


__all__ = ["app", "main"]
