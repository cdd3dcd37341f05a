"""``lodsprite tile``: build a Zarr terrain pyramid from a DEM larger than memory."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import out, progress_bar


def tile(
    source: Annotated[str, typer.Argument(
        help="a GeoTIFF/COG file (read window by window) | fractal:SIZE[:SEED] | "
             "fractal:ROWSxCOLS[:SEED] (generated tile by tile)")],
    out_dir: Annotated[Path, typer.Option("--out", help="the store to write (STORE.zarr)")],
    tile_size: Annotated[int, typer.Option("--tile", help="tile (and shard) side")] = 1024,
    chunk: Annotated[int, typer.Option("--chunk", help="inner chunk side")] = 256,
    encoding: Annotated[str, typer.Option(
        "--encoding", help="float32 | int16 (heights = value · scale + offset)")] = "float32",
    scale: Annotated[float, typer.Option("--scale", help="int16: metres per step")] = 0.25,
    overwrite: Annotated[bool, typer.Option(
        "--overwrite", help="replace an existing store")] = False,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="a Dask scheduler address (tcp://HOST:PORT) to spread the tiles "
                            "over (pip install 'lodsprite[cluster]')")] = None,
    imagery: Annotated[list[str] | None, typer.Option(
        "--imagery", help="an orthophoto (GeoTIFF/COG, any CRS) to drape; repeat to mosaic, "
                          "later ones painted over earlier ones")] = None,
    attribution: Annotated[str | None, typer.Option(
        "--attribution", help="the imagery's licence and attribution line (default: from "
                              "its metadata)")] = None,
    imagery_refine: Annotated[int | None, typer.Option(
        "--imagery-refine", help="imagery texels a height cell side, as a power of two "
                                 "0..3 (default: the finest source's pixel)")] = None,
) -> None:
    """Build a Zarr v3 terrain pyramid from a DEM larger than memory (resumable), with
    orthophotos draped on it."""
    from lodsprite.files import writable_folder
    from lodsprite.terrain.store import build_store

    writable_folder(out_dir)  # before any work: one line if it cannot be

    with progress_bar("tiles") as update:
        s = build_store(source, out_dir, tile_size, chunk, encoding, scale, overwrite, update,
                        scheduler=scheduler, imagery=imagery or (), attribution=attribution,
                        imagery_refine=imagery_refine)
    if s.get("already"):
        out.print(f"{out_dir} is already built ({s['rows']}x{s['cols']}, {s['levels']} levels)")
        return
    out.print(f"{s['rows']}x{s['cols']} samples, {s['levels']} levels: {s['tiles_written']} "
              f"tiles in {s['seconds']:.1f} s ({s['mb_per_s']:.1f} MB/s of float32 heights)"
              f"{' (resumed)' if s['resumed'] else ''}; wrote {out_dir}")
