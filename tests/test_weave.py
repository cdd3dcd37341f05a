"""The ``weave`` path (low among a scene's objects, :mod:`lodsprite.paths.weave`): it
clears the ground by its height, crosses the square north, weaves east and west, looks
where it goes; malformed specs are path errors."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import PathError
from lodsprite.paths import get_path
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import HeightField


def test_it_weaves_low_across_the_square_clearing_the_ground():
    hf = fractal(256, 3)
    path = get_path("weave:6:300:2", hf, 80)  # no frame at the crossing
    eyes = np.array([vp.o for vp in path.viewpoints])
    ground = hf.height_at(eyes[:, 0], eyes[:, 1])
    assert np.all(eyes[:, 2] - ground >= 6 - 1e-6)
    assert eyes[0, 1] == pytest.approx(-300) and eyes[-1, 1] == pytest.approx(300)
    assert np.abs(eyes[:, 0]).max() == pytest.approx(0.6 * 300, rel=1e-3)
    crossings = np.count_nonzero(np.diff(np.sign(np.round(eyes[1:-1, 0], 6))) != 0)
    assert crossings == 1  # two turns: east then west, crossing the centre line once
    # the camera looks along its direction of travel (pitched down 8°)
    look = -np.array([vp.z for vp in path.viewpoints])
    step = np.diff(eyes[:, :2], axis=0)
    step /= np.linalg.norm(step, axis=1, keepdims=True)
    flat = look[:-1, :2] / np.linalg.norm(look[:-1, :2], axis=1, keepdims=True)
    assert np.all(np.sum(flat * step, axis=1) > 0.95)
    assert np.allclose(look[:, 2], -np.sin(np.radians(8)))


def test_it_is_clipped_to_the_terrain_and_has_defaults():
    small = HeightField(np.zeros((17, 17), np.float32), 30.0, 30.0)  # 480 m square
    eyes = np.array([vp.o for vp in get_path("weave", small, 20).viewpoints])
    assert eyes[-1, 1] == pytest.approx(0.45 * 480) and np.allclose(eyes[:, 2], 8.0)
    large = HeightField(np.zeros((65, 65), np.float32), 30.0, 30.0)  # 1920 m square
    eyes = np.array([vp.o for vp in get_path("weave", large, 20).viewpoints])
    assert eyes[-1, 1] == pytest.approx(400.0)  # the default half side


@pytest.mark.parametrize("spec", ["weave:x", "weave:-5", "weave:5:0", "weave:5:100:0",
                                  "weave:5:100:1.5", "weave:1:2:3:4"])
def test_a_malformed_weave_is_a_path_error(spec):
    with pytest.raises(PathError):
        get_path(spec, fractal(64, 1), 10)
