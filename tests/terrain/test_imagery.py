"""Orthophotos in a terrain store: reprojection onto the DEM's grid, the colour pyramid,
resuming, older stores, and the bad inputs refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import run_cli
from lodsprite.errors import InputError
from lodsprite.terrain.imagery import downsample_rgba
from lodsprite.terrain.store import TerrainStore, build_store

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import from_origin  # noqa: E402
from rasterio.warp import transform, transform_bounds  # noqa: E402

UTM = "EPSG:32614"
W0, N0, CELL, SIDE = 600000.0, 3700000.0, 30.0, 129  # the DEM: 129² samples, 30 m, UTM 14N
SQUARE = 0.002  # the orthophoto's checker squares, degrees (about 190 m by 220 m)
PX = 0.0001     # its pixels, degrees (about 9-11 m: a refinement of 2)


def dem(folder: Path, relief: float = 20.0, crs: str = UTM) -> Path:
    yy, xx = np.mgrid[0:SIDE, 0:SIDE]
    h = (relief * np.sin(xx / 9.0) * np.cos(yy / 13.0) + 300.0).astype("float32")
    p = folder / "dem.tif"
    with rasterio.open(p, "w", driver="GTiff", width=SIDE, height=SIDE, count=1,
                       dtype="float32", crs=crs, transform=from_origin(W0, N0, CELL, CELL)
                       ) as f:
        f.write(h, 1)
    return p


def checker(folder: Path, name: str = "ortho.tif", margin: float = 0.01, count: int = 3,
            dtype: str = "uint8", crs: str = "EPSG:4326", bounds=None, **tags) -> Path:
    """A red-green checker in degrees over the DEM (and ``margin`` degrees around it):
    square ``(i, j)`` counted from the north-west corner ``(lon0, lat0)`` is red when
    ``i + j`` is even."""
    w, s, e, n = bounds or transform_bounds(UTM, "EPSG:4326", W0, N0 - SIDE * CELL,
                                            W0 + SIDE * CELL, N0)
    lon0, lat0 = w - margin, n + margin
    cols, rows = int((e + margin - lon0) / PX), int((lat0 - (s - margin)) / PX)
    jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
    red = ((ii * PX // SQUARE + jj * PX // SQUARE) % 2 == 0)
    scale = 255 if dtype == "uint8" else 4000
    a = np.zeros((count, rows, cols), dtype)
    a[0], a[1] = red * scale, (~red) * scale
    if count == 4:
        a[3] = 255
        a[3, :, : cols // 2] = 0  # the west half transparent
    p = folder / name
    with rasterio.open(p, "w", driver="GTiff", width=cols, height=rows, count=count,
                       dtype=dtype, crs=crs, transform=from_origin(lon0, lat0, PX, PX),
                       photometric="RGB" if count >= 3 else "MINISBLACK",
                       **({"alpha": "YES"} if count == 4 else {})) as f:
        f.write(a)
        if tags:
            f.update_tags(**tags)
    return p


def red_at(lon, lat, lon0, lat0) -> np.ndarray:
    i = np.floor((lat0 - lat) / SQUARE)
    j = np.floor((lon - lon0) / SQUARE)
    return (i + j) % 2 == 0


@pytest.fixture(scope="module")
def draped(tmp_path_factory):
    folder = tmp_path_factory.mktemp("imagery")
    d = dem(folder)
    o = checker(folder, TIFFTAG_COPYRIGHT="(c) the checker's makers, CC-BY 4.0")
    store = folder / "s.zarr"
    build_store(str(d), store, tile=64, chunk=32, imagery=[str(o)])
    return folder, store, o


def test_a_checker_in_degrees_lands_on_the_utm_dem_where_its_corners_say(draped, gl):
    """Nadir full-resolution frame of the store: at every sampled pixel the colour is the
    checker's square at the ground point the pixel's ray meets (the terrain has 40 m of
    relief), away from the squares' edges (2 ground pixels)."""
    from lodsprite.api import Renderer
    from lodsprite.camera import look_at
    from lodsprite.scene import load_scene

    folder, store, ortho = draped
    scene = load_scene(str(store), "terrain", None, 1.0)
    size, h_eye = 192, 2600.0
    vp = look_at((0.0, 0.0, h_eye), (0.0, 0.0, 0.0), up=(0, 1, 0))
    with Renderer(scene, (size, size), 60.0, ctx=gl.mgl) as r:
        r.render(vp)
        img = r.read_color().astype(int)
        proj = r.projection(vp)
    inv = np.linalg.inv(proj.matrix() @ vp.view_matrix())
    py, px = np.mgrid[4:size:9, 4:size:9]
    ndc = np.stack([(px.ravel() + 0.5) / size * 2 - 1, 1 - (py.ravel() + 0.5) / size * 2,
                    np.ones(px.size), np.ones(px.size)], 1)
    far = ndc @ inv.T
    far = far[:, :3] / far[:, 3:]
    eye = np.asarray(vp.o)
    d = far - eye
    lo, hi = np.zeros(len(d)), np.ones(len(d))
    for _ in range(60):  # where the ray meets the drawn surface, by bisection
        mid = (lo + hi) / 2
        p = eye + d * mid[:, None]
        above = p[:, 2] > scene.hf.height_at(p[:, 0], p[:, 1])
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    ground = eye + d * lo[:, None]
    e = W0 + SIDE * CELL / 2 + ground[:, 0]
    n = N0 - SIDE * CELL / 2 + ground[:, 1]
    lon, lat = (np.asarray(v) for v in transform(UTM, "EPSG:4326", e, n))
    with rasterio.open(ortho) as o:
        lon0, lat0 = o.transform.c, o.transform.f
    fi, fj = (lat0 - lat) / SQUARE, (lon - lon0) / SQUARE
    edge_m = np.minimum(np.abs(fi - np.rint(fi)) * SQUARE * 111e3,
                        np.abs(fj - np.rint(fj)) * SQUARE * 93e3)
    pixel_m = 2 * h_eye * np.tan(np.radians(30)) / size
    inside = (np.abs(ground[:, 0]) < 0.48 * SIDE * CELL) & (np.abs(ground[:, 1]) < 0.48
                                                             * SIDE * CELL)
    clear = inside & (edge_m > 2 * pixel_m)
    colours = img[py.ravel(), px.ravel()]
    red = (colours[:, 0] > 180) & (colours[:, 1] < 70)
    green = (colours[:, 1] > 180) & (colours[:, 0] < 70)
    want = red_at(lon, lat, lon0, lat0)
    assert clear.sum() > 200
    assert np.all(np.where(want, red, green)[clear])


def test_the_store_keeps_the_imagery_its_attribution_and_a_linear_light_pyramid(draped):
    _, store, _ = draped
    st = TerrainStore(store)
    im = st.imagery
    assert im.refine == 2 and (im.rows, im.cols) == (128 * 4, 128 * 4)
    assert "CC-BY" in im.attribution
    a0 = st.read_imagery(0, 0, 64, 0, 64)
    a1 = st.read_imagery(1, 0, 32, 0, 32)
    assert np.array_equal(a1, downsample_rgba(a0))


def test_the_attribution_reaches_the_scene_the_page_and_the_window(draped):
    from lodsprite.distributed.messages import SceneMessage
    from lodsprite.scene import load_scene
    from lodsprite.scene.model import scene_attribution
    from lodsprite.viewer.hud import HudState

    _, store, _ = draped
    credit = scene_attribution(load_scene(str(store), "terrain", None, 1.0, light=True))
    assert "CC-BY" in credit
    assert f"imagery {credit}" in HudState(attribution=credit).lines()
    assert "attribution" in SceneMessage.__struct_fields__


def test_coarser_levels_are_filtered_in_linear_light_and_weighted_by_alpha():
    bw = np.zeros((2, 2, 4), np.uint8)
    bw[0, :, :3], bw[..., 3] = 255, 255
    grey = downsample_rgba(bw)[0, 0]
    assert 186 <= grey[0] <= 188 and grey[3] == 255  # the sRGB of 50 % light, not 128
    half = np.zeros((2, 2, 4), np.uint8)
    half[..., 0], half[0, 0, 3], half[0, 1, 3] = 200, 255, 255  # two texels with no data
    out = downsample_rgba(half)[0, 0]
    assert out[0] == 200 and 127 <= out[3] <= 128  # not darkened by the empty texels


def test_an_interrupted_imagery_build_resumes_to_the_same_store(tmp_path, draped):
    folder, whole, ortho = draped
    d = folder / "dem.tif"
    part = tmp_path / "part.zarr"
    s = build_store(str(d), part, tile=64, chunk=32, imagery=[str(ortho)], stop_after=9)
    assert s.get("interrupted")
    assert TerrainStore(part).imagery is None  # the heights are done: drawn without imagery
    s = build_store(str(d), part, tile=64, chunk=32, imagery=[str(ortho)], stop_after=40)
    assert s.get("interrupted")
    build_store(str(d), part, tile=64, chunk=32, imagery=[str(ortho)])
    a, b = TerrainStore(part), TerrainStore(whole)
    for j in range(b.imagery.levels):
        r, c = a.group[f"imagery/{j}"].shape[:2]
        assert np.array_equal(a.read_imagery(j, 0, r, 0, c), b.read_imagery(j, 0, r, 0, c))


def test_imagery_is_added_to_a_store_without_and_a_version_1_store_still_opens(tmp_path,
                                                                               draped):
    folder, _, ortho = draped
    s = tmp_path / "s.zarr"
    build_store(str(folder / "dem.tif"), s, tile=64, chunk=32)
    meta = json.loads((s / "zarr.json").read_text())
    meta["attributes"]["lodsprite"]["version"] = 1
    del meta["attributes"]["lodsprite"]["imagery"]
    (s / "zarr.json").write_text(json.dumps(meta))
    assert TerrainStore(s).imagery is None
    build_store(str(folder / "dem.tif"), s, tile=64, chunk=32, imagery=[str(ortho)])
    assert TerrainStore(s).imagery.refine == 2


def test_16_bit_imagery_is_stretched_and_an_alpha_band_honoured(tmp_path, draped):
    folder, _, _ = draped
    o16 = checker(tmp_path, "o16.tif", dtype="uint16")
    o4 = checker(tmp_path, "o4.tif", count=4)
    s = tmp_path / "s.zarr"
    build_store(str(folder / "dem.tif"), s, tile=64, chunk=32, imagery=[str(o16)],
                imagery_refine=1)  # 256² texels: enough for the bands and the mask
    a = TerrainStore(s).read_imagery(0, 0, 256, 0, 256)
    assert a[..., :2].max() == 255 and set(np.unique(a[..., 3])) == {255}
    s4 = tmp_path / "s4.zarr"
    build_store(str(folder / "dem.tif"), s4, tile=64, chunk=32, imagery=[str(o4)],
                imagery_refine=1)
    alpha = TerrainStore(s4).read_imagery(0, 0, 256, 0, 256)[..., 3]
    assert alpha[:, :50].max() == 0 and alpha[:, -50:].min() == 255


def test_sources_are_painted_in_order(tmp_path, draped):
    folder, _, _ = draped
    grey = tmp_path / "grey.tif"
    b = transform_bounds(UTM, "EPSG:4326", W0, N0 - SIDE * CELL, W0 + SIDE * CELL, N0)
    with rasterio.open(grey, "w", driver="GTiff", width=40, height=40, count=3,
                       dtype="uint8", crs="EPSG:4326", nodata=0,
                       transform=from_origin(b[0], b[3], (b[2] - b[0]) / 80,
                                             (b[3] - b[1]) / 80)) as f:
        f.write(np.full((3, 40, 40), 90, np.uint8))  # the north-west quarter only
    s = tmp_path / "s.zarr"
    build_store(str(folder / "dem.tif"), s, tile=64, chunk=32,
                imagery=[str(folder / "ortho.tif"), str(grey)])
    a = TerrainStore(s).read_imagery(0, 0, 512, 0, 512)
    assert np.all(a[20:230, 20:230, :3] == 90)  # the later source on top
    assert a[300:, 300:, :2].max() == 255  # the checker where the grey has no data


@pytest.mark.parametrize("case", ["apart", "mars", "missing", "not-image"])
def test_imagery_that_cannot_be_placed_is_refused_in_one_line(tmp_path, draped, case):
    folder, _, _ = draped
    if case == "apart":
        o = checker(tmp_path, bounds=(10.0, 10.0, 10.05, 10.05), margin=0.0)
        want = "does not overlap"
    elif case == "mars":
        o = checker(tmp_path, crs="IAU_2015:49900")
        want = "cannot be transformed"
    elif case == "missing":
        o, want = tmp_path / "none.tif", "no such imagery"
    else:
        o = tmp_path / "bad.tif"
        o.write_bytes(b"not a tiff at all")
        want = "cannot read imagery"
    out = tmp_path / "s.zarr"
    with pytest.raises(InputError, match=want):
        build_store(str(folder / "dem.tif"), out, imagery=[str(o)])
    assert not out.exists()
    r = run_cli("tile", str(folder / "dem.tif"), "--out", str(out), "--imagery", str(o))
    assert r.returncode == 2 and want in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not out.exists()


def test_a_truncated_imagery_chunk_is_one_line_from_render(tmp_path, draped):
    import shutil

    _, store, _ = draped
    s = tmp_path / "s.zarr"
    shutil.copytree(store, s)
    shard = max((s / "imagery" / "0").rglob("c/*/*/*"), key=lambda p: p.stat().st_size)
    shard.write_bytes(shard.read_bytes()[: shard.stat().st_size // 2])
    with pytest.raises(InputError, match="damaged"):
        TerrainStore(s).read_imagery(0, 0, 512, 0, 512)
    r = run_cli("render", "--terrain", str(s), "--mode", "full", "--frames", "2",
                "--size", "64x64", "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and "damaged" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "run").exists()


def test_the_reference_drawn_by_windows_reads_the_imagery_as_the_whole_one_shows(draped, gl):
    """The band-limited reference of a store drawn in windows of at most 48 samples a side
    (as a store beyond 4097 a side is), each coloured by the store's imagery read at level
    0's detail, against the reference of the store whole with its whole imagery: the same
    frame (RMSE < 2 grey levels), and not the heights shading (RMSE > 40 against it)."""
    from lodsprite.camera import look_at
    from lodsprite.gl.reference import LevelZeroReference
    from lodsprite.harness import imagery_windows
    from lodsprite.scene import load_scene
    from lodsprite.terrain.textures import drape

    _, store, _ = draped
    st = TerrainStore(store)
    hf = load_scene(str(store), "terrain", None, 1.0).hf
    vp = look_at((-900.0, -2600.0, 2300.0), (200.0, 300.0, 300.0))
    whole_tex = drape(st.imagery_texture(4096), hf)
    refs = [LevelZeroReference(gl, st, (96, 72), 50.0, "texture", whole_tex, samples=2),
            LevelZeroReference(gl, st, (96, 72), 50.0, "texture", None, max_side=48,
                               samples=2, imagery=imagery_windows(st, "terrain", 4096)),
            LevelZeroReference(gl, st, (96, 72), 50.0, "heights", samples=2)]
    try:
        whole, windows, heights = (r.image(vp).astype(float) for r in refs)
        assert "by window" not in refs[0].identity() and "by window" in refs[1].identity()
    finally:
        for r in refs:
            r.release()
    assert np.sqrt(np.mean((whole - windows) ** 2)) < 2.0
    assert np.sqrt(np.mean((whole - heights) ** 2)) > 40.0


@pytest.mark.parametrize("what", ["dem", "imagery"])
def test_a_truncated_source_stops_the_build_in_one_line_and_it_stays_resumable(tmp_path,
                                                                               draped, what):
    """A COG cut in half (its header whole, its last tiles gone): tile stops at the first
    read it cannot make, one line and exit 2: a DEM's before anything is written, an
    orthophoto's with the tiles written kept: the heights finished, the store opens
    without its imagery, which info calls unfinished (tile it again to resume)."""
    folder, _, ortho = draped
    dem_path = folder / "dem.tif"
    with rasterio.open(dem_path if what == "dem" else ortho) as src:
        profile = {k: v for k, v in src.profile.items()
                   if k not in ("blockxsize", "blockysize", "tiled", "interleave")}
        profile |= {"driver": "COG", "blocksize": 128, "compress": "deflate"}
        cut = tmp_path / f"cut_{what}.tif"
        with rasterio.open(cut, "w", **profile) as dst:
            dst.write(src.read())
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    args = (cut, ortho) if what == "dem" else (dem_path, cut)
    out = tmp_path / "s.zarr"
    r = run_cli("tile", str(args[0]), "--out", str(out), "--tile", "64", "--chunk", "32",
                "--imagery", str(args[1]))
    assert r.returncode == 2 and "cannot read" in r.stderr and "Traceback" not in r.stderr
    errors = [line for line in r.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and errors[0].startswith("lodsprite: error: ")
    if what == "dem":  # its decimated read, before anything is written, fails
        assert not out.exists()
        return
    st = TerrainStore(out)  # the heights finished: the terrain opens, without its imagery
    assert st.imagery is None and not st.header.complete
    assert "unfinished" in run_cli("info", str(out)).stdout


@pytest.mark.parametrize("mode", ["full", "adaptive"])
def test_the_clipmap_streams_imagery_finer_than_the_texture_around_the_eye(draped, gl,
                                                                         monkeypatch, mode):
    """With the scene's texture held to 256 texels a side (half the imagery's),
    the full-resolution frame of a close nadir view, once the clip levels around the eye
    have arrived (streamed by the reader process, never waited for inside a frame), is
    the windowed reference's level-0 imagery (RMSE under 3 grey levels; full resolution
    and the adaptive renderer alike), where the one texture alone blurs every checker edge
    (RMSE more than 4 times as large; 0.9 against 16.7 measured)."""
    import time

    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.camera import look_at
    from lodsprite.gl.reference import LevelZeroReference
    from lodsprite.harness import imagery_windows
    from lodsprite.scene import load_scene, model

    _, store, _ = draped
    monkeypatch.setattr(model, "IMAGERY_SIDE", 256)
    scene = load_scene(str(store), "terrain", None, 1.0)
    assert max(scene.texture.shape) <= 256
    vp = look_at((150.0, -100.0, 720.0), (150.0, -100.0, 0.0), up=(0, 1, 0))
    size, fov = (128, 128), 50.0
    with Renderer(scene, size, fov, ctx=gl.mgl) as r:
        r.render(vp)
        blurred = r.read_color().astype(float)  # no technique yet: the one texture
        tech = techniques.create(mode, r)
        clip = r.terrain_gl.geometry.clip
        assert clip.core is not None and clip.core.levels == [0]
        end = time.monotonic() + 30
        while True:
            tech.frame(vp)
            if clip.core.idle() and clip.uploaded and (
                    mode == "full" or tech.terrain.loader.idle()):
                tech.frame(vp)
                break
            assert time.monotonic() < end, "the clip levels did not arrive"
            time.sleep(0.01)
        sharp = r.read_color().astype(float)
        tech.release()
    st = TerrainStore(store)
    ref = LevelZeroReference(gl, st, size, fov, "texture", None, max_side=64, samples=2,
                             imagery=imagery_windows(st, "terrain", 4096))
    try:
        want = ref.image(vp).astype(float)
    finally:
        ref.release()
    err_sharp = np.sqrt(np.mean((sharp - want) ** 2))
    err_blurred = np.sqrt(np.mean((blurred - want) ** 2))
    assert err_sharp < 3.0 and err_blurred > 4 * err_sharp, (err_sharp, err_blurred)


def test_the_served_keyframes_stream_the_clipmap_too(draped, gl, monkeypatch):
    """A page's renderer (the adaptive keyframe service) over the same store, texture held
    to half the imagery's resolution: once its clip levels arrive its keyframe of the close
    nadir view is the reference's level-0 imagery (RMSE under 3)."""
    import time

    from lodsprite.camera import look_at
    from lodsprite.distributed.protocol import LoadArgs
    from lodsprite.distributed.render import AdaptiveKeyframeService
    from lodsprite.gl.reference import LevelZeroReference
    from lodsprite.harness import imagery_windows
    from lodsprite.scene import model

    _, store, _ = draped
    monkeypatch.setattr(model, "IMAGERY_SIDE", 256)
    vp = look_at((150.0, -100.0, 720.0), (150.0, -100.0, 0.0), up=(0, 1, 0))
    size = (128, 128)
    service = AdaptiveKeyframeService(LoadArgs(terrain=str(store), size=size, lod=16,
                                               grid=64, fov_y_deg=50.0), gl)
    st = TerrainStore(store)
    ref = LevelZeroReference(gl, st, size, 50.0, "texture", None, max_side=64, samples=2,
                             imagery=imagery_windows(st, "terrain", 4096))
    try:
        clip = service.keys.adaptive.clip
        assert clip is not None and clip.core is not None and clip.core.levels == [0]
        end, seq = time.monotonic() + 30, 0
        while True:
            seq += 1
            kf = service.render(vp, seq, 0.0)
            if clip.core.idle() and clip.uploaded:
                kf = service.render(vp, seq + 1, 0.0)
                break
            assert time.monotonic() < end, "the clip levels did not arrive"
            time.sleep(0.01)
        want = ref.image(vp, kf.projection).astype(float)
        err = np.sqrt(np.mean((kf.color.astype(float) - want) ** 2))
        assert err < 3.0, err
    finally:
        service.release()
        ref.release()


def test_a_build_begun_with_a_refinement_resumes_without_repeating_it(tmp_path, draped):
    folder, _, ortho = draped
    out = tmp_path / "s.zarr"
    args = (str(folder / "dem.tif"), out)
    s = build_store(*args, tile=64, chunk=32, imagery=[str(ortho)], imagery_refine=1,
                    stop_after=12)
    assert s.get("interrupted")
    build_store(*args, tile=64, chunk=32, imagery=[str(ortho)])  # as the hint says
    assert TerrainStore(out).imagery.refine == 1
    assert build_store(*args, tile=64, chunk=32, imagery=[str(ortho)])["already"]
    with pytest.raises(InputError, match="refined 1, not 2"):
        build_store(*args, tile=64, chunk=32, imagery=[str(ortho)], imagery_refine=2)
