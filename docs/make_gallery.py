"""Make the gallery's pictures and video (docs/images/) from real runs of lodsprite.

Every picture comes from a ``lodsprite`` command run here, at small sizes (320x240 and a
few dozen frames) so the whole script takes a few minutes on 2 CPU cores with Mesa's
llvmpipe.  The window pictures need Xvfb (``xvfb``, ``xauth``).  Usage::

    python3 docs/make_gallery.py [--work out/gallery] [--out docs/images]

The commands it runs are printed as it goes and listed on docs/gallery.md.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
SIZE = "320x240"
VIDEO_FRAMES = 90


def lodsprite(*args: str, xvfb: bool = False) -> None:
    """Run one ``lodsprite`` command (under ``xvfb-run -a`` for the window)."""
    exe = shutil.which("lodsprite")
    if exe is None:
        sys.exit("make_gallery: the lodsprite command is not installed (pip install -e .)")
    cmd = (["xvfb-run", "-a"] if xvfb else []) + [exe, *args]
    print("$ lodsprite " + " ".join(args), flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def shown(path: Path) -> str:
    """``path`` relative to the repository where it lies inside it."""
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def save_png(image: Image.Image, path: Path, colors: int = 160) -> None:
    """Save a palette PNG (a few tens of KB at 320x240) for the docs."""
    image.convert("RGB").quantize(colors=colors, method=Image.Quantize.MEDIANCUT,
                                  dither=Image.Dither.NONE).save(path, optimize=True)
    print(f"  wrote {shown(path)} ({path.stat().st_size // 1024} KB)", flush=True)


def strip(paths: list[Path]) -> Image.Image:
    """The images side by side, left to right."""
    images = [Image.open(p).convert("RGB") for p in paths]
    w, h = images[0].size
    out = Image.new("RGB", (w * len(images), h))
    for i, im in enumerate(images):
        out.paste(im, (w * i, 0))
    return out


def read_frames(path: Path) -> list[dict[str, str]]:
    """A run's frames.csv as rows, each with ``kind`` (older runs call it ``type``)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        row.setdefault("kind", row.get("type", ""))
    return rows


def lod_sprite(work: Path, out: Path) -> None:
    """LOD-sprite beside full resolution: the video and one still of it."""
    video = out / "lodsprite.mp4"
    lodsprite("render", "--mode", "sprite", "--ground-truth", "--path", "swan2002",
              "--frames", str(VIDEO_FRAMES), "--size", SIZE, "--out", str(work / "sprite"),
              "--video", str(video))
    print(f"  wrote {shown(video)} ({video.stat().st_size // 1024} KB)")
    import imageio.v3 as iio

    # The still: the spriteframe farthest from its keyframe (its difference panel shows).
    error = [float(r["error_px"]) if r["kind"] == "sprite" else -1.0
             for r in read_frames(work / "sprite" / "frames.csv")]
    still = iio.imread(video, index=int(np.argmax(error)))
    save_png(Image.fromarray(still), out / "lodsprite.png")


def large_terrain(work: Path, out: Path) -> None:
    """A 1k² fractal store tiled, then flown with the adaptive renderer."""
    store = work / "fractal1k.zarr"
    lodsprite("tile", "fractal:1024", "--out", str(store), "--tile", "512", "--overwrite")
    lodsprite("render", "--terrain", str(store), "--mode", "adaptive", "--path", "chen1999",
              "--frames", "46", "--size", SIZE, "--save-frames", "--out", str(work / "adaptive"))
    frames = work / "adaptive" / "frames"
    save_png(strip([frames / f"frame_{i:05d}.png" for i in (8, 20, 44)]), out / "adaptive.png")


def draped(work: Path, out: Path) -> None:
    """jacksboro (a real DEM, matplotlib's, in degrees) with an orthophoto made from it in
    a UTM zone (its heights' hypsometric tint and hillshade at twice the DEM's resolution,
    with a field pattern), tiled with --imagery (reprojected by the tiler), flown."""
    import rasterio
    from rasterio.transform import from_bounds
    from rasterio.warp import calculate_default_transform, reproject

    from lodsprite.terrain import load_heightfield
    from lodsprite.terrain.textures import terrain_texture

    hf = load_heightfield("jacksboro")
    m = hf.meta
    bounds = (m["west"], m["south"], m["east"], m["north"])
    dem = work / "jacksboro.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=hf.cols, height=hf.rows, count=1,
                       dtype="float32", crs="EPSG:4326",
                       transform=from_bounds(*bounds, hf.cols, hf.rows)) as f:
        f.write(hf.heights.astype("float32"), 1)
    rgb = np.repeat(np.repeat(terrain_texture(hf), 2, 0), 2, 1).astype(np.int16)
    yy, xx = np.mgrid[0:rgb.shape[0], 0:rgb.shape[1]]
    fields = ((xx // 23 + yy // 17) % 3 - 1) * 9 + (np.sin(xx / 3.0) * 4).astype(np.int16)
    rgb = np.clip(rgb + fields[..., None], 0, 255).astype(np.uint8).transpose(2, 0, 1)
    src_t = from_bounds(*bounds, rgb.shape[2], rgb.shape[1])
    dst_t, w, h = calculate_default_transform("EPSG:4326", "EPSG:32614", rgb.shape[2],
                                              rgb.shape[1], *bounds)
    ortho = work / "ortho_utm.tif"
    with rasterio.open(ortho, "w", driver="GTiff", width=w, height=h, count=3, dtype="uint8",
                       crs="EPSG:32614", transform=dst_t, photometric="RGB", nodata=0) as f:
        for b in range(3):
            band = np.zeros((h, w), np.uint8)
            reproject(rgb[b], band, src_transform=src_t, src_crs="EPSG:4326",
                      dst_transform=dst_t, dst_crs="EPSG:32614", dst_nodata=0)
            f.write(band, b + 1)
    store = work / "jacksboro.zarr"
    lodsprite("tile", str(dem), "--out", str(store), "--imagery", str(ortho), "--attribution",
              "imagery made from the DEM by docs/make_gallery.py", "--overwrite")
    lodsprite("render", "--terrain", str(store), "--mode", "adaptive", "--path", "chen1999",
              "--frames", "46", "--size", SIZE, "--save-frames", "--out", str(work / "draped"))
    frames = work / "draped" / "frames"
    save_png(strip([frames / f"frame_{i:05d}.png" for i in (8, 20, 44)]), out / "draped.png",
             colors=192)


def distributed(work: Path, out: Path) -> None:
    """Frame times of inline LOD-sprite and of the distributed client, one path."""
    common = ["--path", "swan2002", "--frames", "300", "--size", SIZE]
    lodsprite("render", "--mode", "sprite", *common, "--out", str(work / "inline"))
    lodsprite("render", "--mode", "distributed", "--max-error", "off", *common,
              "--out", str(work / "distributed"))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 2.6), dpi=100)
    for name, label in (("inline", "inline (keyframes in the frame)"),
                        ("distributed", "the paper's distributed client and a LOD server")):
        rows = read_frames(work / name / "frames.csv")
        ms = np.array([float(r["ms"]) for r in rows])
        ax.plot(ms, lw=1, label=f"{label}: p99 {np.percentile(ms, 99):.0f} ms")
        keys = [i for i, r in enumerate(rows) if r["kind"] in ("keyframe", "local_keyframe")]
        ax.plot(keys, ms[keys], "o", ms=3, color=ax.lines[-1].get_color())
    ax.set(xlabel="frame (swan2002 path, 320x240)", ylabel="ms", yscale="log")
    ax.legend(fontsize=8, frameon=False)
    fig.tight_layout()
    png = work / "distributed.png"
    fig.savefig(png)
    plt.close(fig)
    save_png(Image.open(png), out / "distributed.png", colors=64)


def profile(work: Path, out: Path) -> None:
    """The Jacksboro mountain's LOD error profile, plotted from the table it wrote."""
    table = work / "mountain.npz"
    lodsprite("profile", "mountain", "--image", "128", "--phi-step", "90", "--theta-step",
              "45", "--out", str(table))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.load(table, allow_pickle=False)
    error = t["error_csf"].mean(axis=(1, 2))  # (LOD, z): the mean over view directions
    fig, ax = plt.subplots(figsize=(6.4, 2.6), dpi=100)
    for lod in range(len(t["faces"]) - 1):
        ax.plot(t["z"] / t["z"][0], error[lod], lw=1, label=f"{t['faces'][lod]:,} faces")
    ax.set(xlabel="distance / z0", ylabel="error (Eq. 16)", xscale="log", yscale="log")
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    png = work / "profile.png"
    fig.savefig(png)
    plt.close(fig)
    save_png(Image.open(png), out / "profile.png", colors=64)


def lumigraph(work: Path, out: Path) -> None:
    """A small lumigraph captured, then played in the window."""
    folder = work / "lumigraph"
    lodsprite("lumigraph", "capture", "--st", "16", "--uv", "128", "--out", str(folder))
    shots = work / "lumigraph-shots"
    lodsprite("view", str(folder), "--play", "arc", "--frames", "30", "--size", SIZE,
              "--screenshots", str(shots), "--every", "10", "--exit", xvfb=True)
    save_png(strip(sorted(shots.glob("frame_*.png"))), out / "lumigraph.png")


def crowd(work: Path, out: Path) -> None:
    """A crowd of 300 continuous-LOD ogres walked through in the window."""
    shots = work / "crowd-shots"
    lodsprite("view", "crowd:300", "--play", "walk", "--frames", "30", "--size", SIZE,
              "--screenshots", str(shots), "--every", "10", "--exit", xvfb=True)
    save_png(strip(sorted(shots.glob("frame_*.png"))), out / "crowd.png")


def viewer_hud(work: Path, out: Path) -> None:
    """The window with its HUD: a virtual screen's own pixels, grabbed during a flight."""
    from PIL import ImageGrab

    exe = shutil.which("lodsprite")
    read_fd, write_fd = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write_fd), "-screen", "0", "640x480x24",
                             "-nolisten", "tcp"], pass_fds=(write_fd,))
    os.close(write_fd)
    with os.fdopen(read_fd) as f:
        display = ":" + f.readline().strip()
    args = ["view", "jacksboro", "--play", "swan2002", "--frames", "240", "--fps", "30",
            "--size", "640x480", "--exit"]
    print("$ lodsprite " + " ".join(args) + "   (on Xvfb; the screen grabbed while it flies)")
    view = subprocess.Popen([exe, *args], env=dict(os.environ, DISPLAY=display),
                            stdout=subprocess.DEVNULL)
    last, deadline = None, time.monotonic() + 180
    try:
        while view.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
            grab = ImageGrab.grab(xdisplay=display)
            if (np.asarray(grab).max(axis=2) > 0).mean() > 0.9:  # the window is up
                last = grab
    finally:
        view.wait(timeout=60)
        xvfb.terminate()
        xvfb.wait(timeout=10)
    if last is None:
        sys.exit("make_gallery: the viewer showed no window on Xvfb")
    save_png(last, out / "viewer.png", colors=192)


STEPS = (lod_sprite, viewer_hud, large_terrain, draped, distributed, profile, lumigraph,
         crowd)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "gallery",
                    help="folder for the runs' own outputs")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images",
                    help="folder for the pictures and the video")
    ap.add_argument("--only", nargs="+", choices=[s.__name__ for s in STEPS],
                    help="make only these pictures")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    args.work.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    for step in STEPS:
        if args.only and step.__name__ not in args.only:
            continue
        with tempfile.TemporaryDirectory(dir=args.work) as tmp:
            step(Path(tmp), args.out.resolve())
    summary = {"seconds": round(time.monotonic() - t0, 1),
               "files": sorted(p.name for p in args.out.iterdir())}
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
