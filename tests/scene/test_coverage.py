"""The layers' screen coverage measured from geometry (issue 30, must-have 4): the
terrain's non-sky part against analytic views of a flat square, rectangle and disc
unions against their areas, overlaps counted once."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.camera import look_at, perspective
from lodsprite.layered.coverage import (
    GRID,
    TERRAIN_GRID,
    discs_coverage,
    rects_coverage,
    terrain_coverage,
)
from lodsprite.terrain.heightfield import HeightField

CELL = 1.0 / GRID          # one grid row or column, the figures' resolution
RAY = 1.0 / TERRAIN_GRID   # the terrain's
PROJ = perspective(90.0, 1.0, 0.5, 1e5)


def flat(half_m: float, samples: int = 65) -> HeightField:
    """A flat square ``2 half_m`` a side at height 0."""
    return HeightField(np.zeros((samples, samples), np.float32), 2 * half_m / (samples - 1),
                       2 * half_m / (samples - 1))


def test_looking_down_at_the_ground_it_covers_everything_and_up_nothing():
    hf = flat(1000.0)
    assert terrain_coverage(hf, look_at((0, 0, 50), (0, 1, 0)), PROJ) == 1.0
    assert terrain_coverage(hf, look_at((0, 0, 50), (0, 1, 100)), PROJ) == 0.0


@pytest.mark.parametrize("h_over_l", [0.25, 0.5, 0.02])
def test_a_level_view_over_a_flat_square_covers_below_its_sky_line(h_over_l):
    # the eye at height h over the centre of a square of half side L, looking along +y
    # with a 90° field of view: the cell at window (u, v) in -1..1 meets the ground at
    # y = h / -v, x = u h / -v, inside the square iff -v >= h / L and |u| <= -v L / h
    half = 1000.0
    h = h_over_l * half
    got = terrain_coverage(flat(half), look_at((0, 0, h), (0, 1, h)), PROJ)
    v = -np.linspace(0, 1, 100001)[1:]
    u_max = np.minimum(1.0, -v / h_over_l)
    lower = np.where(-v >= h_over_l, u_max, 0.0).mean()   # of the window's lower half
    assert got == pytest.approx(lower / 2, abs=RAY)
    assert 0.0 < got <= 0.5


def test_a_wall_covers_the_sky_up_to_its_top():
    # a wall 200 m high, y in 490..510 m, across the square: the level eye at 100 m sees
    # ground below the horizon and the wall up to v = 100 / 490 above it (90° view)
    rows = np.arange(201)
    y = 1000.0 - rows * 10.0
    heights = np.where(np.abs(y - 500.0) <= 10.0, 200.0, 0.0)[:, None] * np.ones(201)
    wall = HeightField(heights.astype(np.float32), 10.0, 10.0)
    got = terrain_coverage(wall, look_at((0, 0, 100), (0, 1, 100)), PROJ)
    assert got == pytest.approx((1 + 100 / 490) / 2, abs=RAY)


def test_rectangles_union_counts_an_overlap_once():
    assert rects_coverage([(0.0, 0.0, 0.5, 0.5)]) == pytest.approx(0.25, abs=2 * CELL)
    assert rects_coverage([(0.0, 0.0, 0.5, 0.5)] * 3) == rects_coverage([(0.0, 0.0, 0.5, 0.5)])
    two = rects_coverage([(0.0, 0.0, 0.5, 0.5), (0.25, 0.0, 0.5, 0.5)])
    assert two == pytest.approx(0.375, abs=2 * CELL)
    assert rects_coverage([]) == 0.0


def test_discs_union_counts_an_overlap_once():
    size = (200, 100)
    one = discs_coverage([[100, 50]], [30.0], size)
    assert one == pytest.approx(np.pi * 30 ** 2 / (200 * 100), abs=0.02)
    assert discs_coverage([[100, 50]] * 5, [30.0] * 5, size) == one
    apart = discs_coverage([[50, 50], [150, 50]], [30.0, 30.0], size)
    assert apart == pytest.approx(2 * one, abs=0.01)
    big = discs_coverage([[100, 50]], [1000.0], size)
    assert big == 1.0
    # small discs (splatted) and large ones (every cell) agree with a brute-force count
    rng = np.random.default_rng(1)
    many, radii = rng.uniform(0, 200, (300, 2)), rng.uniform(0.5, 40.0, 300)
    cells = (np.stack(np.meshgrid(np.arange(GRID), np.arange(GRID)), -1).reshape(-1, 2)
             + 0.5) * np.array(size) / GRID
    brute = (((cells[:, None] - many[None]) ** 2).sum(-1) <= radii ** 2).any(1).mean()
    assert discs_coverage(many, radii, size) == brute
