"""The patrol path: back and forth over one stretch, several passes, one heading."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import PathError
from lodsprite.paths import get_path, patrol
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import HeightField


def test_it_goes_back_and_forth_over_one_stretch_clear_of_the_ground():
    hf = fractal(256, 3)
    path = get_path("patrol:300:3000:5", hf, 200)
    eyes = np.array([vp.o for vp in path.viewpoints])
    assert len(eyes) == 200 and np.allclose(eyes[:, 0], 0)
    assert eyes[:, 1].min() == pytest.approx(-1500) and eyes[:, 1].max() == pytest.approx(1500)
    steps = np.sign(np.diff(eyes[:, 1]))
    turns = np.count_nonzero(np.diff(steps[steps != 0]))
    assert turns == 4                               # five passes
    ground = hf.height_at(eyes[:, 0], eyes[:, 1])
    assert np.all(eyes[:, 2] - ground >= 300 - 1e-6)
    # one heading: every pass sees the views of the others
    look = -np.array([vp.z for vp in path.viewpoints])
    assert np.allclose(look, look[0])


def test_it_works_on_any_terrain_size_and_has_defaults():
    small = HeightField(np.zeros((65, 65), np.float32), 30.0, 30.0)   # 1.9 km deep
    large = HeightField(np.zeros((2049, 2049), np.float32), 30.0, 30.0)
    a = np.array([vp.o for vp in patrol(small, 30).viewpoints])
    b = np.array([vp.o for vp in get_path("patrol", large).viewpoints])
    assert len(b) == 460 and b[:, 1].max() - b[:, 1].min() == pytest.approx(4000, rel=1e-3)
    assert a[:, 1].max() - a[:, 1].min() <= 0.9 * 64 * 30 + 1e-6
    assert np.allclose(b[:, 2], 500)


@pytest.mark.parametrize("spec", ["patrol:x", "patrol:-5", "patrol:100:0", "patrol:1:2:0",
                                  "patrol:1:2:2.5", "patrol:1:2:3:4", "patrol:nan"])
def test_a_malformed_patrol_is_a_path_error(spec):
    with pytest.raises(PathError):
        get_path(spec, fractal(64, 1), 10)
