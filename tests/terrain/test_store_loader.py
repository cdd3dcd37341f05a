"""Streaming a terrain store's tiles through a reader process (issue 16, 2)."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from lodsprite.terrain.quadtree import Node, Quadtree
from lodsprite.terrain.store import TerrainStore, build_store
from lodsprite.terrain.streaming import StoreTileLoader, tile_loader


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("ld") / "s.zarr"
    build_store("fractal:300x400:5", path, tile=128, chunk=64)
    return TerrainStore(path)


def pump_until(loader, done, seconds=20.0):
    deadline = time.monotonic() + seconds
    while not done() and time.monotonic() < deadline:
        loader.pump()
        time.sleep(0.005)


def test_a_store_streams_through_a_reader_process_the_samples_the_store_holds(store):
    tree = Quadtree(store, grid=64)
    threads = threading.active_count()
    loader = tile_loader(tree, host_mb=64)
    assert isinstance(loader, StoreTileLoader)
    try:
        nodes = [Node(0, i, j) for i in range(4) for j in range(6) if tree.exists(Node(0, i, j))]
        loader.want([(float(m), n) for m, n in enumerate(nodes)])
        pump_until(loader, lambda: loader.loaded + len(loader.bad) == len(nodes))
        assert loader.loaded == len(nodes) and not loader.bad and loader.idle()
        assert threading.active_count() == threads  # no thread beside the draws
        for n in nodes:
            r0, r1, c0, c1 = tree.samples(n)
            np.testing.assert_array_equal(loader.take(n), store.read(0, r0, r1, c0, c1))
        pid = loader.worker.pid
    finally:
        loader.close()
    assert not loader.worker.alive
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_a_reader_that_dies_is_started_again_and_only_its_tile_is_bad(store):
    tree = Quadtree(store, grid=64)
    loader = StoreTileLoader(tree, host_mb=64, in_flight=1)
    try:
        first = Node(0, 0, 0)
        loader.want([(1.0, first)])
        pump_until(loader, lambda: loader.loaded == 1)
        pid = loader.worker.pid
        os.kill(pid, signal.SIGSTOP)        # it cannot answer ...
        victim, other = Node(0, 1, 1), Node(0, 2, 2)
        loader.want([(2.0, victim), (1.0, other)])  # ... the victim is sent to it
        assert loader.pending == [victim]
        os.kill(pid, signal.SIGKILL)        # and it dies with the victim in flight
        pump_until(loader, lambda: loader.loaded == 2)
        assert loader.bad == {victim} and loader.take(other) is not None
        assert loader.worker.alive and loader.worker.pid != pid
        assert loader.worker.deaths == 1
    finally:
        loader.close()


def test_an_unreadable_chunk_is_answered_as_an_error_and_is_bad_once(tmp_path):
    build_store("fractal:200x200:2", tmp_path / "b.zarr", tile=128, chunk=64)
    shards = sorted((tmp_path / "b.zarr" / "0").rglob("c/*/*"))
    shards[0].write_bytes(b"not a shard")
    tree = Quadtree(TerrainStore(tmp_path / "b.zarr"), grid=64)
    loader = tile_loader(tree, host_mb=16)
    try:
        bad, good = Node(0, 0, 0), Node(0, 2, 2)
        for _ in range(2):
            loader.want([(2.0, bad), (1.0, good)])
            pump_until(loader, lambda: loader.loaded == 1 and loader.bad)
        assert loader.bad == {bad} and loader.loaded == 1
    finally:
        loader.close()
