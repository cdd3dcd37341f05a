"""A scene file's world (issue 23, must-have 1): types normalised (z up, base at 0,
centred, scaled), glTF groups as types and instances at their nodes, seeded scatter inside
the terrain, instances on the ground of a tilted plane, walkers inside at their speed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lodsprite.errors import SceneFileError
from lodsprite.scene import placement
from lodsprite.scene.walk import walk
from lodsprite.scene.world import World, load_scene_file, summary

SLOPE = (0.05, -0.02)          # the tilted plane's dz/dx, dz/dy
SPACING_M = 30.0               # a .npy terrain's spacing (lodsprite.terrain.loaders)
N = 32                         # quads a side: 960 m x 960 m, x and y in -480..480


def plane_terrain(folder: Path) -> Path:
    """``z = a x + b y + 100`` on a (N+1)² grid, as a .npy terrain: bilinear is exact."""
    r, c = np.mgrid[0:N + 1, 0:N + 1].astype(np.float64)
    x, y = c * SPACING_M - N * SPACING_M / 2, N * SPACING_M / 2 - r * SPACING_M
    p = folder / "plane.npy"
    np.save(p, (SLOPE[0] * x + SLOPE[1] * y + 100.0).astype(np.float32))
    return p


def world_of(folder: Path, body: str) -> World:
    """The world of ``body`` over the plane; ``cube.off``, a 1 m cube, beside it."""
    import trimesh

    plane_terrain(folder)
    trimesh.creation.box((1.0, 1.0, 1.0)).export(folder / "cube.off")
    scene = folder / "scene.toml"
    scene.write_text(f'[terrain]\nsource = "plane.npy"\ngrid = {N}\n' + body)
    return load_scene_file(scene, textured=False).objects


def plane_z(xy: np.ndarray) -> np.ndarray:
    return SLOPE[0] * xy[:, 0] + SLOPE[1] * xy[:, 1] + 100.0


@pytest.fixture
def box_obj(tmp_path: Path) -> Path:
    import trimesh

    p = tmp_path / "box.obj"
    box = trimesh.creation.box((2.0, 1.0, 4.0))
    box.apply_translation([10.0, -3.0, 7.0])        # off centre and lifted: normalised away
    box.export(p)
    return p


def test_a_mesh_file_is_normalised_and_scaled(tmp_path: Path, box_obj: Path) -> None:
    w = world_of(tmp_path, '[[objects]]\nmesh = "box.obj"\nheight_m = 8.0\ncount = 4\n')
    (t,) = w.types
    lo, hi = t.vertices.min(0), t.vertices.max(0)
    np.testing.assert_allclose(lo, [-2.0, -1.0, 0.0], atol=1e-5)   # x2: 4 m -> 8 m tall
    np.testing.assert_allclose(hi, [2.0, 1.0, 8.0], atol=1e-5)
    assert t.vertices.dtype == np.float32 and t.faces.dtype == np.int32
    assert t.colours.shape == t.vertices.shape and t.source == box_obj
    assert t.height_m == pytest.approx(8.0) and t.lod == "linear"
    y_up = world_of(tmp_path, '[[objects]]\nmesh = "box.obj"\nheight_m = 8.0\nup = "y"\n')
    v = y_up.types[0].vertices                        # (x, y, z) -> (x, -z, y): 1 m -> 8 m
    np.testing.assert_allclose(v.min(0), [-8.0, -16.0, 0.0], atol=1e-4)
    np.testing.assert_allclose(v.max(0), [8.0, 16.0, 8.0], atol=1e-4)


def test_the_built_in_ogre_stands_on_its_base(tmp_path: Path) -> None:
    w = world_of(tmp_path, '[[objects]]\nmesh = "ogre"\nheight_m = 1.8\ncount = 2\n'
                 'lod = "profile"\n')
    (t,) = w.types
    assert t.source is None and t.name == "ogre" and t.lod == "profile"
    assert t.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert t.vertices[:, 2].max() == pytest.approx(1.8, rel=1e-5)
    assert t.model is not None and float(np.max(t.model.vertices[:, 2])) == pytest.approx(1.8)
    assert len(t.faces) > 1000


def test_a_gltf_group_gives_a_type_per_mesh_and_instances_at_its_nodes(tmp_path: Path) -> None:
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    scene = trimesh.Scene()                      # glTF is +y up: (x, y, z) -> (x, -z, y)
    scene.add_geometry(trimesh.creation.box((1.0, 2.0, 1.0)), node_name="hut",
                       geom_name="hut", transform=translation_matrix([5.0, 0.0, 3.0]))
    turn = translation_matrix([-4.0, 0.0, -6.0]) @ rotation_matrix(np.pi / 2, [0, 1, 0])
    scene.add_geometry(trimesh.creation.box((4.0, 6.0, 1.0)), node_name="tower",
                       geom_name="tower", transform=turn)
    scene.graph.update(frame_to="hut2", frame_from=scene.graph.base_frame, geometry="hut",
                       matrix=translation_matrix([0.0, 0.0, 10.0]))  # the hut again
    scene.export(tmp_path / "camp.glb")
    (tmp_path / "at.csv").write_text("100,50,0\n")             # heading 0: as laid out
    w = world_of(tmp_path, '[[objects]]\nmesh = "camp.glb"\npoints = "at.csv"\n')
    names = [t.name for t in w.types]
    assert names == ["camp.glb:hut", "camp.glb:tower"]
    hut, tower = w.types
    assert hut.height_m == pytest.approx(2.0) and tower.height_m == pytest.approx(6.0)
    by_type = {i.type_index: i for i in w.instances}
    # hut at glTF (5, 0, 3) -> world offset (5, -3); tower at (-4, 0, -6) -> (-4, 6)
    np.testing.assert_allclose(by_type[0].xy, [[105.0, 47.0], [100.0, 40.0]], atol=1e-9)
    np.testing.assert_allclose(by_type[1].xy, [[96.0, 56.0]], atol=1e-9)
    # the tower's node turns +90° about glTF +y (up), i.e. +90° about world +z (up)
    assert by_type[0].yaw[0] == pytest.approx(0.0, abs=1e-9)
    assert by_type[1].yaw[0] == pytest.approx(np.pi / 2, abs=1e-9)
    (tmp_path / "at.csv").write_text("100,50,90\n")            # the group turned by 90°
    turned = world_of(tmp_path, '[[objects]]\nmesh = "camp.glb"\npoints = "at.csv"\n')
    np.testing.assert_allclose(turned.instances[0].xy, [[103.0, 55.0], [110.0, 50.0]],
                               atol=1e-9)
    assert abs(turned.instances[1].yaw[0]) == pytest.approx(np.pi, abs=1e-9)
    # scaled as a whole: the tallest type to height_m, the offsets with it
    scaled = world_of(tmp_path, '[[objects]]\nmesh = "camp.glb"\nheight_m = 3.0\n')
    assert [t.height_m for t in scaled.types] == pytest.approx([1.0, 3.0])
    offsets = np.concatenate([i.xy for i in scaled.instances])
    np.testing.assert_allclose(offsets, [[2.5, -1.5], [0.0, -5.0], [-2.0, 3.0]], atol=1e-9)


def camp_glb(folder: Path) -> Path:
    """A glTF of three nodes, each a box of 12 triangles, 10 m apart."""
    import trimesh
    from trimesh.transformations import translation_matrix

    scene = trimesh.Scene()
    for k in range(3):
        scene.add_geometry(trimesh.creation.box((1.0, 2.0, 1.0)), node_name=f"n{k}",
                           geom_name=f"g{k}", transform=translation_matrix([10.0 * k, 0, 0]))
    scene.export(folder / "camp.glb")
    return folder / "camp.glb"


def test_a_group_over_the_instance_cap_is_refused_before_it_is_scattered(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # review finding 6: nodes x anchors checked before scatter/expand allocate them
    from lodsprite.scene import world as world_module

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("allocated before the cap was checked")

    camp_glb(tmp_path)
    monkeypatch.setattr(world_module, "expand", never)
    monkeypatch.setattr(world_module, "scatter", never)
    with pytest.raises(SceneFileError, match="more than 200000 instances in all"):
        world_of(tmp_path, '[[objects]]\nmesh = "camp.glb"\ncount = 70000\n')


def test_gltf_nodes_and_faces_are_capped_while_reading(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # review finding 6: a node cap, and the faces cap checked node by node (before copies)
    from lodsprite.scene import file as scene_file
    from lodsprite.scene import objects

    camp_glb(tmp_path)
    body = '[[objects]]\nmesh = "camp.glb"\n'
    monkeypatch.setattr(scene_file, "MAX_GLTF_NODES", 2)
    with pytest.raises(SceneFileError, match="objects.0..mesh: camp.glb has 3 mesh nodes, "
                                             "over 2"):
        world_of(tmp_path, body)
    monkeypatch.setattr(scene_file, "MAX_GLTF_NODES", 10)
    monkeypatch.setattr(scene_file, "MAX_MESH_FACES", 20)
    copied = []
    colours = objects._colours
    monkeypatch.setattr(objects, "_colours", lambda tm, n: copied.append(n) or colours(tm, n))
    with pytest.raises(SceneFileError, match="over 20 triangles"):
        world_of(tmp_path, body)
    assert len(copied) == 1                       # the second node's 12 faces: refused


def test_each_mesh_is_read_and_each_section_scattered_once(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # review finding 15: a mesh file was loaded twice, a group's scatter drawn twice
    import trimesh

    from lodsprite.scene import world as world_module

    camp_glb(tmp_path)
    loads, scatters = [], []
    load, scatter = trimesh.load, world_module.scatter
    monkeypatch.setattr(trimesh, "load", lambda *a, **k: loads.append(a[0]) or load(*a, **k))
    monkeypatch.setattr(world_module, "scatter",
                        lambda *a, **k: scatters.append(a[0]) or scatter(*a, **k))
    w = world_of(tmp_path, '[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 5\n'
                           '[[objects]]\nmesh = "camp.glb"\ncount = 4\n')
    assert sorted(Path(p).name for p in loads) == ["camp.glb", "cube.off"]
    assert scatters == [5, 4]
    assert [len(i) for i in w.instances] == [5, 4, 4, 4]
    lo, hi = w.extent
    xy = np.concatenate([i.xy for i in w.instances])
    assert ((xy >= lo) & (xy <= hi)).all()


def test_scatter_stays_inside_and_repeats_by_seed(tmp_path: Path) -> None:
    body = '[[objects]]\nmesh = "cube.off"\nheight_m = 3.0\ncount = 500\nseed = {}\n'
    a, b, c = (world_of(tmp_path, body.format(s)) for s in (7, 7, 8))
    lo, hi = a.extent
    np.testing.assert_allclose(lo, [-480.0, -480.0])
    xy = a.instances[0].xy
    assert xy.shape == (500, 2) and ((xy >= lo) & (xy <= hi)).all()
    assert xy.std(axis=0).min() > 0.4 * 960 / np.sqrt(12)      # spread over the extent
    np.testing.assert_array_equal(xy, b.instances[0].xy)
    np.testing.assert_array_equal(a.instances[0].yaw, b.instances[0].yaw)
    assert not np.allclose(xy, c.instances[0].xy)


def test_instances_stand_on_the_ground(tmp_path: Path) -> None:
    (tmp_path / "p.csv").write_text("0,0\n-480,480\n479.9,-123.4\n17.3,-200.1\n")
    w = world_of(tmp_path, '[[objects]]\nmesh = "cube.off"\nheight_m = 3.0\ncount = 200\n'
                 '[[objects]]\nmesh = "cube.off"\nheight_m = 3.0\npoints = "p.csv"\n'
                 'walk_mps = 2.0\n')
    for t in (0.0, 3.7, 250.0):
        poses = w.poses(t)
        assert poses.shape == (204, 4) and poses.dtype == np.float32
        np.testing.assert_allclose(poses[:, 2], plane_z(poses[:, :2].astype(np.float64)),
                                   atol=1e-3)
    np.testing.assert_allclose(w.poses(0.0)[200:, :2], [[0, 0], [-480, 480], [479.9, -123.4],
                                                        [17.3, -200.1]], atol=1e-4)
    assert list(w.moving()) == [False] * 200 + [True] * 4
    assert len(w.types) == 1                        # one mesh, one height: one shared type
    assert list(w.type_indices()) == [0] * 204
    assert [i.walk_mps for i in w.instances] == [0.0, 2.0]
    np.testing.assert_array_equal(w.poses(0.0)[:200], w.poses(99.0)[:200])   # static


def test_walkers_stay_inside_and_keep_their_speed(tmp_path: Path) -> None:
    w = world_of(tmp_path, '[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 3000\n'
                 'walk_mps = 1.5\nseed = 3\n')
    lo, hi = w.extent
    dt = 0.5
    checked = 0
    for t in (0.0, 40.0, 333.0, 1000.0):
        a, b = w.poses(t).astype(np.float64), w.poses(t + dt).astype(np.float64)
        assert ((b[:, :2] >= lo - 1e-3) & (b[:, :2] <= hi + 1e-3)).all()
        straight = np.abs(np.angle(np.exp(1j * (b[:, 3] - a[:, 3])))) < 1e-6  # no bounce
        assert straight.mean() > 0.95
        speed = np.linalg.norm(b[straight, :2] - a[straight, :2], axis=1) / dt
        np.testing.assert_allclose(speed, 1.5, rtol=0.01)
        heading = np.arctan2(b[straight, 1] - a[straight, 1], b[straight, 0] - a[straight, 0])
        np.testing.assert_allclose(np.angle(np.exp(1j * (heading - a[straight, 3]))), 0.0,
                                   atol=1e-2)
        checked += int(straight.sum())
    assert checked > 11_000
    assert np.abs(w.poses(2000.0)[:, :2] - w.poses(0.0)[:, :2]).max() > 100.0   # they went


def test_an_area_holds_its_scatter_and_its_walkers(tmp_path: Path) -> None:
    body = ('[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 400\nwalk_mps = 3.0\n'
            'area = [-100.0, 0.0, 50.0, 300.0]\n'
            '[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 100\nwalk_mps = 3.0\n')
    w = world_of(tmp_path, body)
    lo, hi = np.array([-100.0, 0.0]), np.array([50.0, 300.0])
    for t in (0.0, 77.0, 500.0):
        xy = w.poses(t)[:400, :2]
        assert ((xy >= lo - 1e-3) & (xy <= hi + 1e-3)).all()
    assert (np.abs(w.poses(500.0)[400:, :2]) > 300.0).any()      # the others roam the terrain
    (tmp_path / "p.csv").write_text("0,10\n60,10\n")
    points = body.replace("count = 400", 'points = "p.csv"')
    with pytest.raises(SceneFileError, match=r"objects\[0\]\.points: line 2: \(60, 10\) is "
                                             "outside its area"):
        world_of(tmp_path, points)
    bad = body.replace("300.0]", "600.0]")
    with pytest.raises(SceneFileError, match=r"objects\[0\]\.area: \(50, 600\) is outside"):
        world_of(tmp_path, bad)


def test_a_walker_turns_back_at_the_edge() -> None:
    lo, hi = np.array([-10.0, -10.0]), np.array([10.0, 10.0])
    xy, yaw = walk(np.array([[9.0, 0.0]]), np.array([0.0]), np.array([1.0]), 3.0, lo, hi)
    np.testing.assert_allclose(xy, [[8.0, 0.0]])       # 1 m to the edge, 2 m back
    assert abs(yaw[0]) == pytest.approx(np.pi)
    xy, _ = walk(np.array([[9.0, 0.0]]), np.array([0.0]), np.array([1.0]), 3.0 + 40.0, lo, hi)
    np.testing.assert_allclose(xy, [[8.0, 0.0]], atol=1e-9)  # one period of 2 x 20 m later


def test_poses_are_one_vectorised_pass(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    w = world_of(tmp_path, '[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 2000\n'
                 'walk_mps = 1.0\n[[objects]]\nmesh = "cube.off"\nheight_m = 2.0\ncount = 1000\n')
    calls = []
    real = placement.ground
    monkeypatch.setattr("lodsprite.scene.world.ground",
                        lambda hf, xy: calls.append(len(xy)) or real(hf, xy))
    poses = w.poses(12.5)
    assert calls == [3000] and poses.shape == (3000, 4)
    lo, hi = w.extent
    one = w.instances[0]
    xy, yaw = walk(one.xy[5:6], one.yaw[5:6], np.array([1.0]), 12.5, lo, hi)
    np.testing.assert_allclose(poses[5, :2], xy[0], atol=1e-3)
    np.testing.assert_allclose(poses[5, 3], yaw[0], atol=1e-6)


def test_the_example_battlefield_loads() -> None:
    example = Path(__file__).resolve().parents[2] / "examples" / "battlefield.toml"
    w = load_scene_file(example, textured=False).objects
    assert [t.name for t in w.types] == ["ogre", "tree"]
    assert w.count == 3100 and int(w.moving().sum()) == 3000
    xy = w.poses(60.0)[:3000, :2]
    assert (np.abs(xy) <= 400.0 + 1e-3).all()                  # the crowd keeps its area


def test_light_fields_stand_where_the_file_puts_them(tmp_path: Path) -> None:
    for name in ("statue.lf", "tree.lf"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "lumigraph.json").write_text("{}")
    body = "".join(f'[[lightfields]]\nsource = "{n}"\nposition = [{x}, -30.0]\nheight_m = 30\n'
                   for n, x in (("statue.lf", 120.0), ("tree.lf", -400.0)))
    plane_terrain(tmp_path)
    (tmp_path / "scene.toml").write_text(f'[terrain]\nsource = "plane.npy"\ngrid = {N}\n' + body)
    scene = load_scene_file(tmp_path / "scene.toml", textured=False)
    assert [(lf.source, lf.position, lf.height_m) for lf in scene.lightfields] == [
        (tmp_path / "statue.lf", (120.0, -30.0), 30.0), (tmp_path / "tree.lf", (-400.0, -30.0),
                                                         30.0)]
    assert summary(scene)[2] == ("lightfields: 2 (statue.lf at (120, -30), 30 m; tree.lf at "
                              "(-400, -30), 30 m)")


def test_lod_floor_sets_the_coarsest_lod_of_built_ins_and_meshes(tmp_path):
    """``lod_floor``: the fraction of a type's triangles its coarsest LOD keeps, for a
    built-in and for a mesh file (the objects layer's progressive mesh)."""
    import trimesh

    from lodsprite.layered.objects import world_crowd

    box = trimesh.creation.box((1.0, 1.0, 1.0))
    for _ in range(4):
        box = box.subdivide()
    box.export(tmp_path / "cube.off")
    body = ('[terrain]\nsource = "fractal:64"\n'
            '[[objects]]\nmesh = "ogre"\ncount = 2\nlod_floor = 0.02\n'
            '[[objects]]\nmesh = "cube.off"\nheight_m = 3.0\ncount = 2\nlod_floor = 0.05\n'
            '[[objects]]\nmesh = "tree"\ncount = 2\n')
    (tmp_path / "scene.toml").write_text(body)
    crowd = world_crowd(load_scene_file(tmp_path / "scene.toml").objects)
    floors = [m.triangles(0.0) / m.triangles(1.0) for m in crowd.models]
    assert floors[0] == pytest.approx(0.02, abs=0.005)
    assert floors[1] == pytest.approx(0.05, abs=0.01)
    assert len(floors) == 3
    assert floors[2] == pytest.approx(0.1, abs=0.02)        # the default, the paper's
