"""The heights shading at a grid's samples (``terrain.textures.height_shading``, what a page
shows where no keyframe saw a store's surface), against the shading's own formula on
planes whose normal and ramp position are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.errors import TerrainError
from lodsprite.terrain.textures import SHADE_LIGHT, height_shading


def shade(t: float, normal: np.ndarray) -> np.ndarray:
    low, mid, high = np.array([0.32, 0.45, 0.25]), np.array([0.55, 0.48, 0.34]), 0.9
    c = low + (mid - low) * t / 0.6 if t < 0.6 else mid + (high - mid) * (t - 0.6) / 0.4
    n = normal / np.linalg.norm(normal)
    return c * (0.3 + 0.7 * max(float(n @ SHADE_LIGHT), 0.0)) * 255.0


def test_a_flat_grid_is_its_ramp_colour_lit_from_above() -> None:
    h = np.full((5, 7), 30.0)
    got = height_shading(h, 2.0, 2.0, 0.0, 100.0)
    assert got.shape == (5, 7, 3) and got.dtype == np.uint8
    np.testing.assert_allclose(got, np.broadcast_to(shade(0.3, np.array([0.0, 0.0, 1.0])),
                                                    got.shape), atol=0.5)


def test_a_slope_facing_the_sun_is_lit_and_one_facing_away_is_dark() -> None:
    rows, cols, d = 9, 9, 10.0
    x = np.arange(cols) * d
    y = -np.arange(rows) * d                     # row 0 north: y falls with the row
    east = np.broadcast_to(0.5 * x, (rows, cols))  # rises to the east: faces west (sun side)
    north = np.broadcast_to(0.5 * y[:, None], (rows, cols))  # rises to the north: faces south
    for h, normal in ((east, np.array([-0.5, 0.0, 1.0])), (north, np.array([0.0, -0.5, 1.0]))):
        lo, hi = float(h.min()), float(h.max())
        got = height_shading(h, d, d, lo, hi).astype(float)
        for r, c in ((4, 4), (0, 0), (8, 8)):  # the edges: one-sided, the same on a plane
            t = (h[r, c] - lo) / (hi - lo)
            np.testing.assert_allclose(got[r, c], shade(t, normal), atol=0.5)
    # the sun is to the north-west: the west-facing slope is brighter than the south-facing
    assert height_shading(east, d, d, 0, 40)[4, 4].sum() > height_shading(
        north, d, d, -40, 0)[4, 4].sum()


def test_a_grid_of_one_row_is_refused() -> None:
    with pytest.raises(TerrainError):
        height_shading(np.zeros((1, 5)), 1.0, 1.0, 0.0, 1.0)
