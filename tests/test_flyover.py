"""The flyover path: a low flight of fixed height and length in metres."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import PathError
from lodsprite.paths import flyover, get_path
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import HeightField


def test_it_clears_the_ground_by_its_height_and_looks_down_the_track():
    hf = fractal(256, 3)
    path = get_path("flyover:300:5000", hf, 50)
    eyes = np.array([vp.o for vp in path.viewpoints])
    ground = hf.height_at(eyes[:, 0], eyes[:, 1])
    assert np.all(eyes[:, 2] - ground >= 300 - 1e-6)
    # the highest ground within one height ahead and behind is cleared too
    ys = np.linspace(eyes[0, 1], eyes[-1, 1], 2000)
    g = hf.height_at(np.zeros_like(ys), ys)
    for e in eyes:
        near = np.abs(ys - e[1]) <= 300
        assert e[2] >= g[near].max() + 300 - 0.5  # (ground sampled between the path's)
    assert np.allclose(eyes[:, 0], 0) and eyes[-1, 1] - eyes[0, 1] == pytest.approx(5000)
    look = -np.array([vp.z for vp in path.viewpoints])
    assert np.allclose(look, [0, np.cos(np.radians(20)), -np.sin(np.radians(20))])


def test_it_is_the_same_flight_in_metres_whatever_the_terrain_size():
    small = HeightField(np.zeros((65, 65), np.float32), 30.0, 30.0)   # 1.9 km deep
    large = HeightField(np.zeros((1025, 1025), np.float32), 30.0, 30.0)
    a, b = (np.array([vp.o for vp in flyover(hf, 20).viewpoints]) for hf in (small, large))
    assert b[-1, 1] - b[0, 1] == pytest.approx(10000)          # the default track
    assert a[-1, 1] - a[0, 1] == pytest.approx(0.9 * 64 * 30)  # clipped to the terrain
    assert np.allclose(a[:, 2], 1000) and np.allclose(b[:, 2], 1000)


@pytest.mark.parametrize("spec", ["flyover:x", "flyover:-5", "flyover:100:0",
                                  "flyover:1:2:3", "flyover:nan"])
def test_a_malformed_flyover_is_a_path_error(spec):
    with pytest.raises(PathError):
        get_path(spec, fractal(64, 1), 10)
