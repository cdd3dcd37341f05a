"""``lodsprite profile``: a model's LOD error profile (Scoggins et al. 2000)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import numbers, out, progress_bar


def profile(
    model: Annotated[str, typer.Argument(
        help="sphere | mountain[:TERRAIN] | a mesh file (.obj .ply .off .stl .glb)")],
    out_path: Annotated[Path | None, typer.Option(
        "--out", help="table file to write (default: MODEL-profile.npz here)")] = None,
    faces: Annotated[str | None, typer.Option(
        "--faces", help="mesh files: LOD face counts, e.g. 1000,2000,4000")] = None,
    ratios: Annotated[str | None, typer.Option(
        "--ratios", help="mesh files: LOD face ratios, e.g. 0.05,0.2,0.5 "
                         "(default 0.01,0.02,0.05,0.1,0.2,0.5)")] = None,
    image: Annotated[int, typer.Option("--image", help="profile image size M (pixels)")] = 512,
    phi_step: Annotated[float, typer.Option("--phi-step", help="azimuth step, degrees")] = 30.0,
    theta_step: Annotated[float, typer.Option(
        "--theta-step", help="elevation step, degrees (0..90)")] = 15.0,
    workers: Annotated[int | None, typer.Option(
        "--workers", help="local worker processes (default: one per core)")] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Dask scheduler address (tcp://HOST:PORT): run views there "
                             "(needs the cluster extra: pip install 'lodsprite[cluster]')")
    ] = None,
) -> None:
    """Compute a model's LOD error profile (Scoggins et al. 2000) and write its table."""
    from lodsprite.cluster import require_dask
    from lodsprite.errors import InputError
    from lodsprite.files import writable_folder

    if out_path is not None:  # before any work: the folder it goes in
        writable_folder(out_path.expanduser().absolute().parent, "--out")
    from lodsprite.profiles.generate import ProfileSettings, generate_profile
    from lodsprite.profiles.models import get_model

    if scheduler is not None:
        require_dask()  # one line naming the extra, before any model is built
    settings = ProfileSettings(image_size=image, phi_step_deg=phi_step,
                               theta_step_deg=theta_step)
    chain = get_model(model, faces=numbers(faces, int, "--faces"),
                      ratios=numbers(ratios, float, "--ratios"))
    if out_path is None:
        stem = Path(model).stem if Path(model).suffix else model.replace(":", "-")
        out_path = Path(f"{stem}-profile.npz")
    if out_path.is_dir():
        raise InputError(f"--out {out_path} is a folder; give a table file name")
    with progress_bar(f"profile {chain.name} (views)") as update:
        table = generate_profile(chain, settings, workers=workers, scheduler=scheduler,
                                 progress=update)
    table.save(out_path)
    out.print(f"{chain.name}: {len(chain.levels)} LODs {chain.faces}, {table.error.shape[1]}x"
              f"{table.error.shape[2]} views, {len(table.z)} distances, "
              f"{table.meta['seconds']:.1f} s; wrote {out_path}")
