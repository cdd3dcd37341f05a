"""The keyframe cache (Chen et al. 1999 §5): the policy shows the cached keyframe with the
lowest error, the cache keeps within its byte budget, lru and benefit evict what they
should, the GL pool stays within the budget, and cache_mb=0 is the 1999 loop as before."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.sprite.cache import MAX_CANDIDATES, KeyframeCache
from lodsprite.sprite.policy import KEYFRAME, KeyframePolicy
from lodsprite.terrain.generators import fractal

KB = 1024
PROJ = Projection(45.0, 1.0, 1.0, 1e5)


def _north(y: float, z: float = 2500.0) -> Viewpoint:
    """Looking north, pitched down 30°, at (0, y, z)."""
    p = np.radians(30.0)
    d = np.array([0.0, -np.cos(p), np.sin(p)])
    up = np.array([0.0, np.sin(p), np.cos(p)])
    return Viewpoint(np.cross(up, d), up, d, np.array([0.0, y, z]))


def _cache(n: int, policy: str = "lru") -> KeyframeCache:
    return KeyframeCache(n * 100 * KB, 100 * KB, policy)


def _insert(cache: KeyframeCache, i: int, now: int):
    return cache.insert(i, _north(float(i)), PROJ, np.zeros((4, 3)), now)


def test_the_policy_shows_the_cached_keyframe_with_the_lowest_error():
    hf = fractal(256, 3)
    cache = KeyframeCache(64 * 2 ** 20, 2 ** 20)
    policy = KeyframePolicy.for_terrain(hf, 16, 1e-9, (128, 128), guard_px=16, predict=False,
                                        cache=cache)
    for y in (-1500.0, 0.0, 1500.0):  # under a tiny ε every frame is a keyframe
        assert policy.decide(_north(y)).type == KEYFRAME
    here = _north(120.0)  # nearest the middle keyframe, which is not the one shown
    assert cache.shown.index == 2
    errors = [policy.cached_error_px(e, here, policy.projection(here)) for e in cache.entries]
    assert int(np.argmin(errors)) == 1 and errors[1] < 0.5 * min(errors[0], errors[2])
    policy.epsilon_px = 2.5 * errors[2]  # under SWITCH_FRACTION ε the shown one stays
    assert policy.best_cached(here, policy.projection(here))[0].index == 2
    policy.epsilon_px = 1.5 * errors[2]  # the shown one serves, but above SWITCH_FRACTION
    best, err = policy.best_cached(here, policy.projection(here))
    assert best.index == 1 and err == pytest.approx(errors[1])
    d = policy.decide(here)
    assert d.key is None and d.keyframe == 1 and d.slot == cache.entries[1].slot
    assert d.decision_error_px == pytest.approx(errors[1]) and cache.shown.index == 1
    policy.epsilon_px = 0.5 * errors[1]  # under the best error: a new keyframe is due
    d = policy.decide(_north(121.0))
    assert d.type == KEYFRAME and d.keyframe == 3 and len(cache.entries) == 4


@settings(max_examples=60, deadline=None)
@given(key_kb=st.integers(1, 4096), budget_keys=st.floats(2.0, 40.0),
       policy=st.sampled_from(["lru", "benefit"]),
       steps=st.lists(st.tuples(st.booleans(), st.integers(0, 50), st.floats(0.1, 900.0)),
                      min_size=1, max_size=120))
def test_the_cache_never_exceeds_its_budget(key_kb, budget_keys, policy, steps):
    """A stream of insertions and uses: resident bytes within the budget, one keyframe per
    slot, slots below the capacity, the shown keyframe never the one evicted."""
    budget = budget_keys * key_kb * KB
    cache = KeyframeCache(budget, key_kb * KB, policy)
    for now, (new, pick, cost) in enumerate(steps):
        if new or not cache.entries:
            shown = cache.shown
            e = _insert(cache, now, now)
            e.cost_ms = cost
            assert shown is None or shown in cache.entries
        else:
            cache.use(cache.entries[pick % len(cache.entries)], now)
        assert cache.resident_bytes <= budget
        slots = [e.slot for e in cache.entries]
        assert len(set(slots)) == len(slots) and max(slots) < cache.capacity
    assert cache.max_resident <= budget // (key_kb * KB)


def test_lru_evicts_the_least_recently_shown():
    cache = _cache(3)
    a, b, c = (_insert(cache, i, i) for i in range(3))
    cache.use(a, 3)                  # b is now the least recently shown
    d = _insert(cache, 3, 4)
    assert b not in cache.entries and d.slot == b.slot
    cache.use(c, 5)
    cache.use(d, 6)                  # a least recent; d shown
    _insert(cache, 4, 7)
    assert a not in cache.entries and [e.index for e in cache.entries] == [2, 3, 4]


def test_benefit_keeps_the_dear_and_often_used():
    cache = _cache(3, "benefit")
    a, b, c = (_insert(cache, i, i) for i in range(3))
    a.cost_ms, b.cost_ms, c.cost_ms = 100.0, 10.0, 50.0
    for now in range(3, 8):
        cache.use(a, now)            # a: 6 uses, dear: stays though not the newest
    cache.use(c, 8)
    _insert(cache, 3, 9)             # b: one use, cheap, old -> lowest benefit
    assert b not in cache.entries and a in cache.entries
    lru = _cache(3)
    a2, b2, c2 = (_insert(lru, i, i) for i in range(3))
    lru.use(b2, 3)
    lru.use(c2, 4)
    _insert(lru, 3, 5)               # lru drops a2 whatever its uses
    assert a2 not in lru.entries


def test_only_nearby_eyes_are_candidates_and_the_shown_one_always():
    cache = _cache(MAX_CANDIDATES + 6)
    for i in range(MAX_CANDIDATES + 6):
        cache.insert(i, _north(100.0 * i), PROJ, np.zeros((4, 3)), i)
    cache.use(cache.entries[0], 99)  # shown: the farthest from the eye below
    cands = cache.candidates(np.array([0.0, 100.0 * (MAX_CANDIDATES + 5), 2500.0]))
    assert len(cands) == MAX_CANDIDATES and cands[0].index == 0
    assert {e.index for e in cands[1:]} == set(range(7, MAX_CANDIDATES + 6))


def test_a_budget_under_two_keyframes_is_a_user_error():
    with pytest.raises(InputError, match="at least"):
        KeyframeCache(1.5 * 2 ** 20, 2 ** 20)
    with pytest.raises(InputError, match="cache policy"):
        KeyframeCache(8 * 2 ** 20, 2 ** 20, "fifo")


# ---------------------------------------------------------------------- with GL

# kinds of fractal:64:3 along chen1999 (120 frames, 64x64, lod 8, ε 3 px) by the code
# before the cache (commit 309a418): k keyframe, f first spriteframe, s spriteframe
BEFORE = ("kfsssssssssskfssskfssssssskfssskfssskfssskfsssskfssssskfssssskfsssskfsssskfsssss"
          "kfssssskfsssskfssskfsssssskfssssssssssss")


def test_cache_off_is_the_1999_loop_as_before(gl):
    from lodsprite import Renderer, get_path, load_scene, techniques

    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 120)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        t = techniques.create("sprite", renderer, lod=8, epsilon=3.0, cache_mb=0.0)
        try:
            frames = [t.frame(vp) for vp in path.viewpoints]
            summary = t.summary(frames)
            assert t.sprite.engine.cache is None and len(t.sprite.sprite.key_targets) == 2
        finally:
            t.release()
    assert "".join(f.kind[0] for f in frames) == BEFORE
    assert summary["keyframes"] == BEFORE.count("k") == 17 and summary["cache_hits"] == 0


@pytest.mark.parametrize("name", ["sprite", "sprite-adaptive"])
@pytest.mark.parametrize("policy", ["lru", "benefit"])
def test_with_the_cache_the_replay_draws_what_the_timed_run_showed(gl, name, policy):
    """Along chen1999 the cache serves some frames from older keyframes; each frame's untimed
    replay equals its timed image, and the GL pool stays within the budget."""
    from lodsprite import Renderer, get_path, load_scene, techniques

    scene = load_scene("fractal:64:3", grid=64)
    path = get_path("chen1999", scene.hf, 120)
    with Renderer(scene, (64, 64), ctx=gl.mgl) as renderer:
        budget = 6 * renderer.sprite(1.0, 8).sprite.keyframe_bytes() / 2 ** 20
        t = techniques.create(name, renderer, **techniques.get(name).bind(
            {"lod": 8, "epsilon": 3.0, "key_sse": 1.0, "cache_mb": budget,
             "cache_policy": policy}))
        try:
            shown, decisions, frames = [], [], []
            for vp in path.viewpoints:
                frames.append(t.frame(vp))
                shown.append(t.read_image())
                decisions.append(t.decision())
            summary = t.summary(frames)
            assert t.sprite.engine.predicted_keyframes > 0  # the look-ahead works with the cache
            if name == "sprite":
                assert f"/{t.sprite.engine.cache.capacity} ({policy}" in t.status()
            sprite = t.sprite.sprite
            assert len(sprite.key_targets) * sprite.keyframe_bytes() <= budget * 2 ** 20
            for i, (vp, d) in enumerate(zip(path.viewpoints, decisions, strict=True)):
                assert np.array_equal(t.replay(vp, d), shown[i]), (name, i)
        finally:
            t.release()
    assert summary["cache_hits"] > 0 and 2 < summary["cache_keyframes"] <= 6
    assert summary["keyframes"] + summary["cache_hits"] < len(path.viewpoints)



def _wall_policy(top_m: float = 150.0) -> tuple[KeyframePolicy, KeyframeCache]:
    """A plain 1.28 km square, 10 m a sample, with a wall ``top_m`` high east-west across
    it 160-240 m north of its centre, under a policy at ε 1 with a cache, its metric on a
    4 x 4-node proxy of every 4th sample (the proxy metric: C' where the key ray first
    meets the proxy, so ground behind the wall is hidden from a low eye south of it)."""
    from lodsprite.sprite.proxy_metric import ProxyMetric
    from lodsprite.sprite.proxy_surface import ProxyNodes
    from lodsprite.terrain.heightfield import HeightField

    h = np.zeros((129, 129), np.float32)
    h[40:49, :] = top_m
    hf = HeightField(h, 10.0, 10.0, "wall")
    xs, ys = hf.world_xy(np.arange(129), np.arange(129))
    cells = [(r, c) for r in range(0, 128, 32) for c in range(0, 128, 32)]
    nodes = ProxyNodes(np.array([(xs[c], ys[r]) for r, c in cells]),
                       np.tile([40.0, 40.0], (16, 1)), np.full((16, 2), 8.0),
                       np.array([h[r:r + 33:4, c:c + 33:4] for r, c in cells], float),
                       np.array([(r, r + 32, c, c + 32) for r, c in cells]))
    cache = KeyframeCache(64 * 2 ** 20, 2 ** 20)
    policy = KeyframePolicy.for_terrain(hf, 16, 1.0, (128, 128), guard_px=16,
                                        predict=False, cache=cache)
    policy.metric = ProxyMetric(lambda eye, view_proj: nodes, hf, policy.metric)
    return policy, cache


def _low(x: float):
    """100 m south of the centre, 200 m up, looking north and down: ``x`` metres east."""
    from lodsprite.camera import look_at

    return look_at(np.array([x, -100.0, 200.0]), np.array([x, 600.0, 0.0]))


def test_a_cached_keyframe_far_from_the_view_is_refused_and_a_near_one_shown():
    # A keyframe from a low eye south of the wall; Eq. 2 alone would show it from 10 m
    # east, where ground it did not see behind the wall comes into view; with the far
    # term the cache refuses it there (a new keyframe), and shows it from 2 m east.
    policy, cache = _wall_policy()
    assert policy.decide(_low(0.0)).type == KEYFRAME
    key = cache.entries[0]
    near, far = _low(2.0), _low(10.0)
    assert policy.cached_error_px(key, near, policy.projection(near)) < 0.5
    d = policy.decide(near)
    assert d.type != KEYFRAME and d.keyframe == 0
    eq2 = policy.error_px(key.c_prime, far, policy.projection(far))
    assert eq2 < 1.0 <= policy.cached_error_px(key, far, policy.projection(far))
    d = policy.decide(far)
    assert d.type == KEYFRAME and d.keyframe == 1


def test_the_far_term_vanishes_where_the_keyframe_saw_every_sample():
    from lodsprite.sprite.cache import far_error_px

    for top, hidden in ((0.0, False), (150.0, True)):  # a plain, then the wall
        policy, cache = _wall_policy(top)
        policy.decide(_low(0.0))
        key, v = cache.shown, _low(40.0)
        p = policy.projection(v)
        far = far_error_px(policy.metric, key.c_prime, key.viewpoint.o, v.o,
                           p.matrix() @ v.view_matrix(), p.pixel_angle_rad(128))
        assert (far > 1.0) if hidden else far == 0.0, (top, far)
