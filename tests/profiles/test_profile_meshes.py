"""Tests of meshes and mesh-file loading (lodsprite.meshes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lodsprite.errors import InputError, MeshError
from lodsprite.meshes import Mesh, bounding_sphere, compact_mesh, load_mesh

FORMATS = ["obj", "ply", "off", "stl", "glb"]


@pytest.fixture(scope="module")
def ico() -> trimesh.Trimesh:
    """Icosphere of 80 faces, 42 vertices, radius 1."""
    return trimesh.creation.icosphere(subdivisions=1)


@pytest.mark.parametrize("ext", FORMATS)
def test_each_format_loads(tmp_path, ico, ext):
    path = tmp_path / f"ball.{ext}"
    ico.export(path)
    mesh = load_mesh(path)
    assert mesh.n_faces == 80
    assert mesh.n_vertices == 42                     # STL's triangle soup is merged too
    assert mesh.vertices.dtype == np.float32 and mesh.vertices.shape == (42, 3)
    assert mesh.faces.dtype == np.int32 and mesh.faces.shape == (80, 3)
    assert mesh.name == "ball"
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), 1.0, atol=1e-6)


def test_scene_with_several_geometries_concatenates(tmp_path, ico):
    box = trimesh.creation.box()
    box.apply_translation([5.0, 0.0, 0.0])
    path = tmp_path / "scene.glb"
    trimesh.Scene([ico, box]).export(path)
    mesh = load_mesh(str(path))
    assert mesh.n_faces == 80 + 12
    assert mesh.vertices[:, 0].max() == pytest.approx(5.5)


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_random_bytes_raise(tmp_path, ext):
    path = tmp_path / f"junk.{ext}"
    path.write_bytes(np.random.default_rng(1).bytes(2000))
    with pytest.raises(MeshError, match="junk"):
        load_mesh(path)


def test_empty_file_raises(tmp_path):
    path = tmp_path / "empty.obj"
    path.write_bytes(b"")
    with pytest.raises(MeshError, match="has no triangles"):
        load_mesh(path)


def test_obj_with_only_vertices_raises(tmp_path):
    path = tmp_path / "points.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(MeshError, match="points.obj has no triangles"):
        load_mesh(path)


def test_obj_with_nan_raises(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="NaN"):
        load_mesh(path)


def test_missing_file_raises(tmp_path):
    with pytest.raises(MeshError, match="no such mesh file"):
        load_mesh(tmp_path / "absent.obj")


def test_unsupported_extension_raises(tmp_path):
    path = tmp_path / "model.xyz"
    path.write_text("0 0 0\n")
    with pytest.raises(MeshError, match="unsupported mesh format .xyz"):
        load_mesh(path)


def test_directory_raises(tmp_path):
    with pytest.raises(MeshError, match="not a file"):
        load_mesh(tmp_path)


def test_messages_are_one_line(tmp_path):
    path = tmp_path / "junk.ply"
    path.write_bytes(b"ply\nformat nonsense\n\n\x00\x01")
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, InputError)


# --- Mesh ------------------------------------------------------------------------------

TRI_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TRI_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_mesh_converts_and_freezes():
    mesh = Mesh(TRI_V, TRI_F, "tet")
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
    assert (mesh.n_vertices, mesh.n_faces) == (4, 4)
    assert not mesh.vertices.flags.writeable and not mesh.faces.flags.writeable
    src = TRI_V.copy()
    m2 = Mesh(src, TRI_F)
    src[0, 0] = 9.0                                   # the mesh holds its own copy
    assert m2.vertices[0, 0] == 0.0
    assert "tet" in repr(mesh)


@pytest.mark.parametrize("vertices, faces, message", [
    (np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0]]), [[0, 1, 2]], "NaN or infinite"),
    (np.array([[0, 0, 0], [1, np.inf, 0], [0, 1, 0]]), [[0, 1, 2]], "NaN or infinite"),
    (TRI_V, [[0, 1, 4]], "out of range"),
    (TRI_V, [[0, -1, 2]], "out of range"),
    (TRI_V, np.zeros((0, 3), dtype=int), "has no triangles"),
    (TRI_V[:, :2], TRI_F, r"shape \(N, 3\)"),
    (TRI_V, TRI_F[:, :2], r"shape \(F, 3\)"),
    (TRI_V, TRI_F.astype(float), "integers"),
])
def test_mesh_validation(vertices, faces, message):
    with pytest.raises(MeshError, match=message):
        Mesh(vertices, faces, "bad")


def test_bounding_sphere_and_digest():
    box = trimesh.creation.box(extents=[2.0, 4.0, 6.0])
    box.apply_translation([1.0, 2.0, 3.0])
    mesh = Mesh(box.vertices, box.faces, "box")
    centre, radius = mesh.bounding_sphere()
    np.testing.assert_allclose(centre, [1.0, 2.0, 3.0])
    assert radius == pytest.approx(np.sqrt(1 + 4 + 9))
    assert centre.dtype == np.float64
    assert mesh.bounding_sphere()[0] is centre        # cached
    again = Mesh(box.vertices, box.faces, "other name")
    assert mesh.digest == again.digest and len(mesh.digest) == 64
    moved = Mesh(box.vertices + 1e-3, box.faces, "box")
    assert moved.digest != mesh.digest
    flipped = Mesh(box.vertices, box.faces[:, ::-1], "box")
    assert flipped.digest != mesh.digest


def test_bounding_sphere_function():
    centre, radius = bounding_sphere(np.array([[-1.0, 0, 0], [3.0, 0, 0], [0, 1.0, 0]]))
    np.testing.assert_allclose(centre, [1.0, 0.5, 0.0])
    assert radius == pytest.approx(np.hypot(2.0, 0.5))


def test_compact_mesh_merges_and_drops():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [7, 7, 7], [-0.0, 0, 0]], float)
    f = np.array([[0, 1, 2], [5, 2, 3], [0, 0, 1]])  # 5 = -0 duplicate of 0, 3 of 1
    cv, cf = compact_mesh(v, f)
    np.testing.assert_array_equal(cv, v[:3])          # order kept, unused [7,7,7] dropped
    np.testing.assert_array_equal(cf, [[0, 1, 2], [0, 2, 1]])  # degenerate face dropped
