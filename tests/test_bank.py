"""The bank path: a low S-turn at a fixed height that rolls into its turns."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import PathError
from lodsprite.paths import bank, get_path
from lodsprite.paths.bank import PITCH_DEG, ROLL_DEG
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import HeightField


def test_it_clears_the_ground_turns_and_rolls_into_the_turns():
    hf = fractal(256, 3)
    path = get_path("bank:200:3000", hf, 81)
    vps = path.viewpoints
    eyes = np.array([vp.o for vp in vps])
    assert np.all(eyes[:, 2] - hf.height_at(eyes[:, 0], eyes[:, 1]) >= 200 - 1e-6)
    look = -np.array([vp.z for vp in vps])
    heading = np.degrees(np.arctan2(look[:, 0], look[:, 1]))  # from north, clockwise
    assert heading.max() > 50 and heading.min() < -50          # it turns both ways
    # pitched down by PITCH_DEG all along
    assert np.allclose(np.degrees(np.arcsin(-look[:, 2])), PITCH_DEG, atol=1e-9)
    # roll about the view axis (+: right wing down): the right axis drops by sin(roll)
    # times the level up axis's height cos(pitch)
    drop = -np.array([vp.x for vp in vps])[:, 2] / np.cos(np.radians(PITCH_DEG))
    roll = np.degrees(np.arcsin(drop))
    assert roll.max() == pytest.approx(ROLL_DEG, abs=0.5) and roll.min() < -ROLL_DEG + 0.5
    rate = np.gradient(np.unwrap(np.radians(heading)))
    turning = np.abs(rate) > 0.3 * np.abs(rate).max()
    assert np.all(np.sign(roll[turning]) == np.sign(rate[turning]))  # into the turn
    step = np.linalg.norm(np.diff(eyes[:, :2], axis=0), axis=1)
    assert step.sum() == pytest.approx(3000, rel=0.01)


def test_it_fits_a_small_terrain():
    small = HeightField(np.zeros((65, 65), np.float32), 30.0, 30.0)   # 1.9 km wide
    eyes = np.array([vp.o for vp in bank(small, 40).viewpoints])
    assert np.abs(eyes[:, :2]).max() <= 0.4 * 64 * 30 + 1e-6
    assert np.allclose(eyes[:, 2], 300.0)


@pytest.mark.parametrize("spec", ["bank:x", "bank:-5", "bank:100:0", "bank:1:2:3", "bank:nan"])
def test_a_malformed_bank_is_a_path_error(spec):
    with pytest.raises(PathError, match="bank"):
        get_path(spec, fractal(64, 1))
