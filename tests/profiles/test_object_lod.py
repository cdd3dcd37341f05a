"""Profile LOD of a scene's object types (lod = "profile", Scoggins et al. 2000 Eq. 17):
the cache beside the mesh, its validation, and the per-instance selection."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
import trimesh

from lodsprite.camera import look_at
from lodsprite.gl.target import RenderTarget
from lodsprite.profiles import object_lod as pl
from lodsprite.profiles.generate import ProfileSettings
from lodsprite.profiles.select import object_views, select_profile
from lodsprite.profiles.table import ProfileTable
from lodsprite.scene.objects import ObjectType

#: Tiny settings: 32² images, 2 x 2 views (the scene's are 128², 4 x 3).
TINY = ProfileSettings(image_size=32, phi_step_deg=180.0, theta_step_deg=90.0, samples=1)
FACTORS = (0.0, 0.5, 1.0)


def sphere_type(folder, name="ball.obj") -> ObjectType:
    mesh = trimesh.creation.icosphere(2, radius=1.0)
    path = folder / name
    mesh.export(path)
    v = (mesh.vertices + [0, 0, 1]).astype(np.float32)
    return ObjectType(name, v, mesh.faces.astype(np.int32),
                      np.full((len(v), 3), 0.5, np.float32), 2.0, "profile", path)


def profile(t: ObjectType) -> pl.TypeProfile:
    return pl.type_profile(t, settings=TINY, factors=FACTORS)


@pytest.fixture
def counts(monkeypatch):
    """Fresh counters of profile work (built / loaded / rebuilt)."""
    monkeypatch.setattr(pl, "stats", {"built": 0, "loaded": 0, "rebuilt": 0})
    return pl.stats


def test_the_cache_is_written_beside_the_mesh_and_reused(gl, tmp_path, counts):
    t = sphere_type(tmp_path)
    first = profile(t)
    assert counts == {"built": 1, "loaded": 0, "rebuilt": 0}
    assert first.path.parent == tmp_path and first.path.name.startswith("ball.obj.")
    assert first.path.name.endswith(pl.SUFFIX) and first.path.is_file()
    assert list(first.factors) == list(FACTORS) and first.table.levels == 3
    again = profile(sphere_type(tmp_path))            # a new type of the same file
    assert counts == {"built": 1, "loaded": 1, "rebuilt": 0}   # no generation the second time
    assert again.path == first.path
    assert np.array_equal(again.table.error_csf, first.table.error_csf)
    # The caller's context stays current through the in-process generation.
    target = RenderTarget(gl, 8, 8)
    try:
        target.use((0.0, 1.0, 0.0))
        assert (target.read_color()[..., 1] == 255).all()
    finally:
        target.release()


def test_a_changed_mesh_or_setting_gets_its_own_profile(gl, tmp_path, counts):
    t = sphere_type(tmp_path)
    a = profile(t)
    t.vertices = t.vertices * np.float32(2.0)
    b = profile(t)
    assert a.path != b.path and counts["built"] == 2
    key = pl.cache_key(t, None, TINY, FACTORS)
    assert key != pl.cache_key(t, None, ProfileSettings(image_size=64, phi_step_deg=180.0,
                                                        theta_step_deg=90.0), FACTORS)


def test_a_corrupt_cache_is_rebuilt(gl, tmp_path, counts):
    t = sphere_type(tmp_path)
    path = profile(t).path
    path.write_bytes(b"PK\x03\x04 not a table")
    p = profile(t)
    assert counts == {"built": 2, "loaded": 0, "rebuilt": 1}
    assert p.path == path and pl.read_cached(path, pl.cache_key(t, None, TINY, FACTORS),
                                             TINY, FACTORS) is not None


def _rewrite(path, **changes):
    """The cached npz with some members replaced (arrays, or meta as a dict)."""
    with np.load(path, allow_pickle=False) as d:
        members = {k: d[k] for k in d.files}
    for k, v in changes.items():
        members[k] = np.array(json.dumps(v)) if k == "meta" else v
    with open(path, "wb") as f:
        np.savez(f, **members)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """One tiny profile built and cached (shared by the hostile-cache cases)."""
    t = sphere_type(tmp_path_factory.mktemp("built"))
    return t, profile(t)


@pytest.mark.parametrize("hostile", ["wrong key", "string errors", "float faces",
                                     "negative error", "extra member", "oversized",
                                     "declared huge", "nested meta", "text fov"])
def test_a_hostile_cache_is_refused(tmp_path, built, hostile):
    t, p = built
    key = pl.cache_key(t, None, TINY, FACTORS)
    path = tmp_path / p.path.name
    path.write_bytes(p.path.read_bytes())
    assert pl.read_cached(path, key, TINY, FACTORS) is not None
    table = p.table
    if hostile == "wrong key":
        _rewrite(path, meta={**table.meta, "format": "lodsprite-lod-error-table",
                               "version": 1, "lodprofile_key": "0" * 64})
    elif hostile == "string errors":
        _rewrite(path, error=np.full(table.error.shape, "1e-3"))
    elif hostile == "float faces":
        _rewrite(path, faces=table.faces.astype(np.float64))
    elif hostile == "negative error":
        _rewrite(path, error_csf=-table.error_csf - 1.0)
    elif hostile == "nested meta":
        with np.load(path, allow_pickle=False) as d:
            members = {k: d[k] for k in d.files}
        members["meta"] = np.array("[" * 100_000 + "]" * 100_000)
        with open(path, "wb") as f:
            np.savez(f, **members)
    elif hostile == "text fov":
        _rewrite(path, meta={**table.meta, "fov_deg": "wide"})
    elif hostile == "extra member":
        _rewrite(path, payload=np.zeros(4))
    elif hostile == "oversized":
        with open(path, "ab") as f:
            f.truncate(pl.MAX_FILE_BYTES + 1)
    else:  # a member that says it unpacks to more than the cap
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for name in (*pl.ARRAYS, "meta"):
                z.writestr(f"{name}.npy", b"\0" * (pl.MAX_UNPACKED_BYTES // 7 + 1))
    assert pl.read_cached(path, key, TINY, FACTORS) is None


def test_a_builtin_is_cached_in_the_user_cache_folder(tmp_path, monkeypatch):
    monkeypatch.setenv(pl.CACHE_ENV, str(tmp_path / "cache"))
    t = ObjectType("ogre", np.zeros((3, 3), np.float32), np.zeros((1, 3), np.int32),
                   np.zeros((3, 3), np.float32), 1.0, "profile", None)
    assert pl.user_cache_dir() == tmp_path / "cache"
    assert pl.cache_path(t, "ab" * 32).parent == tmp_path / "cache"
    monkeypatch.delenv(pl.CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert pl.user_cache_dir() == tmp_path / "xdg" / "lodsprite"


# --- selection on a hand-made table ------------------------------------------------------

def hand_profile() -> pl.TypeProfile:
    """Three LODs, two azimuths (0, 180), one elevation, distances 10, 20, 40; LOD 0's
    error falls with distance, LOD 1's is small; view 180 is twice as bad."""
    e = np.zeros((3, 2, 1, 3))
    e[0, 0, 0] = [0.4, 0.2, 0.05]
    e[1, 0, 0] = [0.1, 0.04, 0.01]
    e[:, 1] = 2 * e[:, 0]
    meta = {"fov_deg": 10.0, "image_size": 100, "z0": 10.0, "centre": [0.0, 0.0, 1.0]}
    table = ProfileTable(e, e, [0.0, 180.0], [0.0], [10.0, 20.0, 40.0], [10, 20, 40],
                         [np.nan] * 3, meta)
    return pl.TypeProfile(table, np.array([0.0, 0.4, 1.0]))


def test_selection_is_coarser_farther_away_and_matches_select_py():
    p = hand_profile()
    d = np.array([5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 80.0])  # eye distance along +x
    positions = np.stack([-d, np.zeros_like(d), np.zeros_like(d)], axis=1)
    eye = np.array([0.0, 0.0, 1.0])
    # height 100 px at the profile's own field of view: z_eff = the distance (Eq. 17)
    f = pl.lod_factors(p, eye, positions, 10.0, 100, threshold=0.1)
    # < z0: full; 10..<40: LOD 1 (0.1, 0.04 <= 0.1, LOD 0's 0.4, 0.2 not); >= 40: LOD 0
    assert list(f) == [1.0, 0.4, 0.4, 0.4, 0.4, 0.0, 0.0]
    assert np.all(np.diff(f) <= 0)
    yaw = np.linspace(0, 6, len(d))
    models = pl.instance_models(np.c_[positions, yaw])
    want = select_profile(p.table, models, eye, 10.0, 100, 0.1)
    assert np.array_equal(pl.lod_factors(p, eye, np.c_[positions, yaw], 10.0, 100, 0.1),
                          p.factors[want])
    # Turned half round, the object shows its worse side: finer at the same distance.
    turned = pl.lod_factors(p, eye, np.c_[positions, np.full(len(d), np.pi)], 10.0, 100, 0.1)
    assert np.all(turned >= f) and np.any(turned > f)


def test_the_manager_hook_is_vectorised_over_objects_and_keeps_linear_types():
    p = hand_profile()
    n = 500
    rng = np.random.default_rng(3)
    types = rng.integers(0, 2, n)                         # type 1 profile, 0 linear
    transforms = np.c_[rng.uniform(-60, 0, (n, 2)), np.zeros(n), rng.uniform(0, 6, n)]
    desired = rng.uniform(0, 1, n)
    hook = pl.ProfileLod({1: p}, types, 10.0, 100, threshold=0.1)
    vp = look_at((0.0, 0.0, 1.0), (-10.0, -10.0, 1.0))
    out = hook(vp, transforms, desired, exponent=1.0)
    assert out.shape == (n,) and np.array_equal(out[types == 0], desired[types == 0])
    assert np.array_equal(out[types == 1], pl.lod_factors(p, vp.o, transforms[types == 1],
                                                          10.0, 100, 0.1))
    assert set(np.unique(out[types == 1])) <= {0.0, 0.4, 1.0}
    assert np.all(hook(vp, transforms, desired, exponent=0.0)[types == 1] == 1.0)
    coarser = hook(vp, transforms, desired, exponent=4.0)[types == 1]
    assert np.all(coarser <= out[types == 1]) and np.any(coarser < out[types == 1])


def test_the_layer_hook_covers_the_profile_types_only(gl, tmp_path, counts):
    a, b = sphere_type(tmp_path, "a.obj"), sphere_type(tmp_path, "b.obj")
    b.lod = "linear"
    assert pl.profile_hook([b], [None], np.zeros(3, int), 60.0, 100) is None
    hook = pl.profile_hook([b, a], [None, None], np.array([0, 1, 1, 0]), 60.0, 100,
                           settings=TINY, factors=FACTORS)
    assert set(hook.profiles) == {1} and counts["built"] == 1
    assert list(hook.members[1]) == [1, 2]


def test_a_gltf_part_is_cached_beside_its_file_by_part_name(tmp_path):
    t = ObjectType("town.glb:house 1", np.zeros((3, 3), np.float32),
                   np.zeros((1, 3), np.int32), np.zeros((3, 3), np.float32), 1.0, "profile",
                   tmp_path / "town.glb")
    assert pl.cache_path(t, "cd" * 32) == tmp_path / f"town.glb.house_1.{'cd' * 8}{pl.SUFFIX}"


def test_instance_views_equal_select_py_object_views():
    rng = np.random.default_rng(5)
    poses = np.c_[rng.uniform(-50, 50, (200, 3)), rng.uniform(-7, 7, 200)]
    eye, centre = np.array([3.0, -20.0, 8.0]), np.array([0.1, -0.2, 1.1])
    got = pl.instance_views(poses, eye, centre)
    want = object_views(pl.instance_models(poses), eye, centre)
    for g, w in zip(got, want, strict=True):
        assert np.allclose(g, w, atol=1e-9)


def test_an_unwritable_mesh_folder_caches_in_the_user_folder(gl, tmp_path, counts,
                                                              monkeypatch):
    t = sphere_type(tmp_path)
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    t.source = blocker / "ball.obj"                     # its folder cannot be made
    monkeypatch.setenv(pl.CACHE_ENV, str(tmp_path / "user"))
    first = profile(t)
    assert first.path.parent == tmp_path / "user" and counts["built"] == 1
    assert profile(t).path == first.path and counts == {"built": 1, "loaded": 1,
                                                        "rebuilt": 0}
    monkeypatch.setenv(pl.CACHE_ENV, str(blocker))      # nowhere to write: used uncached
    t.vertices = t.vertices * np.float32(1.5)
    assert profile(t).path is None and counts["built"] == 2


def test_the_profile_memo_keeps_no_type_alive(tmp_path, monkeypatch):
    # review finding 10: _MEMO held every ObjectType (and its profile) forever
    import gc

    built = []
    monkeypatch.setattr(pl, "type_profile", lambda t, model=None: built.append(t.name) or
                        pl.TypeProfile(None, np.zeros(0), None))
    before = len(pl._MEMO)
    t = sphere_type(tmp_path)
    first = pl.profile_of(t)
    assert pl.profile_of(t) is first and built == ["ball.obj"]   # memoised while it lives
    del t
    gc.collect()
    assert len(pl._MEMO) == before
