"""Run-time LOD selection from an error profile (Scoggins et al. 2000 §4, Eq. 17), and the
geometric screen-space-error selection that engines use by default, for comparison.

Profile selection, per object: transform the eye into object space with the inverse
model matrix (this also divides distances by the object's scale); the view vector from
the object's profile centre gives ``(phi, theta)``, looked up at the nearest table view,
and the distance ``z``.  The profile was computed with field of view ``fov_p`` on
``M`` pixels; a camera with field of view ``fov`` on ``H`` pixels shows the object as
the profile view at the effective distance

    ``z_eff = z * m * M / H``,  ``m = tan(fov/2) / tan(fov_p/2)``   (Eq. 17; the pixel
    factor ``M / H`` keeps the object's size in pixels, and is 1 when ``H = M``).

The LOD chosen is the coarsest whose error at the largest table distance not beyond
``z_eff`` is at most the threshold (the distance is rounded down to a table sample:
the conservative side where error falls with distance, as it mostly does with the CSF;
Eq. 7 errors are nearly flat).  Closer than ``z0`` the table says nothing and
the full model is used; beyond the last distance the last one applies.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.errors import InputError
from lodsprite.profiles.table import ProfileTable


def object_views(models: np.ndarray, eye: np.ndarray,
                 centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """View direction and distance of the eye from each object, in object space.

    ``models (K, 4, 4)`` object-to-world; ``eye (3,)`` world; ``centre (3,)`` object space.
    Returns ``phi_deg (K,)`` in [0, 360), ``theta_deg (K,)`` elevation in [-90, 90] and
    ``distance (K,)`` in object units.
    """
    models = np.asarray(models, dtype=np.float64).reshape(-1, 4, 4)
    eye_h = np.append(np.asarray(eye, dtype=np.float64), 1.0)
    local = np.linalg.solve(models, np.broadcast_to(eye_h, (len(models), 4))[..., None])[..., 0]
    v = local[:, :3] / local[:, 3:4] - np.asarray(centre, dtype=np.float64)
    dist = np.linalg.norm(v, axis=1)
    phi = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360.0
    theta = np.degrees(np.arcsin(np.clip(v[:, 2] / np.where(dist > 0, dist, 1.0), -1, 1)))
    return phi, theta, dist


def magnification(fov_y_deg: float, profile_fov_deg: float) -> float:
    """``m = tan(fov/2) / tan(fov_p/2)`` of Eq. 17 (> 1 for a wider view than the profile's)."""
    if not (0 < fov_y_deg < 180):
        raise InputError(f"field of view must be in (0, 180) degrees, got {fov_y_deg}")
    return math.tan(math.radians(fov_y_deg) / 2) / math.tan(math.radians(profile_fov_deg) / 2)


def effective_distance(table: ProfileTable, distance: np.ndarray, fov_y_deg: float,
                       height_px: int) -> np.ndarray:
    """Profile-equivalent distance (object units) of objects ``distance`` away on a camera
    with vertical field of view ``fov_y_deg`` and ``height_px`` image rows."""
    if height_px < 1:
        raise InputError("image height must be at least 1 pixel")
    m = magnification(fov_y_deg, table.fov_deg)
    return np.asarray(distance, dtype=np.float64) * m * table.image_size / height_px


def nearest_views(table: ProfileTable, phi_deg: np.ndarray,
                  theta_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the nearest table azimuth (wrapping at 360) and elevation (clamped)."""
    phi = np.asarray(phi_deg, dtype=np.float64)[:, None]
    gap = np.abs((phi - table.phi_deg[None, :] + 180.0) % 360.0 - 180.0)
    theta = np.asarray(theta_deg, dtype=np.float64)[:, None]
    return gap.argmin(axis=1), np.abs(theta - table.theta_deg[None, :]).argmin(axis=1)


def coarsest_within(errors: np.ndarray, threshold: float) -> np.ndarray:
    """Per row of ``errors (K, L)`` (LOD 0 coarsest), the first LOD with error <= threshold;
    the last (full) LOD when none is."""
    ok = errors <= threshold
    ok[:, -1] = True
    return ok.argmax(axis=1)


def select_profile(table: ProfileTable, models: np.ndarray, eye: np.ndarray, fov_y_deg: float,
                   height_px: int, threshold: float, csf: bool = True) -> np.ndarray:
    """LOD index ``(K,) int64`` of each object chosen from the error profile."""
    phi, theta, dist = object_views(models, eye, table.centre)
    return select_views(table, phi, theta, dist, fov_y_deg, height_px, threshold, csf)


def select_views(table: ProfileTable, phi_deg: np.ndarray, theta_deg: np.ndarray,
                 distance: np.ndarray, fov_y_deg: float, height_px: int, threshold: float,
                 csf: bool = True) -> np.ndarray:
    """:func:`select_profile` from each object's view already in object space
    (``phi_deg``, ``theta_deg``, ``distance`` ``(K,)`` as :func:`object_views` gives)."""
    if not threshold >= 0:
        raise InputError(f"error threshold must be >= 0, got {threshold}")
    phi, theta, dist = phi_deg, theta_deg, distance
    z_eff = effective_distance(table, dist, fov_y_deg, height_px)
    i_phi, i_theta = nearest_views(table, phi, theta)
    i_z = np.searchsorted(table.z, z_eff * (1 + 1e-9), side="right") - 1
    near = i_z < 0
    i_z = np.clip(i_z, 0, len(table.z) - 1)
    errors = table.errors(csf)[:, i_phi, i_theta, i_z].T                 # (K, L)
    lod = coarsest_within(errors, threshold)
    lod[near] = table.levels - 1
    return lod


def select_screen_space(geometric_error: np.ndarray, models: np.ndarray, eye: np.ndarray,
                        centre: np.ndarray, fov_y_deg: float, height_px: int,
                        tolerance_px: float) -> np.ndarray:
    """LOD index ``(K,)`` by projected geometric error: the coarsest LOD whose Hausdorff
    distance to the full model (object units) projects to at most ``tolerance_px`` pixels
    at the object's distance (the engines' usual rule, e.g. 1 px)."""
    _, _, dist = object_views(models, eye, centre)
    px_per_unit = height_px / (2.0 * math.tan(math.radians(fov_y_deg) / 2.0))
    px = np.asarray(geometric_error, dtype=np.float64)[None, :] * px_per_unit
    px = px / np.maximum(dist, 1e-12)[:, None]
    return coarsest_within(px, tolerance_px)
