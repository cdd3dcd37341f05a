"""The level-0 chunk cache of a store read on demand: chunk geometry at the edges, the
least-recently-used eviction, and the residency mask kept in step with what is held."""

import numpy as np

from lodsprite.terrain.chunkcache import ChunkCache


def test_windows_and_ids_cover_level_0_with_short_edge_chunks():
    cache = ChunkCache((10, 7), 4, 8)  # 3 x 2 chunks, the last row and column short
    assert cache.chunk_cols == 2 and cache.here.size == 6
    assert cache.window(0) == (0, 4, 0, 4) and cache.window(5) == (8, 10, 4, 7)
    r, c = np.meshgrid(np.arange(10), np.arange(7), indexing="ij")
    ids = cache.ids(r, c)
    for cid in range(6):
        r0, r1, c0, c1 = cache.window(cid)
        assert np.all(ids[r0:r1, c0:c1] == cid)
        assert (ids == cid).sum() == (r1 - r0) * (c1 - c0)


def test_the_least_recently_used_chunk_goes_and_the_mask_follows():
    cache = ChunkCache((16, 16), 4, 4)
    for cid in range(4):
        cache.keep(cid, np.full((4, 4), float(cid)))
    assert cache.get(0) is not None  # 0 used again: 1 is now the oldest
    cache.keep(9, np.zeros((4, 4)))
    assert cache.held() == {0, 2, 3, 9} and len(cache) == 4
    assert np.flatnonzero(cache.here).tolist() == [0, 2, 3, 9]
    assert cache.get(1) is None and cache.chunks_read == 5
