"""``lodsprite info DATASET``: a GeoTIFF's and a store's CRS, extent, resolution, nodata
and levels, from their headers, against what was written."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import TerrainError
from lodsprite.terrain.describe import describe


@pytest.fixture
def utm_tif(tmp_path):
    """A 600 x 520 float32 DEM in UTM zone 14N, 30 m cells from (500000, 4100000)
    north-west, nodata -9999 in one corner, overviews 2 and 4."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import from_origin

    z = np.linspace(100.0, 400.0, 600 * 520, dtype=np.float32).reshape(600, 520)
    z[:4, :4] = -9999.0
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", height=600, width=520, count=1,
                       dtype="float32", crs="EPSG:32614", nodata=-9999.0,
                       transform=from_origin(500000.0, 4100000.0, 30.0, 30.0),
                       tiled=True, blockxsize=64, blockysize=64) as ds:
        ds.write(z, 1)
        ds.build_overviews([2, 4], Resampling.average)
    return path


def test_a_geotiffs_header_is_described_as_written(utm_tif):
    d = describe(utm_tif)
    assert d["CRS"] == "EPSG:32614"
    assert d["samples"] == "600 x 520, 1 band(s), float32"
    assert d["extent"] == "west 500000, south 4082000, east 515600, north 4100000"
    assert d["resolution"] == "30 x 30 metre"
    assert d["nodata"] == "-9999" and d["overviews"] == "2, 4"
    assert d["tiling"] == "tiled 64x64"


def test_a_stores_header_gives_its_levels_crs_and_extent(utm_tif, tmp_path):
    from lodsprite.terrain.store import build_store

    store = tmp_path / "dem.zarr"
    build_store(str(utm_tif), store, tile=64, chunk=32)
    d = describe(store)
    assert d["kind"].startswith("lodsprite terrain store") and d["complete"] == "yes"
    assert d["CRS"] == "EPSG:32614"
    assert d["samples"].startswith("600 x 520")
    assert d["resolution"] == "30 x 30 m"
    # halved until the longer side is at most 256 (rounded up)
    assert d["levels"] == "3: 600x520, 300x260, 150x130"
    assert d["extent"] == "west 500000, south 4082000, east 515600, north 4100000"
    assert d["imagery"].startswith("none")


def test_a_south_up_raster_and_an_unfinished_store_are_described_as_they_are(tmp_path):
    import rasterio
    from rasterio.transform import Affine

    from lodsprite.terrain.store import build_store

    path = tmp_path / "south-up.tif"  # row 0 south: a positive y cell size
    with rasterio.open(path, "w", driver="GTiff", height=300, width=280, count=1,
                       dtype="float32", crs="EPSG:32614",
                       transform=Affine(30.0, 0.0, 500000.0, 0.0, 30.0, 4091000.5)) as ds:
        ds.write(np.ones((300, 280), np.float32), 1)
    assert describe(path)["extent"] == ("west 500000, south 4091000.5, east 508400, "
                                        "north 4100000.5")
    store = tmp_path / "part.zarr"
    build_store(str(path), store, tile=64, chunk=32, stop_after=1)  # interrupted
    d = describe(store)
    assert d["complete"].startswith("no (resumable")
    assert d["levels"] == "2: 300x280, 150x140"


def test_a_store_header_with_a_broken_transform_is_one_error(tmp_path):
    import zarr

    from lodsprite.terrain.store_format import read_header

    g = zarr.open_group(str(tmp_path / "s.zarr"), mode="w")
    base = {"format": "lodsprite-terrain", "version": 1, "source": "x", "rows": 4,
            "cols": 4, "dx": 1.0, "dy": 1.0, "levels": 1, "tile": 64, "chunk": 32,
            "encoding": "float32"}
    for t in ([1.0, 0.0], [0.0, 0.0, 0.0, 0.0, -1.0, 0.0]):
        g.attrs["lodsprite"] = {**base, "transform": t}
        with pytest.raises(Exception, match="transform must be 6 finite numbers"):
            read_header(g)


def test_built_ins_and_refusals(tmp_path):
    assert describe("fractal:64:2")["samples"] == "65 x 65"
    assert describe("jacksboro")["CRS"] == "EPSG:4326"
    with pytest.raises(TerrainError, match="no such dataset"):
        describe(tmp_path / "missing.tif")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(TerrainError, match="describes a GeoTIFF"):
        describe(tmp_path / "notes.txt")
    (tmp_path / "bad.tif").write_bytes(b"not a tiff")
    with pytest.raises(TerrainError, match="cannot read"):
        describe(tmp_path / "bad.tif")


def test_info_prints_a_dataset_or_refuses_it_in_one_line(utm_tif, cli, tmp_path):
    proc = cli("info", utm_tif)
    assert proc.returncode == 0 and "EPSG:32614" in proc.stdout and "-9999" in proc.stdout
    proc = cli("info", tmp_path / "missing.zarr")
    lines = [x for x in (proc.stdout + proc.stderr).splitlines() if x.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "no such dataset" in lines[0]
