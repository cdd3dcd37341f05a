"""Profile LOD against distance-linear LOD at equal triangles (issue 23, must-have 3;
Scoggins, Machiraju & Moorhead 2000 §4.3 compare profile selection with the usual rule
at equal triangle counts).

On one crowd (:class:`~lodsprite.manager.scene.Crowd`, its types' profiles given) and a
few viewpoints: every visible object's LOD factor comes either from its type's error
profile at one threshold (:func:`lodsprite.profiles.object_lod.lod_factors`, Eq. 17) or
from the manager's distance-linear rule ``(1 - (d - near) / (far - near)) ** p``
(:func:`~lodsprite.manager.core.desired_lod`) with the exponent ``p`` tuned by bisection
(on ``log p``) until the triangles drawn over all viewpoints match the profile's within
``tolerance``; where no exponent reaches them the LOD ranges are scaled instead (the
"scale").  Linear factors are rounded to :data:`FACTOR_STEP` (the LODs actually
extracted; profile factors are the profile's levels).  Each selection is drawn by the
crowd drawer (:class:`~lodsprite.gl.crowd.CrowdDrawer`) and compared with every
object at its full mesh: RMSE (grey levels) and FLIP, means over the viewpoints.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.camera import frustum_planes, perspective
from lodsprite.errors import InputError
from lodsprite.manager.core import desired_lod
from lodsprite.manager.scene import spheres_in_frustum
from lodsprite.profiles.object_lod import DEFAULT_THRESHOLD, TypeProfile, lod_factors, type_profile

if TYPE_CHECKING:
    from lodsprite.camera import Viewpoint
    from lodsprite.manager.scene import Crowd
    from lodsprite.scene.objects import ObjectType

#: Linear factors are rounded to this step (at most 1 / FACTOR_STEP + 1 LODs a type).
FACTOR_STEP = 1.0 / 32.0
BISECTIONS = 48


@dataclass(frozen=True)
class ProfileVsLinear:
    """The comparison's figures: means over the viewpoints of RMSE (grey levels 0..255)
    and FLIP (0..1) against the full-detail render, triangles drawn in all, and the
    linear rule's tuned ``exponent`` and range ``scale``."""

    rmse_profile: float
    rmse_linear: float
    flip_profile: float
    flip_linear: float
    triangles_profile: int
    triangles_linear: int
    triangles_full: int
    exponent: float
    scale: float
    threshold: float
    views: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class _Views:
    """What every selection shares: per viewpoint the view-projection, the visible
    objects and their distances."""

    def __init__(self, crowd: Crowd, viewpoints: list[Viewpoint], size: tuple[int, int],
                 fov_y_deg: float) -> None:
        w, h = size
        proj = perspective(fov_y_deg, w / h, 0.3, 4.0 * crowd.extent + 100.0)
        self.view_proj = [proj @ vp.view_matrix() for vp in viewpoints]
        centres, radii = crowd.centres, crowd.radii
        self.visible = [spheres_in_frustum(frustum_planes(m), centres, radii)
                        for m in self.view_proj]
        self.dist = [np.linalg.norm(centres - vp.o, axis=1) for vp in viewpoints]


def type_profiles(types: list[ObjectType], models: list[Any]) -> dict[int, TypeProfile]:
    """Every type's profile (read from its cache or built), by type index, from the LOD
    models the crowd draws (``models[k]`` for ``types[k]``), whatever each type's ``lod``:
    the comparison selects every type both ways."""
    return {k: type_profile(t, m) for k, (t, m) in enumerate(zip(types, models, strict=True))}


def _triangles(crowd: Crowd, views: _Views, factors: list[np.ndarray]) -> int:
    """Triangles drawn over all viewpoints with ``factors[v] (N,)``."""
    total = 0
    for vis, f in zip(views.visible, factors, strict=True):
        for t, m in enumerate(crowd.models):
            sel = vis & (crowd.types == t)
            values, counts = np.unique(f[sel], return_counts=True)
            total += sum(m.triangles(float(v)) * int(c)
                         for v, c in zip(values, counts, strict=True))
    return total


def profile_factors(crowd: Crowd, profiles: dict[int, TypeProfile],
                    viewpoints: list[Viewpoint], fov_y_deg: float, height_px: int,
                    threshold: float) -> list[np.ndarray]:
    """Per viewpoint, every object's factor ``(N,)`` from its type's profile."""
    missing = sorted(set(range(len(crowd.models))) - set(profiles))
    if missing:
        raise InputError(f"profile LOD needs a profile for every type; none for {missing}")
    poses = np.concatenate([crowd.positions, crowd.yaw[:, None]], axis=1)
    out = []
    for vp in viewpoints:
        f = np.ones(len(crowd))
        for t, p in profiles.items():
            idx = np.flatnonzero(crowd.types == t)
            f[idx] = lod_factors(p, vp.o, poses[idx], fov_y_deg, height_px, threshold)
        out.append(f)
    return out


def linear_factors(views: _Views, near: float, far: float, exponent: float,
                   scale: float) -> list[np.ndarray]:
    """Per viewpoint, the distance-linear factors, rounded to :data:`FACTOR_STEP`."""
    return [np.round(desired_lod(d, near * scale, far * scale, exponent) / FACTOR_STEP)
            * FACTOR_STEP for d in views.dist]


def _bisect_log(count, lo: float, hi: float, target: int, falling: bool) -> float:
    """The parameter in ``[lo, hi]`` (log-bisected) whose ``count`` is nearest ``target``;
    ``count`` falls with the parameter when ``falling``."""
    best, best_gap = lo, math.inf
    for _ in range(BISECTIONS):
        mid = math.sqrt(lo * hi)
        n = count(mid)
        if abs(n - target) < best_gap:
            best, best_gap = mid, abs(n - target)
        if n == target:
            break
        if (n > target) == falling:
            lo = mid
        else:
            hi = mid
    return best


def match_linear(crowd: Crowd, views: _Views, target: int, near: float, far: float,
                 tolerance: float = 0.02) -> tuple[float, float]:
    """The linear rule's ``(exponent, scale)`` drawing about ``target`` triangles: the
    exponent bisected at scale 1, then (when no exponent in 1/64..64 comes within
    ``tolerance``) the ranges' scale at the nearer exponent bound."""
    def by_exponent(p: float) -> int:
        return _triangles(crowd, views, linear_factors(views, near, far, p, 1.0))

    p = _bisect_log(by_exponent, 1 / 64, 64.0, target, falling=True)
    if abs(by_exponent(p) - target) <= tolerance * max(target, 1):
        return p, 1.0
    p = 64.0 if by_exponent(64.0) > target else 1 / 64

    def by_scale(s: float) -> int:
        return _triangles(crowd, views, linear_factors(views, near, far, p, s))

    return p, _bisect_log(by_scale, 1 / 256, 256.0, target, falling=False)


def _render(gl, drawer, target, crowd: Crowd, views: _Views, v: int,
            factors: np.ndarray, extracted: dict) -> np.ndarray:
    """One viewpoint with ``factors (N,)``: each distinct (type, factor) one index buffer
    (``extracted``: buffer ids so far), one instanced draw each; ``(H, W, 3) uint8``."""
    idx = np.flatnonzero(views.visible[v])
    keys = list(zip(crowd.types[idx].tolist(), factors[idx].tolist(), strict=True))
    for key in dict.fromkeys(keys):
        if key not in extracted:
            extracted[key] = len(extracted)
            drawer.set_indices(extracted[key], key[0], crowd.models[key[0]].extract(key[1]))
    buffers = np.array([extracted[k] for k in keys], np.int64)
    order = np.argsort(buffers, kind="stable")
    ids, first, counts = np.unique(buffers[order], return_index=True, return_counts=True)
    poses = np.concatenate([crowd.positions, crowd.yaw[:, None]], axis=1)[idx[order]]
    drawer.upload_instances(poses.astype(np.float32))
    drawer.draw(views.view_proj[v], target.fbo,
                  list(zip(ids.tolist(), first.tolist(), counts.tolist(), strict=True)))
    gl.finish()
    return target.read_color()


def profile_vs_linear(gl, crowd: Crowd, profiles: dict[int, TypeProfile],
                      viewpoints: list[Viewpoint], size: tuple[int, int] = (128, 128),
                      fov_y_deg: float = 60.0, threshold: float = DEFAULT_THRESHOLD,
                      range_near: float = 5.0, range_far: float = 150.0,
                      tolerance: float = 0.02) -> ProfileVsLinear:
    """Profile LOD against linear LOD at equal triangles on ``crowd`` from ``viewpoints``
    (see the module doc), drawn at ``size`` ``(w, h)`` pixels on ``gl``
    (:class:`~lodsprite.gl.context.GLContext`).  ``profiles`` by type index (every type);
    ``range_near``/``range_far`` metres the linear rule's ranges before scaling."""
    from lodsprite import metrics
    from lodsprite.gl.crowd import CrowdDrawer
    from lodsprite.gl.target import RenderTarget

    if not viewpoints:
        raise InputError("the comparison needs at least one viewpoint")
    views = _Views(crowd, viewpoints, size, fov_y_deg)
    prof = profile_factors(crowd, profiles, viewpoints, fov_y_deg, size[1], threshold)
    tri_profile = _triangles(crowd, views, prof)
    p, s = match_linear(crowd, views, tri_profile, range_near, range_far, tolerance)
    lin = linear_factors(views, range_near, range_far, p, s)
    full = [np.ones(len(crowd)) for _ in viewpoints]
    target = RenderTarget(gl, *size)
    drawer = CrowdDrawer(gl, crowd.models, crowd.extent)
    try:
        extracted: dict = {}
        scores: dict[str, list[float]] = {k: [] for k in ("rp", "rl", "fp", "fl")}
        for v in range(len(viewpoints)):
            ref = _render(gl, drawer, target, crowd, views, v, full[v], extracted)
            for name, f in (("p", prof[v]), ("l", lin[v])):
                img = _render(gl, drawer, target, crowd, views, v, f, extracted)
                scores["r" + name].append(metrics.rmse(img, ref))
                scores["f" + name].append(metrics.flip(img, ref))
    finally:
        drawer.release()
        target.release()
    return ProfileVsLinear(
        float(np.mean(scores["rp"])), float(np.mean(scores["rl"])),
        float(np.mean(scores["fp"])), float(np.mean(scores["fl"])), tri_profile,
        _triangles(crowd, views, lin), _triangles(crowd, views, full), p, s,
        float(threshold), len(viewpoints))
