"""Tests of the built-in models (lodsprite.profiles.models)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lodsprite.errors import MeshError
from lodsprite.profiles.models import (
    MOUNTAIN_FACES,
    MOUNTAIN_LOD_FACES,
    get_model,
    mountain,
    sphere_bands,
    sphere_family,
    sphereflake,
    sphereflake_levels,
    uv_sphere,
)
from lodsprite.terrain import load_terrain


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    t = vertices.astype(np.float64)[faces]
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


@pytest.fixture(scope="module")
def family():
    return sphere_family()


@pytest.fixture(scope="module")
def jacksboro_mountain():
    return mountain("jacksboro")


# --- sphere family ---------------------------------------------------------------------


def test_uv_sphere_counts_and_closed():
    for m in (2, 3, 7):
        v, f = uv_sphere(m)
        assert len(v) == 2 + 2 * m * (m - 1) and len(f) == 4 * m * (m - 1)
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0                          # outward winding
    with pytest.raises(MeshError):
        uv_sphere(1)


def test_sphere_family_default(family):
    faces = family.faces
    assert len(family) == 19 and family.name == "sphere"
    assert faces[0] == 24
    assert abs(faces[-1] - 394_212) <= 0.01 * 394_212
    assert all(b > a for a, b in zip(faces, faces[1:], strict=False))
    ratios = np.diff(np.log(faces))
    assert ratios.max() < 2.5 * ratios.mean()          # roughly geometric
    for level in family.levels:
        v = level.vertices.astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(v, axis=1), 0.5, atol=1e-6)
        n = _normals(level.vertices, level.faces)
        centroid = v[level.faces].mean(axis=1)
        outward = np.einsum("ij,ij->i", n, centroid)
        assert outward.mean() > 0 and np.all(outward > 0)
    centre, radius = family.full.bounding_sphere()
    np.testing.assert_allclose(centre, 0.0, atol=1e-6)
    assert radius == pytest.approx(0.5, abs=1e-6)


def test_sphere_family_small():
    chain = sphere_family(levels=6, max_faces=20000)
    assert len(chain) == 6 and chain.faces[0] == 24
    assert abs(chain.faces[-1] - 20000) <= 0.01 * 20000
    assert list(sphere_bands(1, 24)) == [3]
    with pytest.raises(MeshError, match="distinct"):
        sphere_family(levels=50, max_faces=1000)
    with pytest.raises(MeshError):
        sphere_family(levels=0)


# --- sphereflake -----------------------------------------------------------------------


@pytest.mark.parametrize("depth, count", [(0, 1), (1, 10), (2, 91)])
def test_sphereflake_counts(depth, count):
    centres, radii = sphereflake(depth)
    levels = sphereflake_levels(depth)
    assert centres.shape == (count, 3) and radii.shape == (count,) and levels.shape == (count,)
    assert centres.dtype == radii.dtype == np.float64
    np.testing.assert_array_equal(np.bincount(levels), 9 ** np.arange(depth + 1))
    np.testing.assert_allclose(radii, 0.5 / 3.0 ** levels)


def test_sphereflake_children_touch_parents_and_nothing_overlaps():
    centres, radii = sphereflake(2)
    parent = np.concatenate([[-1], np.zeros(9, int), np.repeat(np.arange(1, 10), 9)])
    for child in range(1, len(centres)):
        p = parent[child]
        gap = np.linalg.norm(centres[child] - centres[p])
        assert gap == pytest.approx(radii[p] + radii[child], abs=1e-9)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert np.all(d >= radii[:, None] + radii[None] - 1e-9)


def test_sphereflake_root_children_layout():
    centres, _ = sphereflake(1)
    z = centres[1:, 2]
    assert np.sum(np.isclose(z, 0.0, atol=1e-12)) == 6          # equator
    assert np.sum(z > 0.5) == 3 and not np.any(z < -1e-12)      # upper side only
    with pytest.raises(MeshError):
        sphereflake(-1)


# --- mountain --------------------------------------------------------------------------


def test_mountain_jacksboro(jacksboro_mountain):
    chain = jacksboro_mountain
    full = chain.full
    assert chain.name == "mountain:jacksboro"
    assert abs(full.n_faces - MOUNTAIN_FACES) <= 0.10 * MOUNTAIN_FACES
    assert len(chain) == len(MOUNTAIN_LOD_FACES) + 1
    for got, want in zip(chain.faces[:-1], MOUNTAIN_LOD_FACES, strict=True):
        assert abs(got - want) <= 0.05 * want
    hf = load_terrain("jacksboro", 512)
    peak = float(hf.heights.max())
    assert full.vertices[:, 2].max() == peak                     # contains the peak
    centre = 0.5 * (full.vertices[:, :2].min(axis=0) + full.vertices[:, :2].max(axis=0))
    np.testing.assert_allclose(centre, 0.0, atol=1e-3)
    assert np.all(_normals(full.vertices, full.faces)[:, 2] > 0)  # up
    for level in chain.levels[:-1]:
        nz = _normals(level.vertices, level.faces)[:, 2]
        assert np.mean(nz > 0) >= 0.99


def test_get_model(tmp_path, family):
    path = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=3).export(path)
    chain = get_model(str(path), faces=[100, 400])
    assert chain.faces == [100, 400, 1280] and chain.name == "ball"
    chain = get_model(str(path), ratios=[0.5])
    assert len(chain) == 2
    assert get_model("sphere").faces == family.faces
    with pytest.raises(MeshError, match="no such mesh file or built-in model: nope"):
        get_model("nope")
    with pytest.raises(MeshError, match="fixed levels"):
        get_model("sphere", faces=[10])
    with pytest.raises(MeshError, match="not ratios"):
        get_model("mountain", ratios=[0.5])


def test_get_model_mountain_of_fractal():
    chain = get_model("mountain:fractal:128:3", faces=[500, 1000])
    assert chain.name == "mountain:fractal:128:3"
    assert len(chain) == 3 and chain.faces[-1] > 1000
