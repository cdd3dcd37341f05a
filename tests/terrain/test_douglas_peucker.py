"""The border ribbon's Douglas-Peucker simplification (:func:`lodsprite.terrain.proxy.
douglas_peucker`): the points scikit-image's ``approximate_polygon`` keeps, without the
import that cost every process drawing a proxy about a second."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import imported_by
from lodsprite.terrain.proxy import douglas_peucker


@pytest.mark.parametrize("m", [1, 2, 3, 5, 17, 65, 257])
def test_it_keeps_the_points_scikit_image_keeps(m):
    from skimage.measure import approximate_polygon

    rng = np.random.default_rng(m)
    for spacing, relief, tol in ((30.0, 200.0, 7.5), (1.0, 0.3, 0.05), (10.0, 50.0, 0.0),
                                 (30.0, 1.0, 100.0)):
        for _ in range(20):
            x = np.arange(m) * spacing
            y = np.cumsum(rng.normal(0.0, relief / 8, m)) + relief * rng.random()
            pts = np.stack([x, y], axis=1)
            kept = douglas_peucker(pts, tol)
            assert np.array_equal(pts[kept], approximate_polygon(pts, tol)), (m, tol)
            assert kept[0] == 0 and kept[-1] == m - 1 and (np.diff(kept) > 0).all()


def test_a_flat_run_keeps_its_ends_and_a_spike_keeps_its_peak():
    pts = np.stack([np.arange(9.0), np.zeros(9)], axis=1)
    assert douglas_peucker(pts, 0.1).tolist() == [0, 8]
    pts[4, 1] = 5.0
    assert douglas_peucker(pts, 0.1).tolist() == [0, 3, 4, 5, 8]
    assert douglas_peucker(pts, 6.0).tolist() == [0, 8]


def test_a_process_drawing_a_proxy_does_not_import_scipy_signal():
    """The CLI, a distributed client or server and the keyframe workers build border
    ribbons at their start: ``skimage.measure`` (and ``scipy.signal`` with it) stays out."""
    code = ("from lodsprite.terrain.proxy import proxy_mesh\n"
            "from lodsprite.terrain.generators import fractal\n"
            "mesh = proxy_mesh(fractal(64, seed=1), 16)\n"
            "assert len(mesh.tris) > 0")
    assert imported_by(code, ("scipy.signal", "skimage.measure")) == []
