"""Tests of LOD chains, simplification and geometric error (lodsprite.profiles.chain)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lodsprite.errors import MeshError
from lodsprite.meshes import Mesh
from lodsprite.profiles.chain import (
    DEFAULT_RATIOS,
    LodChain,
    build_chain,
    geometric_errors,
    max_surface_distance,
    point_triangle_distance,
    simplify,
    surface_distances,
)
from lodsprite.profiles.models import sphere_family


@pytest.fixture(scope="module")
def ball() -> Mesh:
    """Icosphere of 5120 faces, radius 1."""
    ico = trimesh.creation.icosphere(subdivisions=4)
    return Mesh(ico.vertices, ico.faces, "ball")


@pytest.fixture(scope="module")
def small_family():
    return sphere_family(levels=6, max_faces=20000)


def _sheet(n: int = 40) -> Mesh:
    """Open wavy sheet of ``2 n^2`` faces (a terrain-like mesh with a border)."""
    r, c = np.mgrid[0:n + 1, 0:n + 1].astype(np.float64)
    z = np.sin(r / 5.0) * np.cos(c / 7.0)
    v = np.stack([c.ravel(), r.ravel(), z.ravel()], axis=1)
    i = (r[:-1, :-1] * (n + 1) + c[:-1, :-1]).astype(np.int64).ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + n + 1], 1)])
    return Mesh(v, f, "sheet")


@pytest.mark.parametrize("target", [50, 500, 2000])
def test_simplify_hits_target(ball, target):
    v, f = simplify(ball.vertices, ball.faces, target)
    assert v.dtype == np.float32 and f.dtype == np.int32
    assert abs(len(f) - target) <= 0.03 * target
    assert np.unique(f).size == len(v)               # no unreferenced vertices
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=0.1)


def test_simplify_open_mesh_keeps_border_and_hits_target():
    sheet = _sheet()
    for target in (100, 1000):
        v, f = simplify(sheet.vertices, sheet.faces, target)
        assert abs(len(f) - target) <= 0.03 * target
        assert v[:, 0].min() == 0 and v[:, 0].max() == 40   # corners survive
        assert v[:, 1].min() == 0 and v[:, 1].max() == 40


def test_simplify_target_at_or_above_full_is_a_copy(ball):
    v, f = simplify(ball.vertices, ball.faces, 10**6)
    np.testing.assert_array_equal(v, ball.vertices)
    np.testing.assert_array_equal(f, ball.faces)
    assert v.flags.writeable


def test_simplify_rejects_zero_target(ball):
    with pytest.raises(MeshError, match="at least 1"):
        simplify(ball.vertices, ball.faces, 0)


def test_build_chain_default_ratios(ball):
    chain = build_chain(ball)
    faces = chain.faces
    assert len(chain) == len(DEFAULT_RATIOS) + 1
    assert all(b > a for a, b in zip(faces, faces[1:], strict=False))
    assert chain.full is ball and faces[-1] == 5120
    for got, ratio in zip(faces, DEFAULT_RATIOS, strict=False):
        assert abs(got - ratio * 5120) <= 0.03 * ratio * 5120 + 1
    assert len(set(chain.digests)) == len(chain)
    assert chain.name == "ball" and "ball" in repr(chain)


def test_build_chain_face_counts_and_ratios(ball):
    chain = build_chain(ball, face_counts=[2000, 100, 5120, 9000, 100])
    assert chain.faces[-1] == 5120 and len(chain) == 3
    assert chain.faces[0] == pytest.approx(100, abs=3)
    chain = build_chain(ball, ratios=[0.5, 0.25])
    assert len(chain) == 3


@pytest.mark.parametrize("kwargs, message", [
    ({"face_counts": [100], "ratios": [0.5]}, "not both"),
    ({"ratios": [0.0]}, r"\(0, 1\)"),
    ({"ratios": [1.0]}, r"\(0, 1\)"),
    ({"face_counts": [0, 10]}, "positive"),
])
def test_build_chain_rejects_bad_arguments(ball, kwargs, message):
    with pytest.raises(MeshError, match=message):
        build_chain(ball, **kwargs)


def test_lod_chain_validation(ball):
    coarse = Mesh(*simplify(ball.vertices, ball.faces, 100), "c")
    with pytest.raises(MeshError, match="increase strictly"):
        LodChain("x", (ball, coarse))
    with pytest.raises(MeshError, match="increase strictly"):
        LodChain("x", (coarse, coarse))
    with pytest.raises(MeshError, match="no levels"):
        LodChain("x", ())
    assert LodChain("x", [coarse, ball]).levels == (coarse, ball)


def test_point_triangle_distance_matches_trimesh():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(2000, 3, 3))
    p = rng.normal(size=(2000, 3)) * 2
    closest = trimesh.triangles.closest_point(tri, p)
    expected = np.linalg.norm(closest - p, axis=1)
    got = point_triangle_distance(p, tri[:, 0], tri[:, 1], tri[:, 2])
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # degenerate (collinear) triangle: distance to its segment
    d = point_triangle_distance(np.array([[0.5, 1.0, 0.0]]), np.zeros((1, 3)),
                                np.array([[1.0, 0, 0]]), np.array([[0.5, 0, 0]]))
    assert d[0] == pytest.approx(1.0)


def test_surface_distance_bounds_and_exact_max(small_family):
    full = small_family.full
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(80, 3))
    pts *= (0.3 + 0.4 * rng.random(80))[:, None] / np.linalg.norm(pts, axis=1, keepdims=True)
    tri = full.vertices.astype(np.float64)[full.faces]
    brute = np.array([point_triangle_distance(np.broadcast_to(q, (len(tri), 3)), tri[:, 0],
                                              tri[:, 1], tri[:, 2]).min() for q in pts])
    approx = surface_distances(pts, full.vertices, full.faces)
    assert np.all(approx >= brute - 1e-12)
    assert max_surface_distance(pts, full.vertices, full.faces) == pytest.approx(brute.max(),
                                                                                 abs=1e-12)


def test_geometric_errors_on_sphere_family(small_family):
    errors = geometric_errors(small_family, samples=5000)
    assert errors.shape == (len(small_family),) and errors.dtype == np.float64
    assert errors[-1] == 0.0
    assert np.all(errors[:-1] > 0)
    assert np.all(np.diff(errors) < 0)                # coarser level, larger error
    # 24-face UV sphere: deepest points are the centres of the equatorial faces,
    # 0.5 * (1 - cos(30 deg) * cos(30 deg)) = 0.125 inside the sphere.
    assert errors[0] == pytest.approx(0.125, rel=0.01)
    again = geometric_errors(small_family, samples=5000)
    np.testing.assert_array_equal(errors, again)      # seeded
