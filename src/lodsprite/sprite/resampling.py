"""The keyframe image's resampling error, in pixels (Chen, Swan & Kaufman 1999, §5's first
item of future work: "the texel from the original texture is resampled twice ... it should
be possible to characterize this process using the language of sampling theory ... it might
lead to better error metrics"), added to the warp angle of their §3.2, Eq. 1-2.

**The map.**  A spriteframe colours the current pixel ``p`` seeing the point ``X(p)`` of the
coarse surface with the keyframe image at ``q(X(p))``, bilinearly (the sprite texture has no
mipmaps: ``gl/sprite.py``, ``DEFAULT_SPRITE_MIPMAPS``).  Near a surface point ``P`` with unit
normal ``n`` the surface is its tangent plane ``X = P + u t1 + v t2`` (``t1, t2`` an
orthonormal basis of the plane), and ``p -> q`` is the homography that plane induces between
the two images.  Its Jacobian is

    J = B A^-1   (keyframe texels per current pixel, 2x2),

with ``A = dp/d(u, v)`` and ``B = dq/d(u, v)``.  For an image of ``w x h`` pixels through
``M = proj @ view`` (``c = M [X; 1]``, ``ndc = c_xy / c_w``, ``pixel = (ndc + 1) / 2 * (w, h)``)

    d pixel_x / du = (w / 2) (M_0 - ndc_x M_3)[:3] . t1 / c_w     (likewise y with h, v with t2).

The y flip of image rows and the guard band's offset change neither ``J``'s singular values
``s1 >= s2`` nor anything below.

**The error.**  At ``J = I`` (the keyframe's own view and pixel size) every pixel lands on a
texel centre and the sprite reproduces the keyframe exactly.  Otherwise, by sampling theory:

* *Magnification* (``s2 < 1``): a keyframe texel covers ``1 / s2`` current pixels along the
  most stretched direction.  Bilinear reconstruction fills them by interpolation, so detail
  the current view resolves and the keyframe did not sample (the band between the
  keyframe's Nyquist rate and the current one) is missing: the image is blurred over
  ``blur = 1 / s2 - 1`` pixels beyond the pixel itself.  This is unbounded (a keyframe that
  saw the surface edge-on holds almost no texels of it).
* *Minification* (``s1 > 1``): a current pixel's footprint spans ``s1`` texels along the
  most compressed direction, of which the unfiltered bilinear sample reads one 2x2
  neighbourhood: the fraction ``alias = 1 - 1 / s1`` of the pixel's footprint is ignored, so
  keyframe detail finer than the pixel aliases.  The error of one aliased sample is bounded
  by the contrast inside one pixel, so this term is bounded by 1 px.

The two combine as independent errors, ``e_res = sqrt(blur² + alias²)`` pixels, clipped to
:data:`MAX_RESAMPLING_PX` (so edge-on planes stay finite).  ``e_res`` is 0 exactly at ``J = I``,
grows with zoom-out (``s1 = s2 = d / d_key`` along the view axis, so ``alias = 1 - d_key/d``)
and zoom-in (``blur = d_key / d - 1``), and with the grazing angle (a plane seen at angle
``φ`` from its normal is compressed by ``cos φ`` across the view's horizontal axis, so
seen face-on in the keyframe and at ``φ`` now, ``s1 = d / (d_key cos φ)``).

The metric (:mod:`lodsprite.sprite.metric`) adds it per sample to the warp angle:
``θ² = θ_warp² + (β e_res)²``, so the error stays ``sqrt(mean θ²) / β`` pixels and Eq. 2's
test ``error_px >= ε`` is unchanged.
"""

from __future__ import annotations

import numpy as np

MAX_RESAMPLING_PX = 64.0  # e_res is clipped here (edge-on planes, points behind an eye)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products ``(K, 3)`` of ``a, b (K, 3)`` (np.cross costs more on
    the few hundred rows of a frame)."""
    return np.c_[a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                 a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]]


def tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents ``(t1, t2)`` ``(K, 3) float64`` of the planes with ``normals (K, 3)``
    (need not be unit; zero normals give the xy plane)."""
    n = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 0, n / np.where(length > 0, length, 1.0), [0.0, 0.0, 1.0])
    # The world axis least aligned with n is never parallel to it.
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    t1 = cross(n, axis)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, cross(n, t1)


def pixel_derivatives(points: np.ndarray, t1: np.ndarray, t2: np.ndarray,
                      view_proj: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """``(D (K, 2, 2) float64, w (K,) float64)``: the pixel derivatives ``d(x, y)/d(u, v)``
    of the plane points ``points + u t1 + v t2`` in the ``size = (w, h)`` image through
    ``view_proj (4, 4)``, and each point's clip ``w`` (<= 0: behind the eye)."""
    m = np.asarray(view_proj, dtype=np.float64)
    clip = points @ m[:, :3].T + m[:, 3]
    cw = clip[:, 3]
    safe = np.where(cw != 0, cw, 1.0)
    ndc = clip[:, :2] / safe[:, None]
    half = 0.5 * np.asarray(size, dtype=np.float64)
    out = np.empty((len(points), 2, 2))
    for j, t in enumerate((t1, t2)):
        dc = t @ m[:, :3].T  # (K, 4): the clip coordinates' derivative along t
        out[:, :, j] = half * (dc[:, :2] - ndc * dc[:, 3:4]) / safe[:, None]
    return out, cw


def singular_values(j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(s1, s2)`` ``(K,) float64``, ``s1 >= s2 >= 0``: singular values of ``j (K, 2, 2)``
    (closed form without cancellation: with ``J = [[a, b], [c, d]]``,
    ``s1, s2 = (|(a + d, c - b)| ± |(a - d, c + b)|) / 2``)."""
    a, b, c, d = j[:, 0, 0], j[:, 0, 1], j[:, 1, 0], j[:, 1, 1]
    p, q = np.hypot(a + d, c - b), np.hypot(a - d, c + b)
    return 0.5 * (p + q), 0.5 * np.abs(p - q)


def texel_jacobian(points: np.ndarray, normals: np.ndarray, key_view_proj: np.ndarray,
                   key_size: tuple[int, int], view_proj: np.ndarray,
                   size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(J (K, 2, 2) float64, ok (K,) bool)``: keyframe texels per current pixel at each
    surface point ``points (K, 3)`` metres with ``normals (K, 3)`` (module docstring:
    ``J = B A^-1``).  ``ok`` is False where ``J`` is undefined: a point behind either eye,
    or a plane seen edge-on from the current view."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    t1, t2 = tangent_basis(np.asarray(normals).reshape(-1, 3))
    a, cw = pixel_derivatives(points, t1, t2, view_proj, size)
    b, kw = pixel_derivatives(points, t1, t2, key_view_proj, key_size)
    return jacobian(a, cw, b, kw)


def jacobian(a: np.ndarray, cw: np.ndarray, b: np.ndarray,
             kw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(J = B A^-1, ok)`` from the current and keyframe pixel derivatives ``a, b (K, 2,
    2)`` and clip ``w`` values ``cw, kw (K,)`` (:func:`pixel_derivatives`; a keyframe's
    ``b`` computed once serves every frame)."""
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    scale = (a * a).sum(axis=(1, 2))
    ok = (cw > 0) & (kw > 0) & (np.abs(det) > 1e-12 * np.maximum(scale, 1e-300))
    det = np.where(ok, det, 1.0)
    inv = np.stack([np.stack([a[:, 1, 1], -a[:, 0, 1]], -1),
                    np.stack([-a[:, 1, 0], a[:, 0, 0]], -1)], 1) / det[:, None, None]
    return b @ inv, ok


def resampling_from_singular(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """``e_res (K,) float64`` pixels from the singular values of ``J`` (module docstring):
    ``sqrt(blur² + alias²)`` with ``blur = max(1/s2 - 1, 0)``, ``alias = max(1 - 1/s1, 0)``,
    clipped to :data:`MAX_RESAMPLING_PX`."""
    with np.errstate(divide="ignore", invalid="ignore"):
        blur = np.where(s2 > 0, 1.0 / s2 - 1.0, np.inf)
        alias = np.where(s1 > 0, 1.0 - 1.0 / s1, 0.0)
    blur = np.clip(np.nan_to_num(blur, nan=MAX_RESAMPLING_PX), 0.0, MAX_RESAMPLING_PX)
    alias = np.clip(np.nan_to_num(alias, nan=1.0), 0.0, 1.0)
    return np.minimum(np.hypot(blur, alias), MAX_RESAMPLING_PX)


def resampling_px(points: np.ndarray, normals: np.ndarray, key_view_proj: np.ndarray,
                  key_size: tuple[int, int], view_proj: np.ndarray,
                  size: tuple[int, int]) -> np.ndarray:
    """The resampling error ``(K,) float64`` pixels of showing, in the ``size = (w, h)``
    image through ``view_proj (4, 4)``, the surface points ``points (K, 3)`` metres (unit or
    not ``normals (K, 3)``) from the keyframe image of ``key_size`` pixels rendered through
    ``key_view_proj (4, 4)`` (module docstring).  0 where ``J = I``; points where ``J`` is
    undefined (behind an eye, edge-on) get :data:`MAX_RESAMPLING_PX`."""
    j, ok = texel_jacobian(points, normals, key_view_proj, key_size, view_proj, size)
    s1, s2 = singular_values(j)
    return np.where(ok, resampling_from_singular(s1, s2), MAX_RESAMPLING_PX)
