"""``lodsprite lumigraph capture | import | render``: the time-critical lumigraph
(Sloan et al. 1997)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lodsprite.cli.common import SizeOpt, out, progress_bar
from lodsprite.cli.options import with_technique_options

lumigraph_app = typer.Typer(no_args_is_help=True,
                             help="Time-critical lumigraph (Sloan et al. 1997): capture, render.")


@lumigraph_app.command("capture")
def lumigraph_capture(
    model: Annotated[str, typer.Argument(
        help="still-life (built in) | a mesh FILE (.obj .ply .off .stl .glb .gltf)")
    ] = "still-life",
    out_dir: Annotated[Path, typer.Option("--out", help="lumigraph folder to write")] = Path(
        "out/lumigraph"),
    st: Annotated[int, typer.Option("--st", help="st nodes per side")] = 32,
    uv: Annotated[int, typer.Option("--uv", help="uv image size in pixels")] = 256,
    codec: Annotated[str, typer.Option("--codec", help="jpeg | png (lossless)")] = "jpeg",
    quality: Annotated[int, typer.Option("--quality", help="JPEG quality 1-100")] = 90,
    slabs: Annotated[int, typer.Option(
        "--slabs", help="1 (in front, as in the paper) or 6 (round the object: orbit it)")
    ] = 1,
) -> None:
    """Render a two-plane lumigraph of an object: one uv image per st node, compressed."""
    from lodsprite.files import writable_folder
    from lodsprite.lumigraph.run import capture_lumigraph

    writable_folder(out_dir)  # before any work: one line if it cannot be

    with progress_bar("capture") as update:
        s = capture_lumigraph(model, out_dir, st, uv, codec, quality, slabs=slabs,
                              progress=update)
    out.print(f"{s['nodes']} nodes of {s['uv']}² ({s['codec']}) of {s['object']} "
              f"({s['faces']:,} triangles) in {s['capture_s']:.1f} s; wrote {out_dir}")


@lumigraph_app.command("import")
def lumigraph_import(
    folder: Annotated[Path, typer.Argument(
        help="a Stanford Light Field Archive rectified/ folder (out_RR_CC_Y_X_.png)")],
    out_dir: Annotated[Path, typer.Option("--out", help="lumigraph folder to write")] = Path(
        "out/lumigraph"),
    uv: Annotated[int, typer.Option("--uv", help="uv image size in pixels")] = 256,
    codec: Annotated[str, typer.Option("--codec", help="jpeg | png (lossless)")] = "jpeg",
    st_scale: Annotated[float, typer.Option(
        "--st-scale", help="scale of the camera grid against the image plane")] = 1.0,
) -> None:
    """Import a rectified light field of the Stanford archive as a lumigraph."""
    from lodsprite.files import writable_folder
    from lodsprite.lumigraph.importer import import_stanford

    writable_folder(out_dir)  # before any work: one line if it cannot be

    s = import_stanford(folder, out_dir, uv, codec, st_scale=st_scale)
    out.print(f"{s['nodes']} nodes ({s['grid']}x{s['grid']} cameras) of {s['uv']}²; "
              f"wrote {out_dir}")


def lumigraph_render(
    folder: Annotated[Path, typer.Argument(help="a lumigraph folder (lumigraph capture)")],
    frames: Annotated[int, typer.Option("--frames", help="frames along the arc")] = 120,
    path: Annotated[str | None, typer.Option(
        "--path", help="a JSON path file (default: an arc in front of the object, or an "
                       "orbit round it for six slabs)")] = None,
    size: SizeOpt = "512x512",
    out_dir: Annotated[Path, typer.Option("--out", help="output folder")] = Path(
        "out/lumigraph-render"),
    ground_truth: Annotated[bool, typer.Option(
        "--ground-truth", help="compare every frame with the object drawn directly "
                               "(PSNR, SSIM)")] = False,
    method: Annotated[str, typer.Option(
        "--method", help="full | subsample | fixed | arbitrary | line | projective | "
                         "progressive | critical")] = "full",
    every: Annotated[int, typer.Option(
        "--every", help="with --ground-truth: compare every K-th frame")] = 1,
    flip: Annotated[bool, typer.Option(
        "--flip", help="with --ground-truth: FLIP too (about 0.4 s a 512² frame)")] = False,
    options: dict | None = None,
) -> None:
    """Reconstruct a lumigraph along a path with one of the paper's methods (its options:
    the lumigraph techniques' declarations, under "Technique options")."""
    from lodsprite.files import writable_folder
    from lodsprite.lumigraph.run import render_lumigraph
    from lodsprite.paths import load_path_json
    from lodsprite.run import parse_size

    writable_folder(out_dir)  # before any work: one line if it cannot be

    cam = load_path_json(path) if path is not None else None
    opts = dict(options or {})
    depth_correction = opts.pop("depth_correction", True)
    with progress_bar(f"lumigraph {method}") as update:
        s = render_lumigraph(folder, out_dir, frames, parse_size(size), cam, ground_truth,
                             depth_correction, method, every, update, flip, **opts)
    line = (f"{s['frames']} frames ({method}, {s['images_per_frame_mean']:.1f} images a "
            f"frame): median {s['median_ms']:.2f} ms, mean {s['mean_ms']:.2f} ms, "
            f"p99 {s['p99_ms']:.2f} ms")
    if "psnr_mean" in s:
        line += f"; PSNR {s['psnr_mean']:.2f} dB, SSIM {s['ssim_mean']:.3f}"
    if "flip_mean" in s:
        line += f", FLIP {s['flip_mean']:.4f}"
    out.print(line + f"; wrote {out_dir / 'frames.csv'}, {out_dir / 'summary.json'}")


lumigraph_app.command("render")(with_technique_options(lumigraph_render, ("lightfield",)))
