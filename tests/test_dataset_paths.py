"""Paths in the dataset's own coordinates (``"coordinates": "dataset"``): an eye given as
easting, northing and height lands on the world point of that place, for a GeoTIFF in a
projected CRS, one in degrees and the store tiled from it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lodsprite.errors import PathError
from lodsprite.paths import get_path
from lodsprite.terrain.loaders import load_heightfield

ROWS, COLS, RES = 41, 57, 30.0
WEST, NORTH = 500000.0, 4100000.0


def pattern() -> np.ndarray:
    """Each sample's height tells its place: 1000 row + column (metres)."""
    r, c = np.mgrid[0:ROWS, 0:COLS]
    return (1000.0 * r + c).astype(np.float32)


def write_tif(path, crs="EPSG:32614", west=WEST, north=NORTH, res=RES):
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", height=ROWS, width=COLS, count=1,
                       dtype="float32", crs=crs,
                       transform=from_origin(west, north, res, res)) as ds:
        ds.write(pattern(), 1)
    return path


def path_file(tmp_path, frames) -> str:
    f = tmp_path / "flight.json"
    f.write_text(json.dumps({"format": "lodsprite-path", "version": 1,
                             "coordinates": "dataset", "frames": frames}))
    return str(f)


def cell_centre(r: int, c: int, west=WEST, north=NORTH, res=RES) -> tuple[float, float]:
    return west + (c + 0.5) * res, north - (r + 0.5) * res


@pytest.mark.parametrize("cells", [[(0, 0), (40, 56), (13, 29), (30, 5)]])
def test_an_eye_in_utm_lands_over_its_cell(tmp_path, cells):
    hf = load_heightfield(write_tif(tmp_path / "dem.tif")).scaled(2.0)
    frames = []
    for r, c in cells:
        e, n = cell_centre(r, c)
        frames.append({"eye": [e, n, 5000.0], "target": [e + 10.0, n + 20.0, 0.0]})
    path = get_path(path_file(tmp_path, frames), hf)
    for (r, c), vp in zip(cells, path.viewpoints, strict=True):
        under = float(hf.height_at(np.array([vp.o[0]]), np.array([vp.o[1]]))[0])
        assert under == pytest.approx(2.0 * (1000.0 * r + c), abs=1e-3)  # that cell
        assert vp.o[2] == pytest.approx(2.0 * 5000.0)  # heights exaggerated as the terrain
        # looking east-north-east and down: +x, +y (north) in the world
        assert -vp.z[0] > 0 and -vp.z[1] > 0 and -vp.z[2] < 0


def test_an_eye_in_degrees_lands_over_its_cell(tmp_path):
    res = 1.0 / 1200.0  # 3 arc-seconds
    tif = write_tif(tmp_path / "geo.tif", "EPSG:4326", -84.4, 36.7, res)
    hf = load_heightfield(tif)
    e, n = cell_centre(20, 17, -84.4, 36.7, res)
    path = get_path(path_file(tmp_path, [{"eye": [e, n, 900.0], "target": [e, n + res, 0.0]}]),
                    hf)
    o = path.viewpoints[0].o
    assert float(hf.height_at(np.array([o[0]]), np.array([o[1]]))[0]) == pytest.approx(
        1000.0 * 20 + 17, abs=1e-3)


def test_jacksboro_takes_a_path_in_degrees(tmp_path):
    """The built-in DEM (EPSG:4326) places an eye given in degrees over its centre at the
    world's origin."""
    hf = load_heightfield("jacksboro")
    m = hf.meta
    lon, lat = 0.5 * (m["west"] + m["east"]), 0.5 * (m["south"] + m["north"])
    vp = get_path(path_file(tmp_path, [{"eye": [lon, lat, 2000.0],
                                        "target": [lon, lat + 0.01, 0.0]}]), hf).viewpoints[0]
    np.testing.assert_allclose(vp.o, [0.0, 0.0, 2000.0], atol=1e-6)


def test_the_store_tiled_from_it_places_the_same_eye(tmp_path):
    from lodsprite.terrain.store import build_store

    tif = write_tif(tmp_path / "dem.tif")
    build_store(str(tif), tmp_path / "dem.zarr", tile=64, chunk=32)
    e, n = cell_centre(13, 29)
    f = path_file(tmp_path, [{"eye": [e, n, 5000.0], "target": [e, n + 50.0, 0.0]}])
    a = get_path(f, load_heightfield(tif)).viewpoints[0]
    b = get_path(f, load_heightfield(tmp_path / "dem.zarr")).viewpoints[0]
    np.testing.assert_allclose(a.o, b.o, atol=1e-6)


def test_a_dataset_path_over_a_terrain_without_a_crs_is_refused(tmp_path):
    f = path_file(tmp_path, [{"eye": [1.0, 2.0, 300.0], "target": [1.0, 50.0, 0.0]}])
    with pytest.raises(PathError, match="georeferenced terrain"):
        get_path(f, load_heightfield("fractal:64"))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "lodsprite-path", "version": 1,
                               "coordinates": "lonlat", "frames": [{}]}))
    with pytest.raises(PathError, match='"coordinates" must be'):
        get_path(str(bad), load_heightfield("fractal:64"))
