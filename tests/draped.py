"""A terrain store draped with a two-colour orthophoto, for the page's and the widget's
imagery tests: ``write_draped(DEM, STORE)`` tiles a DEM (a north-up GeoTIFF) with an
orthophoto over the same extent, its west half ``WEST_RGB`` and east half ``EAST_RGB``,
credited ``IMAGERY_CREDIT``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

IMAGERY_CREDIT = "(c) the test's orthophoto, CC0"
WEST_RGB, EAST_RGB = (220, 30, 30), (30, 30, 220)


def write_draped(dem: Path, store: Path) -> Path:
    import rasterio

    from lodsprite.terrain.store import build_store

    with rasterio.open(dem) as d:
        crs, t, rows, cols = d.crs, d.transform, d.height, d.width
    a = np.empty((3, 2 * rows, 2 * cols), np.uint8)
    a[:, :, :cols] = np.array(WEST_RGB, np.uint8)[:, None, None]
    a[:, :, cols:] = np.array(EAST_RGB, np.uint8)[:, None, None]
    ortho = store.parent / f"{store.stem}-ortho.tif"
    with rasterio.open(ortho, "w", driver="GTiff", height=2 * rows, width=2 * cols, count=3,
                       dtype="uint8", crs=crs, photometric="RGB",
                       transform=t * t.scale(0.5, 0.5)) as ds:
        ds.write(a)
    build_store(str(dem), store, tile=64, chunk=32, imagery=[str(ortho)],
                attribution=IMAGERY_CREDIT)
    return store


def flat_dem(path: Path, side: int = 65, height: float = 500.0, cell: float = 30.0) -> Path:
    """A flat DEM of ``side²`` cells of ``cell`` metres at ``height`` in UTM zone 14N."""
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", height=side, width=side, count=1,
                       dtype="float32", crs="EPSG:32614",
                       transform=from_origin(500000.0, 4100000.0, cell, cell)) as ds:
        ds.write(np.full((side, side), height, np.float32), 1)
    return path
