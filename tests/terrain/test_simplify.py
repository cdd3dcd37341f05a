"""The border ribbons' Douglas-Peucker (:mod:`lodsprite.terrain.simplify`) keeps the points
scikit-image's ``approximate_polygon`` keeps, bit for bit, and its bound holds; drawing a
proxy mesh does not import ``scipy.signal``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from skimage.measure import approximate_polygon as skimage_approximate_polygon

from lodsprite.terrain.simplify import approximate_polygon


def _chains(seed: int) -> list[np.ndarray]:
    """Border-like profiles (x increasing) and arbitrary chains, some with ties."""
    rng = np.random.default_rng(seed)
    out = []
    for n in (2, 3, 5, 17, 65):
        x = np.arange(n) * 30.0
        out.append(np.stack([x, rng.normal(0, 40, n)], 1))             # a rough profile
        out.append(np.stack([x, np.round(rng.normal(0, 2, n))], 1))    # integer steps: ties
        out.append(rng.uniform(-100, 100, (n, 2)))                     # any chain
    out.append(np.stack([np.arange(9.0), np.zeros(9)], 1))             # a straight line
    out.append(np.array([[0.0, 0.0], [1.0, 5.0], [2.0, -5.0], [3.0, 5.0], [4.0, 0.0]]))
    # two points equally far: the first is kept, and within 1 of its chain the second not
    out.append(np.array([[0.0, 0.0], [1.0, 5.0], [2.0, 5.0], [3.0, 0.0]]))
    return out


def test_the_kept_points_are_scikit_images_bit_for_bit():
    for chain in _chains(0) + _chains(1):
        for tol in (0.0, 0.25, 1.0, 7.5, 30.0, 1e9):
            ours, theirs = approximate_polygon(chain, tol), skimage_approximate_polygon(chain, tol)
            assert ours.shape == theirs.shape and np.array_equal(ours, theirs), (chain, tol)


def test_every_point_left_out_lies_within_the_tolerance_of_the_kept_chain():
    rng = np.random.default_rng(5)
    x = np.arange(200) * 10.0
    chain = np.stack([x, np.cumsum(rng.normal(0, 5, 200))], 1)
    tol = 4.0
    kept = approximate_polygon(chain, tol)
    assert np.array_equal(kept[[0, -1]], chain[[0, -1]]) and 2 < len(kept) < len(chain)
    idx = np.searchsorted(chain[:, 0], kept[:, 0])
    for a, b in zip(idx[:-1], idx[1:], strict=True):  # each left-out point and its segment
        p, q = chain[a], chain[b]
        t = (chain[a + 1:b, 0] - p[0]) / (q[0] - p[0])
        line = p[1] + t * (q[1] - p[1])
        # x increases: the perpendicular distance is at most the vertical one
        assert np.all(np.abs(chain[a + 1:b, 1] - line) * abs(q[0] - p[0]) / np.hypot(
            *(q - p)) <= tol + 1e-9)


def test_a_proxy_mesh_with_its_border_ribbons_imports_no_scipy_signal():
    code = ("import sys; from lodsprite.terrain import fractal; "
            "from lodsprite.terrain.proxy import proxy_mesh; "
            "m = proxy_mesh(fractal(64, seed=1), 8, border=True); "
            "print(len(m.tris) > 2 * 8 * 8, 'scipy.signal' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["True", "False"]
