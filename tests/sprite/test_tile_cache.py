"""The cache of tile renders (Chen et al. 1999 §5 per screen tile): each tile shows its
render with the lowest error, the cache stays within its byte budget, a budget that holds
fewer than two renders per tile is refused."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.sprite.cache import TileCache

KB = 1024
PROJ = Projection(45.0, 1.0, 1.0, 1e5)


def _at(x: float) -> Viewpoint:
    return Viewpoint(np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]),
                     np.array([x, 0.0, 1000.0]))


def test_each_tile_shows_its_render_with_the_lowest_error():
    # Hand-made errors: tile 0's renders err 3, 1, 2 px (update index = entry), tile 1's
    # 0.5, 4: the best is update 1 for tile 0 and update 0 for tile 1.
    cache = TileCache(2 * 4 * 100 * KB, [100 * KB, 100 * KB], "lru")
    errs = {0: [3.0, 1.0, 2.0], 1: [0.5, 4.0]}
    for t, e in errs.items():
        for u in range(len(e)):
            cache.insert(t, u, _at(float(u)), PROJ, np.zeros((4, 3)), u)
    for t, e in errs.items():
        entry, err = cache.best(t, np.array([5.0, 0.0, 1000.0]),
                                lambda c, e=e: e[c.index], 10)
        assert entry.index == int(np.argmin(e)) and err == min(e)
        assert cache.caches[t].shown is entry


@pytest.mark.parametrize("policy", ["lru", "benefit"])
def test_the_tile_cache_stays_within_its_budget(policy):
    # 3 tiles of different sizes, 40 renders each: resident bytes never exceed the budget,
    # the shown render is never evicted.
    sizes = [100 * KB, 120 * KB, 90 * KB]
    budget = 3 * 5 * 100 * KB
    cache = TileCache(budget, sizes, policy)
    for now in range(40):
        for t in range(3):
            shown = cache.caches[t].shown
            cache.insert(t, now, _at(float(now)), PROJ, np.zeros((4, 3)), now)
            assert shown is None or shown in cache.caches[t].entries
            assert cache.resident_bytes <= budget
    assert [c.capacity for c in cache.caches] == [5, 4, 5]
    assert cache.max_resident == 14


def test_a_budget_under_two_renders_per_tile_is_refused():
    with pytest.raises(InputError, match="cache-mb"):
        TileCache(3 * 100 * KB, [100 * KB, 100 * KB], "lru")
