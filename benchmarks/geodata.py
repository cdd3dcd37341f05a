"""Real geodata's figures: imagery alignment, a 16k² DEM with a 16k² orthophoto tiled and
flown, bytes fetched over HTTP, and the colour codec's own error.

Parts (``--parts``, default all):

* ``align``: a synthetic orthophoto in EPSG:4326 with marked ground points (magenta
  squares at known longitudes and latitudes) over a DEM in UTM zone 14N with relief,
  tiled into a store; a nadir full-resolution frame (``Renderer.render``); each mark's
  centroid in the frame cast onto the drawn surface, taken to UTM and set against the
  mark's own place.  Target: every mark within half a DEM cell (ground metres).
* ``scale``: ``fractal:SIZE`` (default 16384) with a generated SIZE² RGB orthophoto
  (colours from the heights and a noise texture, no CRS: stretched over the DEM) tiled by
  ``lodsprite tile`` in a child process: wall time and the child's peak RSS; then
  chen1999 (``--frames``) flown with ``render --mode adaptive`` and LOD-sprite with
  adaptive keyframes (``--mode sprite --key-sse 0.5``), imagery (``--shading auto``)
  against the heights shading (``--shading heights``) on the same store, alternated
  ``--repeats`` times: the ratio of median frame times.  Target: tiled in ≤ 15 min at
  ≤ 2 GB, imagery within 1.3× of without.
* ``remote``: a COG and a store served by aiohttp's static route on loopback
  (``tests/range_server.py``, counting the body bytes it sends); ``tile`` of the COG and
  ``render --mode adaptive`` of the store with a fresh cache: bytes fetched against the
  bytes used (the COG's level-0 tiles, read by rasterio's ``block_size``; the store reads'
  byte ranges, traced by ``LODSPRITE_HTTP_TRACE``), then the same with the cache: bytes
  fetched.  Target: ≤ 1.5× and none.
* ``codec``: the stored imagery decoded against the warped sources (``mosaic`` of the
  store's sources, the warp the build does) over sampled windows: max and RMS error,
  stored size against raw RGBA, decode MB/s.

    python benchmarks/geodata.py --work /tmp/geo [--size 16384] [--parts align scale ...]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

UTM, W0, N0, CELL = "EPSG:32614", 600000.0, 3700000.0, 30.0


def sh(*args: str, env: dict | None = None) -> tuple[float, float]:
    """Run ``lodsprite ARGS`` in a child; (wall seconds, the largest child's peak RSS MB
    so far: ``RUSAGE_CHILDREN`` keeps the maximum over every child waited for)."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from lodsprite.cli import main; main()", *args],
                       capture_output=True, text=True, env={**os.environ, **(env or {})})
    if r.returncode:
        raise SystemExit(f"lodsprite {' '.join(args)} failed: {r.stderr.strip()[-400:]}")
    return time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


# ---------------------------------------------------------------------------- align


def align(work: Path) -> dict:
    import rasterio
    from rasterio.transform import from_origin
    from rasterio.warp import transform, transform_bounds

    from lodsprite.api import Renderer
    from lodsprite.camera import look_at
    from lodsprite.gl.context import GLContext
    from lodsprite.scene import load_scene
    from lodsprite.terrain.store import build_store

    side = 257
    yy, xx = np.mgrid[0:side, 0:side]
    h = (60 * np.sin(xx / 17.0) * np.cos(yy / 23.0) + 25 * np.sin((xx + yy) / 7.0) + 400)
    dem = work / "align_dem.tif"
    with rasterio.open(dem, "w", driver="GTiff", width=side, height=side, count=1,
                       dtype="float32", crs=UTM, transform=from_origin(W0, N0, CELL, CELL)) as f:
        f.write(h.astype("float32"), 1)
    w, s, e, n = transform_bounds(UTM, "EPSG:4326", W0, N0 - side * CELL, W0 + side * CELL, N0)
    px = 0.00005  # about 5 m: a refinement of 2 (7.5 m texels)
    cols, rows = int((e - w) / px) + 40, int((n - s) / px) + 40
    lon0, lat0 = w - 20 * px, n + 20 * px
    rng = np.random.default_rng(7)
    img = (rng.integers(60, 140, (3, rows, cols))).astype(np.uint8)  # a noisy ground
    img[2] //= 2
    marks = []
    for i in range(6):
        for j in range(6):
            lon = w + (j + 0.5) / 6 * (e - w)
            lat = s + (i + 0.5) / 6 * (n - s)
            c, r = int((lon - lon0) / px), int((lat0 - lat) / px)
            img[:, r - 2: r + 3, c - 2: c + 3] = np.array([255, 0, 255], np.uint8)[:, None, None]
            marks.append((lon0 + (c + 0.5) * px, lat0 - (r + 0.5) * px))
    ortho = work / "align_ortho.tif"
    with rasterio.open(ortho, "w", driver="GTiff", width=cols, height=rows, count=3,
                       dtype="uint8", crs="EPSG:4326", photometric="RGB",
                       transform=from_origin(lon0, lat0, px, px)) as f:
        f.write(img)
    store = work / "align.zarr"
    shutil.rmtree(store, ignore_errors=True)
    build_store(str(dem), store, imagery=[str(ortho)])
    scene = load_scene(str(store), "terrain", None, 1.0)
    size, fov = 1400, 40.0
    half = 0.5 * (side - 1) * CELL
    height = half / np.tan(np.radians(fov / 2)) + 600
    vp = look_at((0.0, 0.0, height), (0.0, 0.0, 0.0), up=(0, 1, 0))
    ctx = GLContext()
    with Renderer(scene, (size, size), fov, ctx=ctx.mgl) as r:
        r.render(vp)
        frame = r.read_color().astype(int)
        proj = r.projection(vp)
    ctx.release()
    magenta = (frame[..., 0] > 200) & (frame[..., 1] < 60) & (frame[..., 2] > 200)
    from scipy import ndimage

    labels, count = ndimage.label(magenta)
    centres = np.array(ndimage.center_of_mass(magenta, labels, range(1, count + 1)))
    inv = np.linalg.inv(proj.matrix() @ vp.view_matrix())
    ndc = np.stack([(centres[:, 1] + 0.5) / size * 2 - 1, 1 - (centres[:, 0] + 0.5) / size * 2,
                    np.ones(len(centres)), np.ones(len(centres))], 1)
    far = ndc @ inv.T
    far = far[:, :3] / far[:, 3:]
    eye = np.asarray(vp.o)
    d = far - eye
    lo, hi = np.zeros(len(d)), np.ones(len(d))
    for _ in range(60):
        mid = (lo + hi) / 2
        p = eye + d * mid[:, None]
        above = p[:, 2] > scene.hf.height_at(p[:, 0], p[:, 1])
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    ground = eye + d * lo[:, None]
    found_e = W0 + CELL / 2 + half + ground[:, 0]
    found_n = N0 - CELL / 2 - half + ground[:, 1]
    true_e, true_n = (np.asarray(v) for v in transform("EPSG:4326", UTM, *zip(*marks, strict=True)))
    errs = [float(np.min(np.hypot(true_e - fe, true_n - fn)))
            for fe, fn in zip(found_e, found_n, strict=True)]
    return {"marks": len(marks), "found": int(count), "pixel_m": 2 * height *
            np.tan(np.radians(fov / 2)) / size, "max_m": max(errs),
            "median_m": float(np.median(errs)), "half_cell_m": CELL / 2,
            "ok": count == len(marks) and max(errs) <= CELL / 2}


# ---------------------------------------------------------------------------- scale


def make_ortho(path: Path, size: int) -> None:
    """A ``size²`` RGB orthophoto without a CRS made from ``fractal:size``'s heights: a
    green-brown-grey ramp, lit, with a fine noise texture; written window by window."""
    import rasterio

    from lodsprite.terrain.textures import height_shading
    from lodsprite.terrain.tiled import parse_fractal

    src = parse_fractal(f"fractal:{size}")
    lo, hi = -1500.0, 3500.0
    rng = np.random.default_rng(1)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3,
                       dtype="uint8", tiled=True, blockxsize=512, blockysize=512,
                       compress="deflate", photometric="RGB") as f:
        step = 2048
        for r0 in range(0, size, step):
            for c0 in range(0, size, step):
                r1, c1 = min(size, r0 + step), min(size, c0 + step)
                h = src.read(r0, r1, c0, c1)
                rgb = height_shading(h, 30.0, 30.0, lo, hi).astype(np.int16)
                rgb += rng.integers(-18, 19, rgb.shape[:2], dtype=np.int16)[..., None]
                f.write(np.clip(rgb, 0, 255).astype(np.uint8).transpose(2, 0, 1),
                        window=((r0, r1), (c0, c1)))


def scale(work: Path, size: int, frames: int, repeats: int, retile: bool = True) -> dict:
    ortho = work / f"ortho{size}.tif"
    if not ortho.exists():
        t0 = time.perf_counter()
        make_ortho(ortho, size)
        print(f"  made the {size}² orthophoto in {time.perf_counter() - t0:.0f} s", flush=True)
    store = work / f"f{size}_img.zarr"
    out: dict = {}
    if retile or not store.exists():
        shutil.rmtree(store, ignore_errors=True)
        wall, rss = sh("tile", f"fractal:{size}", "--out", str(store), "--imagery", str(ortho))
        out = {"tile_s": wall, "tile_peak_rss_mb": rss}
        print(f"  tiled in {wall:.0f} s, peak RSS {rss:.0f} MB", flush=True)
    out["store_gb"] = sum(f.stat().st_size for f in store.rglob("*") if f.is_file()) / 2 ** 30
    for mode, extra in (("adaptive", ()), ("sprite", ("--key-sse", "0.5"))):
        med = {"auto": [], "heights": []}
        for rep in range(repeats):
            for shading in ("auto", "heights") if rep % 2 == 0 else ("heights", "auto"):
                run = work / f"run_{mode}_{shading}_{rep}"
                sh("render", "--terrain", str(store), "--mode", mode, *extra, "--path",
                   "chen1999", "--frames", str(frames), "--size", "640x480", "--shading",
                   shading, "--out", str(run))
                summary = json.loads((run / "summary.json").read_text())
                med[shading].append(summary["median_ms"])
        ratio = float(np.median(med["auto"]) / np.median(med["heights"]))
        out[mode] = {"imagery_ms": med["auto"], "heights_ms": med["heights"], "ratio": ratio}
        print(f"  {mode}: imagery {np.median(med['auto']):.1f} ms, heights "
              f"{np.median(med['heights']):.1f} ms, ratio {ratio:.2f}", flush=True)
    return out


# ---------------------------------------------------------------------------- remote


def served(folder: Path):
    proc = subprocess.Popen([sys.executable, str(HERE.parent / "tests" / "range_server.py"),
                             str(folder)], stdout=subprocess.PIPE, text=True)
    port = int(proc.stdout.readline())
    return proc, f"http://127.0.0.1:{port}"


def server_stats(base: str, reset: bool = False) -> dict:
    with urllib.request.urlopen(f"{base}/{'_reset' if reset else '_stats'}") as r:
        return json.loads(r.read())


def used_bytes(trace: Path) -> int:
    """The bytes of the union of the traced ranges (a range read twice counts once)."""
    spans: dict[str, list] = {}
    for line in trace.read_text().splitlines():
        path, a, b = line.split("\t")
        spans.setdefault(path, []).append((int(a), int(b)))
    total = 0
    for ranges in spans.values():
        end = -1
        for a, b in sorted(ranges):
            if b > end:
                total += b - max(a, end)
                end = b
    return total


def remote(work: Path, cog_side: int) -> dict:
    import rasterio

    folder = work / "served"
    folder.mkdir(exist_ok=True)
    cog = folder / "dem_cog.tif"
    store = folder / "dem.zarr"
    if not cog.exists():
        from lodsprite.terrain.tiled import parse_fractal

        src = parse_fractal(f"fractal:{cog_side}")
        with rasterio.open(cog, "w", driver="GTiff", width=cog_side, height=cog_side, count=1,
                           dtype="float32", crs=UTM, tiled=True, blockxsize=256,
                           blockysize=256, compress="deflate", predictor=3,
                           transform=rasterio.transform.from_origin(W0, N0, CELL, CELL)) as f:
            for r0 in range(0, cog_side, 1024):
                h = src.read(r0, min(cog_side, r0 + 1024), 0, cog_side)
                f.write(h, 1, window=((r0, r0 + h.shape[0]), (0, cog_side)))
            f.build_overviews([2, 4, 8, 16])
    if not store.exists():
        sh("tile", str(cog), "--out", str(store))
    with rasterio.open(cog) as ds:
        bw, bh = ds.block_shapes[0]
        level0 = sum(ds.block_size(1, i, j) for i in range(-(-ds.height // bh))
                     for j in range(-(-ds.width // bw)))
    proc, base = served(folder)
    out: dict = {"cog_mb": cog.stat().st_size / 2 ** 20, "cog_level0_tiles_mb": level0 / 2 ** 20}
    try:
        for what, args in (("tile", ("tile", f"{base}/dem_cog.tif", "--out",
                                     str(work / "from_http.zarr"), "--overwrite")),
                           ("render", ("render", "--terrain", f"{base}/dem.zarr", "--mode",
                                       "adaptive", "--path", "chen1999", "--frames", "120",
                                       "--size", "640x480", "--out", str(work / "http_run")))):
            cache = work / f"cache_{what}"
            shutil.rmtree(cache, ignore_errors=True)
            trace = work / f"trace_{what}.tsv"
            trace.unlink(missing_ok=True)
            env = {"LODSPRITE_HTTP_CACHE": str(cache), "LODSPRITE_HTTP_TRACE": str(trace)}
            server_stats(base, reset=True)
            sh(*args, env=env)
            first = server_stats(base)
            used = level0 if what == "tile" else used_bytes(trace)
            server_stats(base, reset=True)
            sh(*args, env=env)
            second = server_stats(base)
            out[what] = {"fetched_mb": first["bytes"] / 2 ** 20, "used_mb": used / 2 ** 20,
                         "ratio": first["bytes"] / max(used, 1), "requests": first["requests"],
                         "cached_run_fetched_bytes": second["bytes"],
                         "cached_run_requests": second["requests"]}
            print(f"  {what}: fetched {first['bytes'] / 2 ** 20:.2f} MB for "
                  f"{used / 2 ** 20:.2f} MB used ({out[what]['ratio']:.2f}x, "
                  f"{first['requests']} requests); cached run {second['bytes']} bytes",
                  flush=True)
    finally:
        proc.kill()
    return out


# ---------------------------------------------------------------------------- codec


def codec(store: Path, windows: int = 12) -> dict:
    from lodsprite.terrain.store import TerrainStore
    from lodsprite.terrain.store_imagery import gdal_env, open_sources

    st = TerrainStore(store)
    im = st.imagery
    raw = im.rows * im.cols * 4 * 4 / 3  # every level, RGBA
    stored = sum(f.stat().st_size for f in (store / "imagery").rglob("*") if f.is_file())
    rng = np.random.default_rng(3)
    worst, sq, n = 0, 0.0, 0
    with gdal_env():
        sources = open_sources([s.path for s in im.sources], st.header)
        for s in sources:
            s.warp(im.refine)
        from lodsprite.terrain.imagery import mosaic

        for _ in range(windows):
            r0 = int(rng.integers(0, max(1, im.rows - 256)))
            c0 = int(rng.integers(0, max(1, im.cols - 256)))
            r1, c1 = min(im.rows, r0 + 256), min(im.cols, c0 + 256)
            want = mosaic(sources, r0, r1, c0, c1).astype(int)
            got = st.read_imagery(0, r0, r1, c0, c1).astype(int)
            d = np.abs(got - want)
            worst = max(worst, int(d.max()))
            sq += float((d.astype(float) ** 2).sum())
            n += d.size
        for s in sources:
            s.close()
    j = min(2, im.levels - 1)
    r, c = st.group[f"imagery/{j}"].shape[:2]
    t0 = time.perf_counter()
    a = st.read_imagery(j, 0, r, 0, c)
    dt = time.perf_counter() - t0
    return {"max_abs": worst, "rms": (sq / max(n, 1)) ** 0.5, "stored_mb": stored / 2 ** 20,
            "raw_mb": raw / 2 ** 20, "ratio": stored / raw,
            "decode_mb_s": a.nbytes / 2 ** 20 / dt, "codec": im.codec}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--size", type=int, default=16384)
    ap.add_argument("--frames", type=int, default=460)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--cog-side", type=int, default=4096)
    ap.add_argument("--parts", nargs="+", default=["align", "scale", "remote", "codec"])
    ap.add_argument("--keep-store", action="store_true",
                    help="scale: fly the store already tiled in --work (no tiling figures)")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="geodata-"))
    work.mkdir(parents=True, exist_ok=True)
    from lodsprite.gl.context import GLContext

    ctx = GLContext()
    machine = f"{os.cpu_count()} cores, GL {ctx.info.renderer}"
    ctx.release()
    print(f"machine: {machine}; work in {work}", flush=True)
    results: dict = {"machine": machine}
    if "align" in a.parts:
        results["align"] = align(work)
        print("align:", json.dumps(results["align"]), flush=True)
    if "scale" in a.parts:
        results["scale"] = scale(work, a.size, a.frames, a.repeats, not a.keep_store)
        print("scale:", json.dumps(results["scale"]), flush=True)
    if "remote" in a.parts:
        results["remote"] = remote(work, a.cog_side)
        print("remote:", json.dumps(results["remote"]), flush=True)
    if "codec" in a.parts:
        store = work / f"f{a.size}_img.zarr"
        results["codec"] = codec(store if store.exists() else work / "align.zarr")
        print("codec:", json.dumps(results["codec"]), flush=True)
    (work / "geodata.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
