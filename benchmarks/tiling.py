"""Tiling speed of `lodsprite tile`, in MB/s of float32 level-0 heights written.

Sources: ``fractal:SIDE`` (generated tile by tile) and a GeoTIFF of the same side written
first as a Cloud Optimized-style file (512² tiles, DEFLATE with the floating-point
predictor, internal overviews), read back window by window with rasterio; and the real
Jacksboro DEM as a GeoTIFF.  No network here: the large GeoTIFF's heights are the
fractal's, but reading, decoding and tiling it is the real work on a real file.

    python benchmarks/tiling.py [--side 8192] [--out /tmp/tiling]
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import numpy as np


def write_geotiff(src_spec: str, path: Path, block: int = 2048) -> float:
    """Write ``src_spec`` to a tiled, compressed GeoTIFF with overviews; seconds taken."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import from_origin

    from lodsprite.terrain.tiled import open_source

    src = open_source(src_spec)
    t0 = time.perf_counter()
    profile = {"driver": "GTiff", "width": src.cols, "height": src.rows, "count": 1,
               "dtype": "float32", "crs": "EPSG:32614", "tiled": True, "blockxsize": 512,
               "blockysize": 512, "compress": "deflate", "predictor": 3, "nodata": -9999.0,
               "transform": from_origin(500000.0, 4000000.0, src.dx, src.dy), "BIGTIFF": "YES"}
    with rasterio.open(path, "w", **profile) as dst:
        for r0 in range(0, src.rows, block):
            for c0 in range(0, src.cols, block):
                r1, c1 = min(r0 + block, src.rows), min(c0 + block, src.cols)
                dst.write(src.read(r0, r1, c0, c1)[None], window=((r0, r1), (c0, c1)))
        dst.build_overviews([2, 4, 8, 16], Resampling.average)
    return time.perf_counter() - t0


def tile(spec: str, out: Path) -> dict:
    from lodsprite.terrain.store import build_store

    shutil.rmtree(out, ignore_errors=True)
    return build_store(spec, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--side", type=int, default=8192)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lodsprite-tiling"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    spec = f"fractal:{a.side}:1"
    tif = a.out / f"fractal_{a.side}.tif"
    wrote = write_geotiff(spec, tif)
    print(f"wrote {tif.name} ({tif.stat().st_size / 2**20:.0f} MB on disk) in {wrote:.1f} s")
    jack = a.out / "jacksboro.tif"
    from lodsprite.terrain.loaders import load_heightfield

    hf = load_heightfield("jacksboro")
    np.save(a.out / "jacksboro.npy", hf.heights)
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(jack, "w", driver="GTiff", width=hf.cols, height=hf.rows, count=1,
                       dtype="float32", crs="EPSG:32614",
                       transform=from_origin(0.0, 0.0, hf.dx, hf.dy)) as dst:
        dst.write(hf.heights[None])
    for name, source in ((spec, spec), (f"GeoTIFF {a.side}²", str(tif)),
                         (f"GeoTIFF jacksboro {hf.rows}x{hf.cols}", str(jack))):
        r = tile(source, a.out / "store.zarr")
        print(f"{name}: {r['seconds']:.2f} s, {r['mb_per_s']:.1f} MB/s of float32 heights, "
              f"{r['levels']} levels")


if __name__ == "__main__":
    main()
