"""``lodsprite scene check FILE``: validate a scene file and say what it holds."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import out

scene_app = typer.Typer(no_args_is_help=True,
                        help="Scene files (TOML): terrain, objects and light fields in one world.")


@scene_app.command("check")
def scene_check(
    file: Annotated[Path, typer.Argument(help="the scene file (.toml)")],
    light: Annotated[bool, typer.Option(
        "--light/--full", help="load a terrain store's working grid from a coarse level "
                               "(as the adaptive modes do) or from its finest level")] = True,
) -> None:
    """Read and validate a scene file, build its world (terrain, meshes, placement) and
    print one line per layer; a bad file is one line naming the field, exit code 2."""
    from lodsprite.scene.world import load_scene_file, summary
    from lodsprite.techniques.scenes import checked

    for line in summary(checked(load_scene_file(file, light=light, textured=False))):
        out.print(line, markup=False, highlight=False)
