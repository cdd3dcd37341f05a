"""Critical-time selection (§4), GL-free: benefit, benefit/cost order, eviction, the
rescaling of the cost model, and the loader's process."""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from lodsprite.lumigraph.critical import (
    DISK,
    RAM,
    RESIDENT,
    CostModel,
    benefit,
    neighbour_fraction_missing,
    plan,
    st_point,
)
from lodsprite.lumigraph.geometry import Slab

SLAB = Slab(np.eye(4), st_size=3.0, uv_size=2.0, st_distance=2.5, n_st=8, n_uv=32)


def test_the_eye_st_point_is_on_the_ray_to_the_object_centre():
    eye = np.array([0.8, -0.4, 5.0])
    st = st_point(SLAB, eye)
    np.testing.assert_allclose(st, eye[:2] * 2.5 / 5.0)


def test_benefit_falls_with_distance_from_the_eye_and_from_the_predicted_path():
    drawn = np.zeros(64, bool)
    eye = np.array([0.0, 0.0])
    b = benefit(SLAB, eye, np.zeros((0, 2)), drawn).reshape(8, 8)
    assert ((0 < b) & (b <= 1)).all()
    # nodes nearer the eye's st point rank higher
    order = np.argsort(-b.ravel())
    d = np.linalg.norm(SLAB.node_local()[..., :2].reshape(-1, 2), axis=1)
    assert np.all(np.diff(d[order]) >= -1e-12)
    # a predicted path towards +s lifts the nodes ahead over those behind
    path = np.array([[0.5, 0.0], [1.0, 0.0]])
    bp = benefit(SLAB, eye, path, drawn).reshape(8, 8)
    ahead, behind = bp[6, 3], bp[1, 4]          # mirror images about the eye
    assert np.isclose(b[6, 3], b[1, 4]) and ahead > 2 * behind


def test_neighbor_term_prefers_nodes_whose_neighbours_are_not_drawn():
    drawn = np.zeros((4, 4), bool)
    drawn[0:2, 0:2] = True
    missing = neighbour_fraction_missing(drawn)
    assert missing[3, 3] == 1.0 and missing[0, 0] == 0.0
    np.testing.assert_allclose(missing[1, 1], 5 / 8)   # 3 of its 8 neighbours are drawn


def test_plan_adds_nodes_in_benefit_cost_order_until_the_budget_is_spent():
    costs = CostModel(upload=2.0, raster_base=4.0, raster_node=0.5, base=1.0)
    gain = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.05])
    where = np.array([RAM, RESIDENT, RAM, RESIDENT, RAM, RESIDENT])
    # ratios: resident 0.8/0.5=1.6, 0.6/0.5=1.2, 0.05/0.5=0.1; in RAM 0.9/2.5=0.36,
    # 0.7/2.5=0.28, 0.5/2.5=0.2: order 1, 3, 0, 2, 4, 5
    p = plan(gain, where, costs, budget_ms=11.6, capacity=10)
    # 5 + 0.5 + 0.5 + 2.5 + 2.5 = 11: node 4 (2.5 more) does not fit, node 5 (0.5) does
    assert p.draw.tolist() == [1, 3, 0, 2, 5]
    assert p.upload.tolist() == [0, 2]
    np.testing.assert_allclose(p.predicted_ms, 11.5)
    assert len(p.evict) == 0 and len(p.request) == 0


def test_plan_requests_disk_nodes_best_first_and_never_blocks_on_them():
    costs = CostModel(upload=1.0, raster_base=1.0, raster_node=0.1, base=0.0, fetch=0.5,
                      decode=2.0)
    gain = np.array([1.0, 0.9, 0.2, 0.8])
    where = np.array([DISK, DISK, RESIDENT, DISK])
    p = plan(gain, where, costs, budget_ms=100.0, capacity=4, requests=2)
    assert p.draw.tolist() == [2] and p.request.tolist() == [0, 1]


def test_a_full_texture_memory_evicts_the_lowest_benefit_resident_node():
    costs = CostModel(upload=0.1, raster_base=0.0, raster_node=0.01, base=0.0)
    gain = np.array([0.9, 0.1, 0.3, 0.2, 0.95])
    where = np.array([RESIDENT, RESIDENT, RESIDENT, RESIDENT, RAM])
    p = plan(gain, where, costs, budget_ms=100.0, capacity=4)
    # the new node (0.95) replaces the lowest-benefit resident node (node 1, 0.1)
    assert sorted(p.draw.tolist()) == [0, 2, 3, 4]
    assert p.upload.tolist() == [4] and p.evict.tolist() == [1]


def simulate(costs: CostModel, target: float, frames: int = 80, load: float = 1.0):
    """A synthetic machine: upload 1.6 ms a node, raster 6 + 0.2 ms a node, 1.5 ms more,
    all times ``load``; an endless supply of decoded nodes worth uploading."""
    n = 400
    where = np.full(n, RAM)
    gain = np.linspace(1.0, 0.5, n)
    times = []
    for f in range(frames):
        p = plan(gain, where, costs, target, capacity=n)
        true = {"upload": 1.6 * len(p.upload) * load,
                "raster": (6.0 + 0.2 * len(p.draw)) * load, "base": 1.5 * load}
        times.append(sum(true.values()))
        costs.observe(len(p.upload), len(p.draw), true)
        where[:] = RAM  # nodes keep coming: each frame can upload again
        where[p.draw[: len(p.draw) // 2]] = RESIDENT
        gain = np.roll(gain, 7 + f % 3)
    return np.array(times)


def test_rescaling_converges_on_the_target_from_wrong_cost_estimates():
    # estimates 4x too low for uploads, 2x too high for raster
    costs = CostModel(upload=0.4, raster_base=12.0, raster_node=0.4, base=0.5)
    t = simulate(costs, target=33.0)
    assert t[:5].max() > 40.0                       # the first frames overshoot
    assert np.abs(t[-20:] / 33.0 - 1.0).max() < 0.08
    assert 3.0 < costs.scale["upload"] < 5.0 and 0.4 < costs.scale["raster"] < 0.6


def test_rescaling_follows_a_change_in_machine_load():
    costs = CostModel(upload=1.6, raster_base=6.0, raster_node=0.2, base=1.5)
    simulate(costs, target=33.0, frames=30)
    t = simulate(costs, target=33.0, frames=60, load=1.5)   # the machine gets busier
    assert np.abs(t[-20:] / 33.0 - 1.0).max() < 0.08


def test_one_factor_for_all_components_also_converges_on_the_mean():
    costs = CostModel(upload=0.4, raster_base=12.0, raster_node=0.4, base=0.5,
                      per_component=False)
    t = simulate(costs, target=33.0, frames=120)
    assert abs(t[-40:].mean() / 33.0 - 1.0) < 0.1


def test_the_loader_fetches_and_decodes_wanted_nodes_in_a_process(tmp_path):
    from lodsprite.lumigraph.capture import textured_plane
    from lodsprite.lumigraph.loader import NodeLoader
    from lodsprite.lumigraph.store import Lumigraph, node_name, save

    rng = np.random.default_rng(0)
    images = {(i, j): rng.integers(0, 255, (32, 32, 3), dtype=np.uint8)
              for i in range(8) for j in range(8)}
    save(tmp_path / "lf", [SLAB], [images], textured_plane(2.0, 4), "x", 0.1, 10.0,
         codec="jpeg")
    (tmp_path / "lf" / node_name(0, 0, 1, "jpeg")).unlink()
    threads = threading.active_count()
    loader = NodeLoader(Lumigraph(tmp_path / "lf"), level=1)
    try:
        loader.want(np.array([9, 1, 2]))
        deadline = time.monotonic() + 20
        while (loader.decoded < 2 or 1 not in loader.bad) and time.monotonic() < deadline:
            loader.pump()  # what a frame does: collect without waiting
            time.sleep(0.01)
        held = loader.holds(64)
        assert held[9] and held[2] and not held[1] and loader.bad == {1}
        assert set(loader.lf.bad_nodes) == {(0, 0, 1)}  # said here, found there
        assert loader._worker.pid not in (None, os.getpid())
        assert threading.active_count() == threads  # no thread beside the draws
        img = loader.get(9)
        assert img.shape == (16, 16, 3)               # level 1: decoded at half size
        costs = loader.drain_costs()
        assert {n for n, _, _ in costs} == {9, 2}
        assert all(f >= 0 and d > 0 for _, f, d in costs)
    finally:
        loader.close()
