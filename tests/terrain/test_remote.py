"""Datasets read where they lie: a COG and a terrain store over HTTP range requests from a
real server on loopback (aiohttp's static route), through the block cache on disk; a
server that ignores ranges (Python's http.server) refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from conftest import run_cli
from lodsprite.errors import InputError
from lodsprite.terrain import remote
from lodsprite.terrain.store import TerrainStore, build_store
from terrain.test_imagery import checker, dem

HERE = Path(__file__).resolve().parent.parent


def start(cmd: list[str], port_from) -> tuple[subprocess.Popen, int]:
    """A server process and its port (read from its output within a deadline)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        port = port_from(line)
        if port:
            return proc, port
        if proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("the test server did not start")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A folder with a DEM (a tiled GeoTIFF with overviews), an orthophoto and a store
    built from them, served with ranges; yields (folder, base URL)."""
    import rasterio

    folder = tmp_path_factory.mktemp("served")
    d = dem(folder)
    o = checker(folder)
    cog = folder / "dem_cog.tif"
    with rasterio.open(d) as src:
        profile = src.profile | {"tiled": True, "blockxsize": 64, "blockysize": 64}
        with rasterio.open(cog, "w", **profile) as dst:
            dst.write(src.read())
            dst.build_overviews([2, 4])
    build_store(str(cog), folder / "s.zarr", tile=64, chunk=32, imagery=[str(o)])
    proc, port = start([sys.executable, str(HERE / "range_server.py"), str(folder)],
                       lambda line: int(line) if line.strip().isdigit() else 0)
    yield folder, f"http://127.0.0.1:{port}"
    proc.kill()
    proc.wait()


def stats(base: str, reset: bool = False) -> dict:
    with urllib.request.urlopen(f"{base}/{'_reset' if reset else '_stats'}", timeout=10) as r:
        return json.loads(r.read())


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "http-cache"
    monkeypatch.setenv("LODSPRITE_HTTP_CACHE", str(folder))
    return folder


def test_a_cog_tiled_over_http_equals_one_tiled_here_and_a_second_run_fetches_nothing(
        served, cache, tmp_path):
    folder, base = served
    here = TerrainStore(folder / "s.zarr")
    stats(base, reset=True)
    build_store(f"{base}/dem_cog.tif", tmp_path / "a.zarr", tile=64, chunk=32,
                imagery=[f"{base}/ortho.tif"])
    first = stats(base)
    a = TerrainStore(tmp_path / "a.zarr")
    for k in range(here.levels):
        r, c = here.shape(k)
        assert np.array_equal(a.read(k, 0, r, 0, c), here.read(k, 0, r, 0, c))
    r, c = here.group["imagery/0"].shape[:2]
    assert np.array_equal(a.read_imagery(0, 0, r, 0, c), here.read_imagery(0, 0, r, 0, c))
    total = sum(f.stat().st_size for f in (folder / "dem_cog.tif", folder / "ortho.tif"))
    assert 0 < first["bytes"] <= total
    stats(base, reset=True)
    build_store(f"{base}/dem_cog.tif", tmp_path / "b.zarr", tile=64, chunk=32,
                imagery=[f"{base}/ortho.tif"])
    assert stats(base) == {"bytes": 0, "requests": 0}  # all from the cache on disk


def test_a_store_over_http_reads_as_the_store_here(served, cache, tmp_path):
    folder, base = served
    here, there = TerrainStore(folder / "s.zarr"), TerrainStore(f"{base}/s.zarr")
    assert there.header == here.header and there.path.name == "s.zarr"
    for k in range(here.levels):
        r, c = here.shape(k)
        assert np.array_equal(there.read(k, 0, r, 0, c), here.read(k, 0, r, 0, c))
    assert np.array_equal(there.imagery_texture(256), here.imagery_texture(256))
    r = run_cli("info", f"{base}/s.zarr")
    assert r.returncode == 0 and "EPSG:32614" in r.stdout and "ortho.tif" in r.stdout
    r = run_cli("render", "--terrain", f"{base}/s.zarr", "--mode", "adaptive", "--frames",
                "3", "--size", "64x64", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["frames"] == 3


def test_a_server_that_ignores_ranges_is_refused_in_one_line(served, cache, tmp_path):
    folder, _ = served
    proc, port = start([sys.executable, "-u", "-m", "http.server", "0", "--bind",
                        "127.0.0.1", "--directory", str(folder)],
                       lambda line: int(line.split("port ")[1].split()[0])
                       if "port " in line else 0)
    try:
        url = f"http://127.0.0.1:{port}"
        with pytest.raises(InputError, match="does not answer range requests"):
            remote.open_raster(f"{url}/dem_cog.tif")
        for args in (("info", f"{url}/dem_cog.tif"),
                     ("tile", f"{url}/dem_cog.tif", "--out", str(tmp_path / "t.zarr")),
                     ("render", "--terrain", f"{url}/s.zarr", "--frames", "2",
                      "--out", str(tmp_path / "run"))):
            r = run_cli(*args)
            assert r.returncode == 2 and "does not answer range requests" in r.stderr
            assert len(r.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "t.zarr").exists() and not (tmp_path / "run").exists()
    finally:
        proc.kill()
        proc.wait()
    r = run_cli("info", f"http://127.0.0.1:{port}/dem_cog.tif")  # nobody answers now
    assert r.returncode == 2 and "no answer" in r.stderr


def test_the_cache_is_trimmed_to_its_cap_oldest_first(served, cache):
    _, base = served
    fs = remote.filesystem()
    for name in ("ortho.tif", "dem_cog.tif"):
        remote.read_range(fs, f"{base}/{name}", 0, 200_000)
        time.sleep(0.01)
    held = remote.trim(fs, 1 << 40)
    assert held >= 2 * 200_000 * 0.9
    left = remote.trim(fs, held - 1)  # the ortho, cached first, goes
    assert left < held
    stats(base, reset=True)
    remote.read_range(fs, f"{base}/dem_cog.tif", 0, 200_000)
    assert stats(base)["bytes"] == 0  # the newer file stayed


def test_a_remote_data_folder_serves_stores_and_cogs_under_it_only(served, cache):
    from lodsprite.distributed.datasets import Datasets

    _, base = served
    d = Datasets(base)
    assert d.scene("s.zarr").spec == f"{base}/s.zarr"
    assert d.terrain("dem_cog.tif").shape == (129, 129)
    assert d.local_name(f"{base}/s.zarr") == "s.zarr"
    for bad, why in (("../s.zarr", "relative path"), ("/etc/passwd", "relative path"),
                     ("s.zarr?x=1", "relative path"), ("ortho.png", "serves terrain"),
                     ("none.zarr", "404")):
        with pytest.raises(InputError, match=why):
            d.scene(bad)
    with pytest.raises(InputError, match="serves no files"):
        d.texture("ortho.tif")


def test_the_widget_takes_a_store_at_a_url(served, cache):
    pytest.importorskip("anywidget", reason="the notebook extra")
    from lodsprite.notebook.source import resolve_source

    _, base = served
    src = resolve_source(f"{base}/s.zarr", size=(64, 48))
    assert src.load.terrain == "s.zarr" and src.data_dir == base
    with pytest.raises(InputError, match="404"):
        resolve_source(f"{base}/none.zarr")
