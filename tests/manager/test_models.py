"""Continuous-LOD models: the progressive mesh and leaf collapse."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lodsprite.errors import InputError
from lodsprite.manager.builtins import mesh_model, ogre, tree
from lodsprite.manager.models import ProgressiveMesh


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(3)
    return ProgressiveMesh("sphere", m.vertices, m.faces)


def test_factor_one_is_the_full_mesh(sphere):
    idx = sphere.extract(1.0).reshape(-1, 3)
    assert np.array_equal(np.sort(np.sort(idx, axis=1), axis=0),
                          np.sort(np.sort(sphere.faces, axis=1), axis=0))


def test_triangles_never_grow_as_the_factor_falls_down_to_ten_percent(sphere):
    counts = [len(sphere.extract(f)) // 3 for f in np.linspace(1, 0, 11)]
    assert all(a >= b for a, b in zip(counts, counts[1:], strict=False))
    assert counts[0] == len(sphere.faces)
    assert abs(counts[-1] - 0.1 * len(sphere.faces)) <= 0.02 * len(sphere.faces)
    # the LODs index the one shared vertex buffer, and keep the sphere's size
    for f in (0.0, 0.5):
        idx = sphere.extract(f)
        assert idx.max() < len(sphere.vertices)
        r = np.linalg.norm(sphere.vertices[np.unique(idx)], axis=1)
        np.testing.assert_allclose(r, 1.0, atol=1e-9)


def test_the_built_ins_have_the_papers_sizes():
    o = ogre()
    assert 1800 <= o.full <= 2400 and o.triangles(0.0) <= 0.11 * o.full
    t = tree()
    assert 90_000 <= t.full <= 100_000 and t.triangles(0.0) <= 0.11 * t.full


def test_leaf_collapse_keeps_the_foliage_area():
    t = tree(leaves=4000)
    full = t.leaf_area(1.0)
    for f in (0.75, 0.4, 0.0):
        assert t.leaf_area(f) == pytest.approx(full, rel=1e-6)
    # and the leaves drawn fall with f (two leaves become one per collapse)
    n = [len(t.extract(f)) for f in (1.0, 0.5, 0.0)]
    assert n[0] > n[1] > n[2]


def test_a_user_mesh_becomes_a_progressive_model_and_bad_files_are_one_error(tmp_path):
    trimesh.creation.capsule(count=[12, 12]).export(tmp_path / "c.ply")
    m = mesh_model(str(tmp_path / "c.ply"))
    assert m.vertices[:, 2].min() == pytest.approx(0.0) and m.triangles(0) < m.full
    (tmp_path / "empty.obj").write_text("")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat nonsense\n")
    for bad in ("empty.obj", "junk.ply", "missing.obj"):
        with pytest.raises(InputError):
            mesh_model(str(tmp_path / bad))
