"""Tests of height-field loading (lodsprite.terrain.loaders) and load_terrain."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from PIL import Image

from lodsprite.errors import TerrainError
from lodsprite.terrain import DEFAULT_GRID, load_heightfield, load_terrain
from lodsprite.terrain.loaders import metres_per_degree, parse_fractal_spec

ARCSEC3 = 3.0 / 3600.0


def from_origin(west: float, north: float, xsize: float, ysize: float) -> rasterio.Affine:
    """North-up affine transform (as ``rasterio.transform.from_origin``, without its warning)."""
    return rasterio.Affine(xsize, 0.0, west, 0.0, -ysize, north)


def _relief(rows: int = 40, cols: int = 50) -> np.ndarray:
    """Smooth test relief ``(rows, cols) float64`` in metres, 100..900 m."""
    r, c = np.mgrid[0:rows, 0:cols]
    return 500.0 + 400.0 * np.sin(r / 7.0) * np.cos(c / 9.0)


def _write_tif(path, data, crs, transform, nodata=None, dtype=None):
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[None]
    with rasterio.open(path, "w", driver="GTiff", width=data.shape[2], height=data.shape[1],
                       count=data.shape[0], dtype=dtype or data.dtype, crs=crs,
                       transform=transform, nodata=nodata) as ds:
        ds.write(data.astype(dtype or data.dtype))
    return str(path)


# -- jacksboro --------------------------------------------------------------

@pytest.fixture(scope="module")
def jacksboro():
    return load_heightfield("jacksboro")


def test_jacksboro_shape_and_spacing_in_metres(jacksboro):
    assert jacksboro.heights.shape == (344, 403)
    assert jacksboro.heights.dtype == np.float32
    assert jacksboro.dx == pytest.approx(74.6, abs=0.5)      # 3" of longitude at 36.6 N
    assert jacksboro.dy == pytest.approx(92.5, abs=0.3)      # 3" of latitude
    assert jacksboro.width == pytest.approx(402 * jacksboro.dx)
    assert 236 <= jacksboro.heights.min() and jacksboro.heights.max() <= 1076


def test_jacksboro_row_zero_is_north(jacksboro):
    from matplotlib import cbook

    raw = cbook.get_sample_data("jacksboro_fault_dem.npz")
    raw = raw if hasattr(raw, "files") else np.load(raw)
    assert np.array_equal(jacksboro.heights, raw["elevation"].astype(np.float32))
    meta = jacksboro.meta
    assert meta["north"] == pytest.approx(36.7329, abs=1e-3)
    assert meta["north"] - meta["south"] == pytest.approx(344 * ARCSEC3)
    assert meta["filled_fraction"] == 0.0


def test_metres_per_degree():
    per_lat, per_lon = metres_per_degree(0.0)
    assert per_lat == pytest.approx(110574, abs=2)
    assert per_lon == pytest.approx(111320, abs=2)
    per_lat, per_lon = metres_per_degree(60.0)
    assert per_lat == pytest.approx(111412, abs=2)
    assert per_lon == pytest.approx(55800, abs=5)


# -- fractal specs ------------------------------------------------------------

def test_fractal_spec():
    hf = load_heightfield("fractal:32:5")
    assert hf.heights.shape == (33, 33)
    assert hf.meta["seed"] == 5
    assert np.array_equal(load_heightfield("fractal:32").heights,
                          load_heightfield("fractal:32:0").heights)
    assert parse_fractal_spec("fractal") == (DEFAULT_GRID, 0)
    assert parse_fractal_spec("jacksboro") is None


@pytest.mark.parametrize("spec", ["fractal:30", "fractal:abc", "fractal:64:x", "fractal:64:1:2",
                                  "fractal:"])
def test_bad_fractal_specs(spec):
    with pytest.raises(TerrainError):
        load_heightfield(spec)


# -- GeoTIFF ------------------------------------------------------------------

def test_geotiff_projected_with_nodata_holes(tmp_path):
    valid = _relief().round().astype(np.int16)
    data = valid.copy()
    data[10:14, 20:26] = -32768
    data[0, 0] = -32768
    path = _write_tif(tmp_path / "utm.tif", data, "EPSG:32616",
                      from_origin(500000, 4000000, 30, 30), nodata=-32768)
    hf = load_heightfield(path)
    assert hf.heights.shape == (40, 50)
    assert hf.dx == pytest.approx(30.0) and hf.dy == pytest.approx(30.0)
    good = data != -32768
    assert hf.heights.max() <= valid[good].max()
    assert hf.heights.min() >= valid[good].min()
    assert np.array_equal(hf.heights[good], valid[good].astype(np.float32))
    assert hf.meta["filled_fraction"] == pytest.approx((~good).mean())
    assert hf.meta["crs"] == "EPSG:32616"


def test_geotiff_sentinel_without_declared_nodata_is_not_a_spike(tmp_path):
    data = _relief().astype(np.float32)
    data[5, 5] = -32768.0
    data[6, 6] = np.nan
    path = _write_tif(tmp_path / "nodecl.tif", data, "EPSG:32616",
                      from_origin(500000, 4000000, 10, 10))
    hf = load_heightfield(path)
    assert hf.heights.min() >= np.nanmin(_relief()) - 1e-3
    assert hf.meta["filled_fraction"] == pytest.approx(2 / data.size)


def test_geotiff_feet_crs(tmp_path):
    # Tennessee State Plane, US survey feet: 100 ft pixels
    path = _write_tif(tmp_path / "feet.tif", _relief().astype(np.float32), "EPSG:2274",
                      from_origin(2_000_000, 600_000, 100, 100))
    hf = load_heightfield(path)
    assert hf.dx == pytest.approx(30.48, abs=0.01)
    assert hf.meta["linear_unit"] == "US survey foot"


def test_geotiff_geographic(tmp_path):
    lat_top = 36.6 + 20 * ARCSEC3
    path = _write_tif(tmp_path / "geo.tif", _relief().astype(np.float32), "EPSG:4326",
                      from_origin(-84.2, lat_top, ARCSEC3, ARCSEC3))
    hf = load_heightfield(path)
    per_lat, per_lon = metres_per_degree(36.6)
    assert hf.dx == pytest.approx(ARCSEC3 * per_lon, rel=1e-4)
    assert hf.dy == pytest.approx(ARCSEC3 * per_lat, rel=1e-4)
    assert hf.dx == pytest.approx(74.5, abs=0.5) and hf.dy == pytest.approx(92.5, abs=0.3)
    assert hf.meta["centre_lat"] == pytest.approx(36.6)


def test_geotiff_south_up_is_flipped_to_north_up(tmp_path):
    data = _relief().astype(np.float32)
    north_up = _write_tif(tmp_path / "n.tif", data, "EPSG:32616",
                          from_origin(500000, 4000000, 30, 30))
    # row 0 at the southern edge, rows going north
    south_up = _write_tif(tmp_path / "s.tif", data[::-1], "EPSG:32616",
                          rasterio.Affine(30, 0, 500000, 0, 30, 4000000 - 40 * 30))
    a = load_heightfield(north_up).heights
    b = load_heightfield(south_up).heights
    assert np.array_equal(a, b)


def test_geotiff_without_crs_assumes_metres(tmp_path):
    path = _write_tif(tmp_path / "nocrs.tif", _relief().astype(np.float32), None,
                      from_origin(0, 0, 5, 5))
    hf = load_heightfield(path)
    assert hf.dx == pytest.approx(5.0)
    assert "metres" in hf.meta["spacing_assumed"]
    assert hf.meta["crs"] is None


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_plain_tiff_without_georeferencing(tmp_path):
    data = _relief().astype(np.float32)
    path = tmp_path / "plain.tif"
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1,
                       dtype="float32") as ds:
        ds.write(data, 1)
    hf = load_heightfield(str(path))
    assert np.array_equal(hf.heights, data)          # image row 0 stays row 0
    assert hf.dx == hf.dy == 30.0
    assert "no georeferencing" in hf.meta["spacing_assumed"]


def test_geotiff_two_bands_rejected(tmp_path):
    data = np.stack([_relief(), _relief()]).astype(np.float32)
    path = _write_tif(tmp_path / "two.tif", data, "EPSG:32616",
                      from_origin(500000, 4000000, 30, 30))
    with pytest.raises(TerrainError, match="expected 1 band, found 2"):
        load_heightfield(path)


def test_geotiff_corrupt(tmp_path):
    path = tmp_path / "corrupt.tif"
    path.write_bytes(b"II*\x00" + bytes(range(256)) * 4)
    with pytest.raises(TerrainError, match="corrupt.tif"):
        load_heightfield(str(path))


def test_geotiff_truncated(tmp_path):
    _write_tif(tmp_path / "good.tif", _relief().astype(np.float32), "EPSG:32616",
               from_origin(500000, 4000000, 30, 30))
    truncated = tmp_path / "trunc.tif"
    blob = (tmp_path / "good.tif").read_bytes()
    truncated.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(TerrainError, match="trunc.tif"):
        load_heightfield(str(truncated))


def test_geotiff_one_row_rejected(tmp_path):
    path = _write_tif(tmp_path / "row.tif", _relief(1, 50).astype(np.float32), "EPSG:32616",
                      from_origin(500000, 4000000, 30, 30))
    with pytest.raises(TerrainError, match="row.tif.*2x2"):
        load_heightfield(path)


def test_geotiff_all_nodata(tmp_path):
    data = np.full((10, 10), -9999.0, dtype=np.float32)
    path = _write_tif(tmp_path / "empty.tif", data, "EPSG:32616",
                      from_origin(500000, 4000000, 30, 30), nodata=-9999.0)
    with pytest.raises(TerrainError, match="contains no valid heights"):
        load_heightfield(path)


# -- PNG ------------------------------------------------------------------------

def test_png_8bit(tmp_path):
    data = (np.arange(12 * 16).reshape(12, 16) % 256).astype(np.uint8)
    path = tmp_path / "h8.png"
    Image.fromarray(data).save(path)
    hf = load_heightfield(str(path))
    assert np.array_equal(hf.heights, data.astype(np.float32))
    assert hf.dx == hf.dy == 30.0
    assert hf.meta["bit_depth"] == 8


def test_png_16bit(tmp_path):
    data = (np.arange(12 * 16).reshape(12, 16) * 40).astype(np.uint16)
    path = tmp_path / "h16.png"
    Image.fromarray(data).save(path)
    hf = load_heightfield(str(path))
    assert np.array_equal(hf.heights, data.astype(np.float32))
    assert hf.heights.max() == 191 * 40


def test_png_rgb_rejected(tmp_path):
    path = tmp_path / "rgb.png"
    Image.fromarray(np.zeros((8, 8, 3), dtype=np.uint8)).save(path)
    with pytest.raises(TerrainError, match="expected a greyscale PNG"):
        load_heightfield(str(path))


def test_png_corrupt(tmp_path):
    path = tmp_path / "junk.png"
    path.write_bytes(b"not a png at all")
    with pytest.raises(TerrainError, match="junk.png"):
        load_heightfield(str(path))


# -- NPY --------------------------------------------------------------------------

def test_npy_with_nan_holes(tmp_path):
    valid = _relief()
    data = valid.copy()
    data[3:8, 3:8] = np.nan
    path = tmp_path / "h.npy"
    np.save(path, data)
    hf = load_heightfield(str(path))
    assert hf.heights.shape == (40, 50)
    assert np.all(np.isfinite(hf.heights))
    assert hf.heights.max() <= np.nanmax(data) + 1e-3
    assert hf.heights.min() >= np.nanmin(data) - 1e-3
    assert hf.meta["filled_fraction"] == pytest.approx(25 / data.size)
    assert hf.dx == hf.dy == 30.0


def test_npy_int16_void_value_is_filled(tmp_path):
    data = _relief().round().astype(np.int16)
    data[20, 20] = -32768
    path = tmp_path / "void.npy"
    np.save(path, data)
    hf = load_heightfield(path)                  # a pathlib.Path works too
    assert hf.heights[20, 20] > 0


@pytest.mark.parametrize("array, match", [
    (np.array([["a", "b"], ["c", "d"]]), "real numbers"),
    (np.ones((1, 20)), "2x2"),
    (np.ones((20, 1)), "2x2"),
    (np.ones(20), "2-D"),
    (np.ones((2, 2), dtype=complex), "real numbers"),
    (np.full((5, 5), np.nan), "contains no valid heights"),
])
def test_bad_npy(tmp_path, array, match):
    path = tmp_path / "bad.npy"
    np.save(path, array)
    with pytest.raises(TerrainError, match=match):
        load_heightfield(str(path))
    with pytest.raises(TerrainError, match="bad.npy"):
        load_heightfield(str(path))


def test_npy_object_array_rejected(tmp_path):
    path = tmp_path / "obj.npy"
    np.save(path, np.array([[1, None], [2, 3]], dtype=object), allow_pickle=True)
    with pytest.raises(TerrainError, match="obj.npy"):
        load_heightfield(str(path))


def test_npy_mostly_nodata_rejected(tmp_path):
    data = _relief()
    data[:30] = np.nan
    path = tmp_path / "holes.npy"
    np.save(path, data)
    with pytest.raises(TerrainError, match="nodata"):
        load_heightfield(str(path))


# -- paths and specs -------------------------------------------------------------

def test_missing_file(tmp_path):
    missing = tmp_path / "absent.tif"
    with pytest.raises(TerrainError, match="absent.tif"):
        load_heightfield(str(missing))


def test_unknown_spec():
    with pytest.raises(TerrainError, match="no such terrain file or built-in: foo"):
        load_heightfield("foo")


def test_unsupported_extension(tmp_path):
    path = tmp_path / "heights.txt"
    path.write_text("1 2\n3 4\n")
    with pytest.raises(TerrainError, match="unsupported.*heights.txt"):
        load_heightfield(str(path))


@pytest.mark.parametrize("spec", ["", "   "])
def test_empty_spec(spec):
    with pytest.raises(TerrainError):
        load_heightfield(spec)


# -- load_terrain ------------------------------------------------------------------

def test_load_terrain_resamples_and_exaggerates():
    flat = load_terrain("jacksboro", grid=64, exaggeration=1.0)
    assert flat.heights.shape == (65, 65)
    assert flat.width == pytest.approx(load_heightfield("jacksboro").width)
    tall = load_terrain("jacksboro", grid=64, exaggeration=3.0)
    assert np.allclose(tall.heights, 3.0 * flat.heights, rtol=1e-6)
    assert tall.meta["exaggeration"] == 3.0


def test_load_terrain_grid_defaults():
    assert load_terrain("fractal:32:1").heights.shape == (33, 33)
    assert load_terrain("jacksboro").heights.shape == (DEFAULT_GRID + 1, DEFAULT_GRID + 1)


def test_load_terrain_bad_grid_or_exaggeration():
    with pytest.raises(TerrainError):
        load_terrain("fractal:32", grid=100)
    with pytest.raises(TerrainError):
        load_terrain("fractal:32", exaggeration=0.0)
