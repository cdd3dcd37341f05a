"""Terrain pyramids in Zarr v3 stores, built by streaming (issue 16, first part)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import run_cli
from lodsprite.errors import InputError
from lodsprite.terrain.store import TerrainStore, build_store, downsample
from lodsprite.terrain.tiled import parse_fractal


def levels_of(path):
    st = TerrainStore(path)
    return st, [st.read(k, 0, st.shape(k)[0], 0, st.shape(k)[1]) for k in range(st.levels)]


def test_levels_are_exact_downsamples_and_chunk_bounds_hold(tmp_path):
    build_store("fractal:702x1000:3", tmp_path / "s.zarr", tile=256, chunk=64)
    st, lv = levels_of(tmp_path / "s.zarr")
    assert [a.shape for a in lv] == [(702, 1000), (351, 500), (176, 250)]
    for k in range(1, len(lv)):
        np.testing.assert_array_equal(lv[k], downsample(lv[k - 1]))
    # level 1 has an odd number of rows: its last row is averaged with itself
    np.testing.assert_allclose(lv[2][-1, 0], lv[1][-1, 0:2].mean(), rtol=1e-6)
    np.testing.assert_allclose(lv[1][0, 0], lv[0][0:2, 0:2].mean(), rtol=1e-6)
    mm = st.minmax(0)
    assert mm.shape == (11, 16, 3)
    block = lv[0][64:128, 192:256]
    np.testing.assert_allclose(mm[1, 3], [block.min(), block.max(), 0.0])
    # level 1's error: its triangulated grid against level 0, by hand at one sample
    e1 = st.minmax(1)[..., 2]
    c, f = lv[1], lv[0]
    by_hand = max(abs(f[2 * 5 + 1, 2 * 7 + 1] - (c[5, 7] + c[6, 8]) / 2),
                  abs(f[2 * 5 + 1, 2 * 7] - (c[5, 7] + c[6, 7]) / 2),
                  abs(f[2 * 5, 2 * 7 + 1] - (c[5, 7] + c[5, 8]) / 2), abs(f[10, 14] - c[5, 7]))
    assert e1[0, 0] >= by_hand - 1e-3
    assert st.header.level_errors[0] == 0 and st.header.level_errors[1] == pytest.approx(
        float(e1.max()), rel=1e-6)
    assert st.header.level_errors[2] > st.header.level_errors[1]


def test_the_same_samples_whatever_the_tiling(tmp_path):
    build_store("fractal:600x520:9", tmp_path / "a.zarr", tile=128, chunk=64)
    build_store("fractal:600x520:9", tmp_path / "b.zarr", tile=512, chunk=128)
    _, a = levels_of(tmp_path / "a.zarr")
    _, b = levels_of(tmp_path / "b.zarr")
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    # and a window read across tile borders is the generator's own
    src = parse_fractal("fractal:600x520:9")
    np.testing.assert_array_equal(a[0][100:300, 90:400], src.read(100, 300, 90, 400))


def test_tiling_the_same_source_twice_gives_identical_stores(tmp_path):
    for name in ("a", "b"):
        build_store("fractal:300x400:1", tmp_path / f"{name}.zarr", tile=128, chunk=64,
                    encoding="int16", scale=0.1)
    ha = json.loads((tmp_path / "a.zarr" / "zarr.json").read_text())["attributes"]
    hb = json.loads((tmp_path / "b.zarr" / "zarr.json").read_text())["attributes"]
    assert ha == hb
    _, a = levels_of(tmp_path / "a.zarr")
    _, b = levels_of(tmp_path / "b.zarr")
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    # int16: within half a step of the float source
    src = parse_fractal("fractal:300x400:1").read(0, 300, 0, 400)
    assert np.abs(a[0] - src).max() <= 0.05 + 1e-3


def write_geotiff(path, heights, nodata=-9999.0):
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", height=heights.shape[0],
                       width=heights.shape[1], count=1, dtype="float32", crs="EPSG:32614",
                       transform=from_origin(500000, 4000000, 10.0, 12.0),
                       nodata=nodata) as ds:
        ds.write(heights.astype(np.float32), 1)


def test_a_non_square_geotiff_keeps_rows_columns_spacing_and_values(tmp_path):
    rng = np.random.default_rng(0)
    h = rng.uniform(100, 900, (300, 517))
    h[40:50, 60:75] = -9999.0                        # a nodata hole
    write_geotiff(tmp_path / "dem.tif", h)
    build_store(str(tmp_path / "dem.tif"), tmp_path / "d.zarr", tile=128, chunk=64)
    st, lv = levels_of(tmp_path / "d.zarr")
    assert (st.header.rows, st.header.cols) == (300, 517)
    assert (st.header.dx, st.header.dy) == (10.0, 12.0) and "32614" in st.header.crs
    ok = h != -9999.0
    np.testing.assert_allclose(lv[0][ok], h[ok], rtol=1e-6)
    assert np.isfinite(lv[0]).all()                  # the hole filled from its neighbours


def test_an_all_nodata_dem_is_refused_before_anything_is_written(tmp_path):
    write_geotiff(tmp_path / "empty.tif", np.full((64, 80), -9999.0))
    with pytest.raises(InputError, match="nodata"):
        build_store(str(tmp_path / "empty.tif"), tmp_path / "e.zarr")
    assert not (tmp_path / "e.zarr").exists()


def test_an_interrupted_build_is_refused_then_resumes_to_the_same_store(tmp_path):
    out = tmp_path / "r.zarr"
    r = build_store("fractal:600x600:4", out, tile=128, chunk=64, stop_after=7)
    assert r["interrupted"]
    with pytest.raises(InputError, match="did not finish"):
        TerrainStore(out)
    s = build_store("fractal:600x600:4", out, tile=128, chunk=64)
    assert s["resumed"] and s["tiles_written"] > 0
    build_store("fractal:600x600:4", tmp_path / "fresh.zarr", tile=128, chunk=64)
    _, a = levels_of(out)
    _, b = levels_of(tmp_path / "fresh.zarr")
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_a_corrupt_store_is_one_line_and_exit_code_2(tmp_path, cli):
    build_store("fractal:200x200:1", tmp_path / "c.zarr", tile=128, chunk=64)
    (tmp_path / "c.zarr" / "zarr.json").write_text("{not json")
    with pytest.raises(InputError):
        TerrainStore(tmp_path / "c.zarr")
    r = cli("render", "--terrain", str(tmp_path / "c.zarr"), "--frames", "2",  # in-process
            "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1
    assert not (tmp_path / "o").exists()


def test_every_terrain_command_takes_a_store(tmp_path):
    from lodsprite.terrain import load_terrain

    build_store("fractal:300x500:2", tmp_path / "t.zarr", tile=128, chunk=64)
    hf = load_terrain(str(tmp_path / "t.zarr"), grid=64)
    assert hf.heights.shape == (65, 65) and np.isfinite(hf.heights).all()


def test_a_dask_cluster_builds_the_same_store(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True,
                                  dashboard_address=None) as cluster:
        build_store("fractal:400x300:6", tmp_path / "d.zarr", tile=128, chunk=64,
                    scheduler=cluster.scheduler_address)
    build_store("fractal:400x300:6", tmp_path / "l.zarr", tile=128, chunk=64)
    _, a = levels_of(tmp_path / "d.zarr")
    _, b = levels_of(tmp_path / "l.zarr")
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert np.array_equal(TerrainStore(tmp_path / "d.zarr").minmax(1),
                          TerrainStore(tmp_path / "l.zarr").minmax(1))


def test_tile_then_render_adaptive_from_the_command_line(tmp_path):
    def run(*args):
        return run_cli(*args)  # in this process: no start-up per run

    r = run("tile", "fractal:300x400:1", "--out", str(tmp_path / "s.zarr"), "--tile", "128",
            "--chunk", "64")
    assert r.returncode == 0, r.stderr
    r = run("render", "--terrain", str(tmp_path / "s.zarr"), "--mode", "adaptive",
            "--frames", "4", "--size", "64x64", "--sse", "2", "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["mode"] == "adaptive" and s["tiles_resident"] >= 1 and s["first_frame_s"] > 0
    assert s["tiles_bad"] == 0


def test_an_out_folder_that_is_not_a_store_is_never_replaced(tmp_path):
    """Regression: a non-store folder at --out was a traceback; --overwrite deleted it."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "precious.txt").write_text("keep me")
    with pytest.raises(InputError, match="not a terrain store"):
        build_store("fractal:64:1", tmp_path / "mine", tile=64, chunk=32)
    with pytest.raises(InputError, match="not a terrain store"):
        build_store("fractal:64:1", tmp_path / "mine", tile=64, chunk=32, overwrite=True)
    assert (tmp_path / "mine" / "precious.txt").read_text() == "keep me"


def test_a_window_of_nodata_only_does_not_poison_the_pyramid(tmp_path):
    """Regression: a tile all nodata stayed NaN and the mean carried it to the root."""
    h = np.random.default_rng(1).uniform(100, 200, (256, 256))
    h[:128, :128] = -9999.0                          # one whole 128² tile of nodata
    write_geotiff(tmp_path / "hole.tif", h)
    build_store(str(tmp_path / "hole.tif"), tmp_path / "h.zarr", tile=128, chunk=64)
    _, lv = levels_of(tmp_path / "h.zarr")
    assert all(np.isfinite(a).all() for a in lv)
