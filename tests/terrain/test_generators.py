"""Tests of the procedural terrain generator (lodsprite.terrain.generators)."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import TerrainError
from lodsprite.terrain import fractal
from lodsprite.terrain.generators import DEFAULT_SPACING_M, RELIEF_M


@pytest.fixture(scope="module")
def terrain256():
    return fractal(256, seed=7)


def test_shape_dtype_and_default_spacing(terrain256):
    hf = terrain256
    assert hf.heights.shape == (257, 257)
    assert hf.heights.dtype == np.float32
    assert hf.dx == hf.dy == DEFAULT_SPACING_M
    assert hf.extent == pytest.approx(256 * 30.0)
    assert hf.name == "fractal:256:7"
    assert hf.meta["seed"] == 7


def test_same_seed_identical_different_seed_differs(terrain256):
    again = fractal(256, seed=7)
    assert np.array_equal(again.heights, terrain256.heights)
    other = fractal(256, seed=8)
    assert not np.allclose(other.heights, terrain256.heights)


def test_value_range_is_plausible_relief(terrain256):
    h = terrain256.heights
    assert np.all(np.isfinite(h))
    assert h.min() == 0.0
    assert 0.7 * RELIEF_M < h.max() <= RELIEF_M * 1.001


def test_has_plains_and_mountains():
    hf = fractal(512, seed=1)
    h = hf.heights
    gy, gx = np.gradient(h, hf.dy, hf.dx)
    slope_deg = np.degrees(np.arctan(np.hypot(gx, gy)))
    low_and_flat = (h < np.percentile(h, 30)) & (slope_deg < 5)
    assert low_and_flat.mean() > 0.1                     # lowland plains exist
    assert (h > 0.6 * h.max()).mean() > 0.005            # and a high range


def test_extent_sets_spacing():
    hf = fractal(32, seed=0, extent_m=6400.0)
    assert hf.dx == hf.dy == pytest.approx(200.0)
    assert hf.heights.shape == (33, 33)


def test_erosion_changes_heights_and_conserves_roughly():
    raw = fractal(64, seed=3, erode=False).heights
    eroded = fractal(64, seed=3, erode=True).heights
    assert not np.array_equal(raw, eroded)
    assert raw.max() == pytest.approx(RELIEF_M)
    assert eroded.max() <= raw.max()


def test_relief_parameter():
    hf = fractal(32, seed=0, erode=False, relief_m=1000.0)
    assert hf.heights.max() == pytest.approx(1000.0)


@pytest.mark.parametrize("size", [0, 8, 15, 17, 100, 8193, 16384, -16])
def test_size_must_be_power_of_two_in_range(size):
    with pytest.raises(TerrainError, match="power of two"):
        fractal(size)


@pytest.mark.parametrize("size", [16.0, "64", True])
def test_size_must_be_integer(size):
    with pytest.raises(TerrainError):
        fractal(size)


@pytest.mark.parametrize("kwargs", [{"seed": -1}, {"seed": 1.5}, {"extent_m": 0.0},
                                    {"extent_m": float("inf")}, {"relief_m": 0.0}])
def test_bad_parameters_raise(kwargs):
    with pytest.raises(TerrainError):
        fractal(16, **kwargs)


def test_smallest_size_is_valid():
    h = fractal(16, seed=2).heights
    assert h.shape == (17, 17)
    assert np.all(np.isfinite(h)) and h.max() > 0
