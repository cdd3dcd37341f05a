"""Viewpoints and perspective projections.

A viewpoint is the tuple of Swan, Arango & Nakshatrala (2002, §3.1):
``(x, y, z, o)`` where ``(x, y, z)`` is an orthonormal, right-handed set of
axes giving the orientation and ``o`` is the eye position.  We follow the
OpenGL eye-space convention: ``x`` points right on the screen, ``y`` up on the
screen and the camera looks along ``-z``.

World space is right-handed with ``+z`` up; all lengths are metres, all
angles given to public functions are degrees unless a name ends in ``_rad``.
Matrices are ``(4, 4) float64`` numpy arrays in the mathematical (row-major)
layout, acting on column vectors: ``clip = P @ V @ [x, y, z, 1]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.errors import InputError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

DEFAULT_FOV_Y_DEG = 45.0


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n == 0.0 or not math.isfinite(n):
        raise InputError("cannot normalise a zero or non-finite vector")
    return v / n


@dataclass(frozen=True, eq=False)
class Viewpoint:
    """Orientation axes ``x, y, z`` (unit, orthonormal) and eye ``o`` (metres), each ``(3,)``."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    o: np.ndarray

    def __post_init__(self) -> None:
        for name in ("x", "y", "z", "o"):
            v = np.asarray(getattr(self, name), dtype=np.float64).reshape(3)
            if not np.all(np.isfinite(v)):
                raise InputError(f"viewpoint {name} is not finite: {v}")
            object.__setattr__(self, name, v)
        axes = np.stack([self.x, self.y, self.z])
        if not np.allclose(axes @ axes.T, np.eye(3), atol=1e-6):
            raise InputError("viewpoint axes x, y, z must be orthonormal")
        if np.linalg.det(axes) < 0:
            raise InputError("viewpoint axes x, y, z must be right-handed")

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction, ``-z`` (unit, ``(3,)``)."""
        return -self.z

    def view_matrix(self) -> np.ndarray:
        """World-to-eye matrix ``(4, 4) float64`` (read-only; computed once)."""
        return self._view

    @cached_property
    def _view(self) -> np.ndarray:
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = self.x, self.y, self.z
        m[:3, 3] = -m[:3, :3] @ self.o
        m.flags.writeable = False
        return m

    def to_dict(self) -> dict[str, list[float]]:
        return {k: [float(c) for c in getattr(self, k)] for k in ("x", "y", "z", "o")}

    @classmethod
    def from_dict(cls, d: dict) -> Viewpoint:
        try:
            return cls(*(np.asarray(d[k], dtype=np.float64) for k in ("x", "y", "z", "o")))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed viewpoint {d!r}: {exc}") from exc


def view_rotation(viewpoint: Viewpoint | np.ndarray) -> Rotation:
    """The orientation of ``viewpoint`` as a rotation taking eye space to world space;
    given axes ``(..., 3, 3)`` (rows ``x, y, z`` per viewpoint), a stack of rotations.

    The rows of the view matrix are ``x, y, z``; as columns they map eye-space axes to
    world-space ones.
    """
    from scipy.spatial.transform import Rotation

    if isinstance(viewpoint, Viewpoint):
        return Rotation.from_matrix(np.stack([viewpoint.x, viewpoint.y, viewpoint.z], axis=1))
    return Rotation.from_matrix(np.swapaxes(np.asarray(viewpoint, dtype=np.float64), -1, -2))


def rotated_viewpoint(rotation: Rotation, eye) -> Viewpoint:
    """The viewpoint at ``eye (3,)`` metres oriented by ``rotation`` (eye space to world
    space): the inverse of :func:`view_rotation`."""
    m = rotation.as_matrix()
    return Viewpoint(m[:, 0], m[:, 1], m[:, 2], np.asarray(eye, dtype=np.float64))


def turned(viewpoint: Viewpoint, pixels: float, height: int, fov_y_deg: float) -> Viewpoint:
    """``viewpoint`` turned about its own vertical axis (``y``) so that the image centre of
    a ``height``-pixel image with vertical field of view ``fov_y_deg`` moves ``pixels``
    pixels sideways: a pure rotation, no parallax."""
    a = math.atan(pixels / (0.5 * height / math.tan(math.radians(fov_y_deg) / 2.0)))
    c, s = math.cos(a), math.sin(a)
    vp = viewpoint
    return Viewpoint(c * vp.x + s * vp.z, vp.y, -s * vp.x + c * vp.z, vp.o)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> Viewpoint:
    """Viewpoint at ``eye`` looking at ``target`` with ``up`` as the screen-up hint.

    ``up`` need not be orthogonal to the view direction but must not be parallel
    to it (raises :class:`InputError`).
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = _unit(eye - np.asarray(target, dtype=np.float64))
    x = np.cross(np.asarray(up, dtype=np.float64), z)
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: up vector is parallel to the viewing direction")
    x = _unit(x)
    y = np.cross(z, x)
    return Viewpoint(x, y, z, eye)


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL perspective matrix ``(4, 4) float64`` (NDC depth in [-1, 1])."""
    if not (0.0 < fov_y_deg < 180.0):
        raise InputError(f"field of view must be in (0, 180) degrees, got {fov_y_deg}")
    if not (0.0 < near < far) or aspect <= 0.0:
        raise InputError(f"need 0 < near < far and aspect > 0, got {near}, {far}, {aspect}")
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


@dataclass(frozen=True)
class Projection:
    """Perspective projection: vertical field of view (degrees), aspect (w/h), near/far (metres)."""

    fov_y_deg: float
    aspect: float
    near: float
    far: float

    def matrix(self) -> np.ndarray:
        """The perspective matrix ``(4, 4) float64`` (read-only; computed once)."""
        return self._matrix

    @cached_property
    def _matrix(self) -> np.ndarray:
        m = perspective(self.fov_y_deg, self.aspect, self.near, self.far)
        m.flags.writeable = False
        return m

    def pixel_angle_rad(self, height_px: int) -> float:
        """Angle subtended by one pixel, β = fov / image height (radians), Chen et al. Eq. 1."""
        return math.radians(self.fov_y_deg) / float(height_px)


def widened(projection: Projection, width: int, height: int, margin_px: int,
            spread: float = 1.0) -> Projection:
    """``projection`` grown by a guard band of ``margin_px`` pixels on every side of a
    ``width x height`` image: the ``(width + 2m) x (height + 2m)`` image of the result holds
    the original image, pixel for pixel, at offset ``(m, m)``.

    ``spread >= 1`` widens that image's view ``spread`` times more, aspect kept: the same
    ``(width + 2m) x (height + 2m)`` pixels then see ``spread`` display pixels each (a
    wider guard band at the same memory, sampled ``1/spread`` as finely)."""
    if margin_px < 0:
        raise InputError(f"guard band must be >= 0 pixels, got {margin_px}")
    if not (math.isfinite(spread) and spread >= 1.0):
        raise InputError(f"a guard band's spread must be >= 1, got {spread}")
    if margin_px == 0 and spread == 1.0:
        return projection
    half = (math.tan(math.radians(projection.fov_y_deg) / 2.0)
            * (height + 2 * margin_px) * spread / height)
    return Projection(math.degrees(2.0 * math.atan(half)),
                      (width + 2 * margin_px) / (height + 2 * margin_px),
                      projection.near, projection.far)


def texels_per_pixel(key_fov_y_deg: float, frame_fov_y_deg: float, key_rows: int,
                     frame_rows: int) -> float:
    """Texels a display pixel side (at the image centre) of a ``key_rows``-row image
    seeing ``key_fov_y_deg`` (a widened projection, :func:`widened`) for a
    ``frame_rows``-row frame seeing ``frame_fov_y_deg``: the keyframe scale, less where the
    keyframe was spread wider than its guard band."""
    frame_half = math.tan(math.radians(frame_fov_y_deg) / 2.0)
    key_half = math.tan(math.radians(key_fov_y_deg) / 2.0)
    return key_rows / (frame_rows * key_half / frame_half)


def fit_near_far(
    viewpoint: Viewpoint,
    bounds_min,
    bounds_max,
    clearance: float | None = None,
    max_ratio: float = 1.0e4,
) -> tuple[float, float]:
    """Near and far planes (metres) that enclose an axis-aligned box with good depth precision.

    ``far`` reaches the farthest box corner along the view direction (plus 1 %).
    ``near`` is the nearest box depth when the whole box lies in front of the
    eye; otherwise half of ``clearance`` (the eye's height above the surface
    below it), never less than ``far / max_ratio``, which bounds the loss of
    precision of a 24-bit depth buffer.
    """
    lo = np.asarray(bounds_min, dtype=np.float64)
    hi = np.asarray(bounds_max, dtype=np.float64)
    f = viewpoint.forward
    # Depth is linear in the point, so its extremes over the box are per-axis extremes.
    base = float(viewpoint.o @ f)
    far = max((float(np.maximum(lo * f, hi * f).sum()) - base) * 1.01, 1e-3)
    nearest = float(np.minimum(lo * f, hi * f).sum()) - base
    if nearest > 0.0:
        near = nearest * 0.99
    elif clearance is not None and clearance > 0.0:
        near = 0.5 * clearance
    else:
        near = 0.0
    near = max(near, far / max_ratio)
    if near >= far:
        near = far / max_ratio
    return near, far


def fitted_projection(viewpoint: Viewpoint, fov_y_deg: float, aspect: float, bounds_min,
                      bounds_max, ground_z: float) -> Projection:
    """Perspective projection of ``viewpoint`` with near and far fitted to the scene box
    ``bounds_min, bounds_max (3,)`` (metres) and to the eye's clearance above the ground
    height ``ground_z`` (metres) below it (:func:`fit_near_far`); ``aspect`` is w/h.

    Pure camera math: the terrain renderer draws through this projection, and the GL-free
    keyframe policy (:mod:`lodsprite.sprite.policy`) reasons with the same one.
    """
    clearance = float(viewpoint.o[2] - ground_z)
    near, far = fit_near_far(viewpoint, bounds_min, bounds_max, clearance=clearance)
    return Projection(fov_y_deg, aspect, near, far)


def frustum_planes(view_proj: np.ndarray) -> np.ndarray:
    """The six clip planes ``(6, 4)`` of ``P @ V`` as ``a x + b y + c z + d >= 0`` inside.

    Gribb & Hartmann's extraction; planes are normalised so ``d`` is a distance in metres.
    """
    m = np.asarray(view_proj, dtype=np.float64)
    planes = np.stack([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1],
                       m[3] + m[2], m[3] - m[2]])
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


def boxes_in_frustum(planes: np.ndarray, mins: np.ndarray, maxs: np.ndarray) -> np.ndarray:
    """Conservative test of ``K`` axis-aligned boxes ``(K, 3)`` against frustum planes.

    Returns a ``(K,) bool`` mask, False only for boxes entirely outside one plane.
    """
    mins = np.asarray(mins, dtype=np.float64)
    maxs = np.asarray(maxs, dtype=np.float64)
    n = planes[:, :3]
    # The box corner farthest along each plane normal (the "positive vertex").
    pos = np.where(n[None, :, :] >= 0, maxs[:, None, :], mins[:, None, :])
    dist = np.einsum("kpi,pi->kp", pos, n) + planes[None, :, 3]
    return np.all(dist >= 0.0, axis=1)


def project_points(points: np.ndarray, view_proj: np.ndarray, width: int, height: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project world points ``(N, 3)`` to pixels.

    Returns ``(px (N, 2) float64, ndc_depth (N,), w (N,))``; pixel (0, 0) is the
    top-left corner of the image (rows grow downwards), as in the arrays the
    renderer returns.  Points with ``w <= 0`` lie behind the eye.
    """
    p = np.asarray(points, dtype=np.float64)
    clip = np.c_[p, np.ones(len(p))] @ np.asarray(view_proj, dtype=np.float64).T
    w = clip[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = clip[:, :3] / w[:, None]
    px = np.c_[(ndc[:, 0] + 1.0) * 0.5 * width, (1.0 - ndc[:, 1]) * 0.5 * height]
    return px, ndc[:, 2], w


_FRUSTUM_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7),
                  (0, 4), (1, 5), (2, 6), (3, 7))


def view_footprint(view_proj: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(xy_min (2,), xy_max (2,))`` metres bounding the part of the box ``lo..hi (3,)``
    inside the view frustum of ``view_proj (4, 4)``, or None if it is empty.

    The frustum's slice between the box's lowest and highest z is a convex polytope whose
    vertices are frustum corners in that slab and frustum edges crossing its planes; their
    xy bounds, clipped to the box's, bound the footprint (a superset of it).
    """
    ndc = np.array([[x, y, z, 1.0] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)])
    world = ndc @ np.linalg.inv(view_proj).T
    corners = world[:, :3] / world[:, 3:4]
    pts = [corners[(corners[:, 2] >= lo[2]) & (corners[:, 2] <= hi[2])]]
    a = corners[[e[0] for e in _FRUSTUM_EDGES]]
    b = corners[[e[1] for e in _FRUSTUM_EDGES]]
    for z in (lo[2], hi[2]):
        dz = b[:, 2] - a[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - a[:, 2]) / dz
        ok = (dz != 0) & (s >= 0) & (s <= 1)
        pts.append(a[ok] + s[ok, None] * (b[ok] - a[ok]))
    pts = np.concatenate(pts)
    if pts.size == 0:
        return None
    xy_min = np.maximum(pts[:, :2].min(axis=0), lo[:2])
    xy_max = np.minimum(pts[:, :2].max(axis=0), hi[:2])
    if np.any(xy_min > xy_max):
        return None
    return xy_min, xy_max
