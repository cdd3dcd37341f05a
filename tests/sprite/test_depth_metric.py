"""The error estimate on the keyframe's own depth: closed-form ``C'`` against a ray cast on
the mesh's triangles, zero warp held still and turning, the phase term's analytic values,
parallax growing with the move and the uncovered share."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lodsprite.camera import Projection, look_at, widened
from lodsprite.sprite.depth_metric import DepthEstimate, grid_axis, key_rays

SIZE = 64       # display pixels a side
GUARD = 8       # guard band, display pixels
EYE = np.array([0.0, -300.0, 200.0])
FOV = 45.0


def key_setup(scale: float):
    key = look_at(EYE, (0.0, 0.0, 0.0))
    proj = widened(Projection(FOV, 1.0, 10.0, 5000.0), SIZE, SIZE, GUARD)
    n = int(round((SIZE + 2 * GUARD) * scale))
    return key, proj, n


def window_depth(d: np.ndarray, proj: Projection) -> np.ndarray:
    """Window depth of eye depths ``d`` (metres) through ``proj``."""
    n, f = proj.near, proj.far
    ndc = (f + n - 2.0 * n * f / d) / (f - n)
    return ((ndc + 1.0) / 2.0).astype(np.float32)


def plane_depth(key, proj, n: int, bumps: float = 0.0) -> np.ndarray:
    """The keyframe z-buffer ``(n, n)`` (row 0 at the top) of the ground plane z = 0 seen
    from ``key``, its eye depths rippled by ``bumps`` (relative) when asked."""
    py, px = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    r = key_rays(px.ravel().astype(float), py.ravel().astype(float), (n, n), key, proj)
    d = (-key.o[2] / r[:, 2]).reshape(n, n)  # GL rows, bottom up
    if bumps:
        d = d * (1.0 + bumps * np.sin(px * 1.3) * np.cos(py * 0.7))
    return window_depth(d, proj)[::-1]


def error(est: DepthEstimate, vp, proj=None) -> float:
    proj = proj or Projection(FOV, 1.0, 10.0, 5000.0)
    return est.error_px(vp.o, proj.matrix() @ vp.view_matrix(), proj.pixel_angle_rad(SIZE),
                        (SIZE, SIZE))


def test_c_prime_is_where_the_keyframe_ray_meets_the_mesh_triangle():
    """The blend of inverse depths equals a ray-plane intersection with the triangle the
    sample lies in (its three vertices unprojected from the same z-buffer)."""
    key, proj, n = key_setup(1.0)
    depth = plane_depth(key, proj, n, bumps=0.05)
    stride = 4
    est = DepthEstimate(depth, key, proj, stride, 1.0)
    gl = depth[::-1].astype(np.float64)
    xs = grid_axis(n, stride)
    ys = grid_axis(n, stride)
    nn, ff = proj.near, proj.far

    def point(x, y):
        z = gl[y, x]
        d = 2 * nn * ff / (ff + nn - (2 * z - 1) * (ff - nn))
        return key.o + key_rays(np.array([x], float), np.array([y], float), (n, n), key,
                                proj)[0] * d

    checked = 0
    for i in range(0, len(est.rays), 31):
        px, py = (est.texel[i] - 0.5).astype(int)
        cx = np.searchsorted(xs, px, side="right") - 1
        cy = np.searchsorted(ys, py, side="right") - 1
        cx, cy = min(cx, len(xs) - 2), min(cy, len(ys) - 2)
        x0, x1, y0, y1 = xs[cx], xs[cx + 1], ys[cy], ys[cy + 1]
        u, v = (px - x0) / (x1 - x0), (py - y0) / (y1 - y0)
        tri = ([(x0, y0), (x1, y0), (x1, y1)] if u >= v else [(x0, y0), (x1, y1), (x0, y1)])
        a, b, c = (point(*t) for t in tri)
        normal = np.cross(b - a, c - a)
        ray = est.rays[i]
        t = normal @ (a - key.o) / (normal @ ray)
        expected = key.o + t * ray
        got = key.o + ray / est.inv_mesh[i]
        assert np.allclose(got, expected, rtol=1e-6, atol=1e-6), (got, expected)
        checked += 1
    assert checked > 20


@pytest.mark.parametrize("scale, phase_px", [(1.0, math.sqrt(2 / 12)),
                                             (2.0, math.sqrt(2 * (1 / 12 - 1 / 16)))])
def test_held_still_the_estimate_is_the_phase_term_alone(scale, phase_px):
    """At the keyframe's own view every ``C'`` is on ``C``'s ray (no warp), the map to
    keyframe pixels is the identity (no blur or alias), and the phase term is its analytic
    value: texel centres at k = 1 (a point sample against the reference's box, 0.41 px),
    half-texel phases at k = 2 (0.20 px)."""
    key, proj, n = key_setup(scale)
    est = DepthEstimate(plane_depth(key, proj, n, bumps=0.05), key, proj, 4, scale)
    assert error(est, key) == pytest.approx(phase_px, abs=1e-6)


def test_turning_adds_no_warp_and_moving_over_bumps_adds_parallax():
    """A pure rotation keeps every ``C`` and ``C'`` on one ray from the eye: only the
    resampling terms remain (under 0.6 px for a 2-degree turn).  Moving over a rippled
    surface, the estimate grows with the move; over the flat plane (the mesh exact) it
    stays at the resampling terms."""
    key, proj, n = key_setup(2.0)
    bumpy = DepthEstimate(plane_depth(key, proj, n, bumps=0.1), key, proj, 8, 2.0)
    flat = DepthEstimate(plane_depth(key, proj, n), key, proj, 8, 2.0)
    turned = look_at(EYE, (12.0, 0.0, 0.0))  # about 2 degrees, inside the guard band
    assert error(bumpy, turned) < 0.6
    moves = [look_at(EYE + (dx, 0.0, 0.0), (0.0, 0.0, 0.0)) for dx in (4.0, 16.0, 64.0)]
    e = [error(bumpy, vp) for vp in moves]
    assert e[0] < e[1] < e[2], e
    assert e[2] > 2.0 * error(flat, moves[2])
    assert error(flat, moves[2]) < 1.0


def test_a_view_beyond_the_keyframe_counts_its_uncovered_share():
    """Turned past the guard band the view's cells without a keyframe vertex count at the
    uncovered error: half the view uncovered gives at least sqrt(1/2) of it."""
    from lodsprite.sprite.depth_metric import UNCOVERED_PX

    key, proj, n = key_setup(1.0)
    est = DepthEstimate(plane_depth(key, proj, n), key, proj, 4, 1.0)
    fwd = np.array([0.0, 300.0, -200.0])
    side = np.cross(fwd, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    turned = look_at(EYE, EYE + fwd + side * np.linalg.norm(fwd) * math.tan(math.radians(24)))
    frame = Projection(FOV, 1.0, 10.0, 5000.0)
    u = est.uncovered(frame.matrix() @ turned.view_matrix(), (SIZE, SIZE))
    assert 0.3 < u < 0.8
    assert error(est, turned) >= math.sqrt(u) * UNCOVERED_PX - 1e-9
    assert est.uncovered(frame.matrix() @ key.view_matrix(), (SIZE, SIZE)) == 0.0


def test_contrast_weights_follow_the_keyframes_detail():
    """Weighted by the keyframe's contrast: flat colour leaves every sample's weight 1 (the
    plain estimate); a ramp of even slope leaves the estimate within 2 % of the plain one;
    detail on the left half only gives its samples most of the weight (the floor keeps
    the flat half's above 0)."""
    key, proj, n = key_setup(1.0)
    depth = plane_depth(key, proj, n, bumps=0.1)
    moved = look_at(EYE + (16.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    plain = DepthEstimate(depth, key, proj, 4, 1.0)
    flat = DepthEstimate(depth, key, proj, 4, 1.0)
    flat.weigh_by(np.full((n, n, 3), 90, np.uint8))
    assert np.array_equal(flat.weights, np.ones(len(flat.weights)))
    ramp = DepthEstimate(depth, key, proj, 4, 1.0)
    cols = np.broadcast_to((np.arange(n) * 200 // n).astype(np.uint8)[None, :, None],
                           (n, n, 3))
    ramp.weigh_by(cols)
    assert error(ramp, moved) == pytest.approx(error(plain, moved), rel=0.02)
    half = DepthEstimate(depth, key, proj, 4, 1.0)
    img = np.full((n, n, 3), 90, np.uint8)
    img[:, : n // 2] = np.where((np.arange(n // 2) % 2 == 0), 40, 200)[None, :, None]
    half.weigh_by(img)
    left = half.texel[:, 0] < n // 2 - 4
    right = half.texel[:, 0] > n // 2 + 4
    assert half.weights[left].mean() > 5 * half.weights[right].mean() > 0
    with pytest.raises(ValueError, match="does not match"):
        half.weigh_by(img[:-1])
