"""The scene message carries where the terrain lies in its dataset's CRS (for the page's
cursor) and its vertical exaggeration; a terrain without a CRS carries none, and a
hostile georeference is refused when decoded."""

import numpy as np
import pytest

from lodsprite.distributed.protocol import LoadArgs, ProtocolError
from lodsprite.distributed.web.scene import build_scene_field, decode_scene


def test_a_utm_dem_sends_its_crs_bounds_and_exaggeration(tmp_path):
    import rasterio
    from rasterio.transform import from_origin

    tif = tmp_path / "dem.tif"
    with rasterio.open(tif, "w", driver="GTiff", height=65, width=65, count=1,
                       dtype="float32", crs="EPSG:32614",
                       transform=from_origin(500000.0, 4100000.0, 30.0, 30.0)) as ds:
        ds.write(np.zeros((65, 65), np.float32), 1)
    h = decode_scene(build_scene_field(LoadArgs(terrain=str(tif), grid=64, lod=8,
                                                size=(64, 64), exaggeration=2.5))[0]).header
    assert h.exaggeration == 2.5
    assert h.georef.crs == "EPSG:32614"
    assert h.georef.bounds == (500000.0, 4098050.0, 501950.0, 4100000.0)
    assert h.georef.metres_per_unit == (1.0, 1.0)


def test_a_terrain_without_a_crs_sends_none_and_a_hostile_one_is_refused():
    import msgspec

    from lodsprite.distributed.protocol import encode

    parts, _ = build_scene_field(LoadArgs(terrain="fractal:64:4", grid=64, lod=8,
                                          size=(64, 64)))
    assert decode_scene(parts).header.georef is None
    header = msgspec.msgpack.decode(parts[0])
    for bad in ({"crs": "x", "bounds": [0, 0, 1, float("nan")], "metres_per_unit": [1, 1]},
                {"crs": "x", "bounds": [0, 0, 1, 1], "metres_per_unit": [0, 1]},
                {"crs": "x" * 300, "bounds": [0, 0, 1, 1], "metres_per_unit": [1, 1]},
                {"crs": "x", "bounds": [1, 0, 0, 1], "metres_per_unit": [1, 1]}):
        with pytest.raises(ProtocolError):
            decode_scene(encode({**header, "georef": bad}, *parts[1:]))
