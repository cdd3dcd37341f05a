"""Profile generation end to end on a tiny sphere family: in this process, in local worker
processes and on a local Dask cluster, which must all give the same table."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.profiles.generate import (
    ProfileSettings,
    ViewSetup,
    generate_profile,
    release_cached,
    view_camera,
)
from lodsprite.profiles.models import sphere_family

SETTINGS = ProfileSettings(image_size=64, phi_step_deg=180.0, theta_step_deg=90.0)


@pytest.fixture(scope="module")
def chain():
    return sphere_family(levels=4, max_faces=2000)


@pytest.fixture(scope="module")
def inline_table(chain):
    table = generate_profile(chain, SETTINGS, workers=1)
    release_cached()
    return table


def test_table_shape_and_metadata(inline_table, chain):
    t = inline_table
    assert t.error.shape == (4, 2, 2, len(t.z)) == t.error_csf.shape
    assert list(t.phi_deg) == [0.0, 180.0] and list(t.theta_deg) == [0.0, 90.0]
    assert list(t.faces) == chain.faces
    assert t.meta["digests"] == list(chain.digests)
    assert t.meta["image_size"] == 64 and t.meta["light"] == list(SETTINGS.light)
    # z0 is 9 bounding diameters; the view cone just holds the bounding sphere.
    assert t.z[0] == pytest.approx(9 * 2 * t.meta["radius"])
    assert np.sin(np.radians(t.fov_deg / 2)) == pytest.approx(t.meta["radius"] / t.z[0])


def test_full_model_has_zero_error_and_coarser_levels_more(inline_table):
    t = inline_table
    assert np.all(t.error[-1] == 0) and np.all(t.error_csf[-1] == 0)
    # The UV spheres nest: at the reference distance a coarser sphere is never closer.
    assert np.all(np.diff(t.error[:, :, :, 0], axis=0) <= 0)
    assert np.all(t.error[:-1] > 0)


def test_profile_view_fills_image(chain):
    setup = ViewSetup.for_sphere(*chain.full.bounding_sphere(), SETTINGS)
    vp = view_camera(setup, 30.0, 45.0)
    c = np.append(np.asarray(setup.centre), 1.0)
    clip = vp @ c
    assert np.allclose(clip[:2] / clip[3], 0.0, atol=1e-9)   # centre on the optical axis


def test_worker_processes_match_inline(inline_table, chain):
    t = generate_profile(chain, SETTINGS, workers=2)
    assert np.allclose(t.error, inline_table.error, rtol=1e-6, atol=1e-15)
    assert np.allclose(t.error_csf, inline_table.error_csf, rtol=1e-6, atol=1e-15)
    assert t.meta["workers"] == 2


def test_dask_cluster_matches_inline(inline_table, chain):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        done = []
        t = generate_profile(chain, SETTINGS, scheduler=cluster.scheduler_address,
                             progress=lambda n, total: done.append((n, total)))
    assert done[-1] == (4, 4)
    assert t.meta["workers"] == "dask"
    assert np.allclose(t.error, inline_table.error, rtol=1e-6, atol=1e-15)


def test_unreachable_scheduler_is_a_user_error(chain, monkeypatch):
    from lodsprite import cluster
    from lodsprite.errors import InputError

    monkeypatch.setattr(cluster, "DASK_CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(InputError, match="Dask scheduler"):
        generate_profile(chain, SETTINGS, scheduler="tcp://127.0.0.1:9")
