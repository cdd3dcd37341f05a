"""LOD error tables: file round trip, bad files, and run-time selection (Eq. 17)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lodsprite.profiles.select import (
    effective_distance,
    magnification,
    nearest_views,
    object_views,
    select_profile,
    select_screen_space,
)
from lodsprite.profiles.table import ProfileError, ProfileTable


def synthetic_table(levels: int = 4) -> ProfileTable:
    """Errors that fall with distance (1/z^2) and with LOD number; level L-1 is exact."""
    phi = np.arange(0.0, 360.0, 30.0)
    theta = np.arange(0.0, 91.0, 15.0)
    z = 10.0 * 1.37 ** np.arange(8)
    scale = np.array([8.0, 4.0, 1.0, 0.0])[:levels, None, None, None]
    err = scale * (10.0 / z[None, None, None, :]) ** 2 * np.ones((1, len(phi), len(theta), 1))
    meta = {"fov_deg": 6.0, "image_size": 512, "z0": 10.0, "centre": [0.0, 0.0, 0.0],
            "model": "test"}
    return ProfileTable(err, err / 10, phi, theta, z, np.array([10, 100, 1000, 10000]),
                        np.array([0.1, 0.05, 0.01, 0.0]), meta)


def translate(x: float, y: float, z: float, s: float = 1.0) -> np.ndarray:
    m = np.diag([s, s, s, 1.0])
    m[:3, 3] = (x, y, z)
    return m


def test_round_trip(tmp_path):
    t = synthetic_table()
    path = t.save(tmp_path / "t.npz")
    u = ProfileTable.load(path)
    for name in ("error", "error_csf", "phi_deg", "theta_deg", "z", "faces", "geometric_error"):
        assert np.array_equal(getattr(t, name), getattr(u, name))
    assert u.meta["model"] == "test" and u.meta["format"] == "lodsprite-lod-error-table"


@pytest.mark.parametrize("content", [b"", b"not a zip", None])
def test_bad_files_raise_profile_error(tmp_path, content):
    path = tmp_path / "bad.npz"
    if content is None:
        np.savez(path, error=np.zeros(3))        # a zip of arrays, but not a table
    else:
        path.write_bytes(content)
    with pytest.raises(ProfileError):
        ProfileTable.load(path)
    with pytest.raises(ProfileError):
        ProfileTable.load(tmp_path / "missing.npz")


def test_table_without_required_metadata_is_rejected(tmp_path):
    t = synthetic_table()
    bare = ProfileTable(t.error, t.error_csf, t.phi_deg, t.theta_deg, t.z, t.faces,
                        t.geometric_error, {"model": "test"})
    path = bare.save(tmp_path / "bare.npz")
    with pytest.raises(ProfileError, match="lacks fov_deg"):
        ProfileTable.load(path)


def test_object_views_in_object_space():
    # Eye on the object's +y axis after a 90 degree turn about z: object-space +x.
    rot = np.eye(4)
    rot[:2, :2] = [[0, -1], [1, 0]]
    model = translate(5, 0, 0) @ rot @ np.diag([2.0, 2.0, 2.0, 1.0])
    phi, theta, dist = object_views(model[None], np.array([5.0, 20.0, 0.0]), np.zeros(3))
    assert phi[0] == pytest.approx(0.0, abs=1e-9) and theta[0] == pytest.approx(0.0, abs=1e-9)
    assert dist[0] == pytest.approx(10.0)                  # 20 world units / scale 2
    _, theta, _ = object_views(np.eye(4)[None], np.array([1.0, 0.0, 1.0]), np.zeros(3))
    assert theta[0] == pytest.approx(45.0)


def test_nearest_view_wraps_azimuth():
    t = synthetic_table()
    i_phi, i_theta = nearest_views(t, np.array([359.0, 14.0, 200.0]), np.array([-30, 50, 100]))
    assert list(i_phi) == [0, 0, 7] and list(i_theta) == [0, 3, 6]


def test_selection_coarser_with_distance_and_finer_when_fov_narrows():
    t = synthetic_table()
    eye = np.zeros(3)
    models = np.stack([translate(0, d, 0) for d in (12.0, 30.0, 80.0, 200.0)])
    lod = select_profile(t, models, eye, fov_y_deg=6.0, height_px=512, threshold=0.1)
    assert np.all(np.diff(lod) <= 0)                        # farther: coarser (lower index)
    assert lod[0] > lod[-1]
    # A narrower field of view magnifies: the same objects need finer LODs.
    tele = select_profile(t, models, eye, fov_y_deg=1.0, height_px=512, threshold=0.1)
    assert np.all(tele >= lod) and np.any(tele > lod)
    # Closer than the reference distance: the full model.
    near = select_profile(t, translate(0, 5, 0)[None], eye, 6.0, 512, threshold=1e9)
    assert near[0] == t.levels - 1


def test_effective_distance_fov_and_pixels():
    t = synthetic_table()
    assert magnification(6.0, 6.0) == pytest.approx(1.0)
    m = math.tan(math.radians(15)) / math.tan(math.radians(3))
    assert effective_distance(t, 10.0, 30.0, 512) == pytest.approx(10.0 * m)
    assert effective_distance(t, 10.0, 6.0, 1024) == pytest.approx(5.0)


def test_csf_table_used_on_request():
    t = synthetic_table()
    models = translate(0, 20, 0)[None]
    plain = select_profile(t, models, np.zeros(3), 6.0, 512, threshold=1.0, csf=False)
    weighted = select_profile(t, models, np.zeros(3), 6.0, 512, threshold=1.0, csf=True)
    # z_eff = 20 rounds down to z = 18.77: plain errors 2.27, 1.14, 0.28; CSF ones a tenth.
    assert (plain[0], weighted[0]) == (2, 0)


def test_screen_space_selection():
    geo = np.array([0.1, 0.05, 0.01, 0.0])
    models = np.stack([translate(0, d, 0) for d in (2.0, 10.0, 1000.0)])
    lod = select_screen_space(geo, models, np.zeros(3), np.zeros(3), 45.0, 512, 1.0)
    # 618 px per unit at distance 1: 0.01 units at 2 -> 3.1 px (full), at 10 -> 0.62 px.
    assert list(lod) == [3, 2, 0]
