"""The point under the window's cursor, in the dataset's own coordinates (GL-free).

The ray through a window pixel from the shown viewpoint is marched over the scene's
working grid (steps of half a cell, then bisection: the surface the coarse level and the
page draw), and the world point it meets (metres from the terrain's centre, heights
exaggerated) is taken back to the dataset's CRS by the terrain's georeference
(:func:`world_to_dataset`, the inverse of :func:`lodsprite.paths.core.dataset_to_world`),
as the web page's ``cursor.js`` does.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.terrain.heightfield import HeightField

MAX_STEPS = 20000


def pixel_ray(vp: Viewpoint, px: float, py: float, size: tuple[int, int],
              fov_y_deg: float) -> np.ndarray:
    """The unit world direction ``(3,)`` of the ray through pixel ``(px, py)`` (top-left
    origin) of a ``size = (w, h)`` image with vertical field of view ``fov_y_deg``."""
    w, h = size
    t = math.tan(math.radians(fov_y_deg) / 2)
    u = (2 * (px + 0.5) / w - 1) * t * (w / h)
    v = (1 - 2 * (py + 0.5) / h) * t
    d = u * np.asarray(vp.x) + v * np.asarray(vp.y) - np.asarray(vp.z)
    return d / np.linalg.norm(d)


def ray_ground(hf: HeightField, origin: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """Where the ray ``origin + t d`` first meets ``hf``'s surface (bilinear heights),
    ``(3,)`` world metres, or None where it leaves the terrain without meeting it."""
    o = np.asarray(origin, np.float64)
    lo, hi = hf.bounds()
    span = float(np.linalg.norm(hi - lo)) + float(np.linalg.norm(o - (lo + hi) / 2))
    step = 0.5 * min(hf.dx, hf.dy)
    n = int(min(MAX_STEPS, span / step + 2))
    t = np.linspace(0.0, span, n)
    p = o[None, :] + t[:, None] * d[None, :]
    inside = (p[:, 0] >= lo[0]) & (p[:, 0] <= hi[0]) & (p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1])
    below = inside & (p[:, 2] <= hf.height_at(p[:, 0], p[:, 1]))
    hit = np.flatnonzero(below)
    if not len(hit):
        return None
    i = int(hit[0])
    if i == 0:
        return p[0]
    a, b = t[i - 1], t[i]
    for _ in range(40):
        m = 0.5 * (a + b)
        q = o + m * d
        if q[2] > float(hf.height_at(q[:1], q[1:2])[0]):
            a = m
        else:
            b = m
    return o + b * d


def world_to_dataset(p: np.ndarray, meta: dict) -> tuple[float, float, float] | None:
    """World point ``(3,)`` to the dataset's easting, northing (CRS units) and height
    (metres above its datum) by the terrain's ``meta`` (``georef``, ``exaggeration``);
    None for a terrain without a georeference."""
    ref = meta.get("georef")
    if not ref:
        return None
    w, s, e, n = ref["bounds"]
    fx, fy = ref["metres_per_unit"]
    ex = float(meta.get("exaggeration", 1.0))
    return (float(p[0]) / fx + 0.5 * (w + e), float(p[1]) / fy + 0.5 * (s + n),
            float(p[2]) / ex)


def cursor_line(hf: HeightField, vp: Viewpoint, px: float, py: float,
                size: tuple[int, int], fov_y_deg: float) -> str:
    """The HUD's line for the cursor at ``(px, py)``: the point in the dataset's CRS
    (decimals to about 0.1 m: 6 for degrees) and its height, and the exaggeration."""
    meta = hf.meta
    ex = f"exaggeration {float(meta.get('exaggeration', 1.0)):.2f}x"
    p = ray_ground(hf, np.asarray(vp.o), pixel_ray(vp, px, py, size, fov_y_deg))
    if p is None:
        return ex
    at = world_to_dataset(p, meta)
    if at is None:
        return (f"cursor x {p[0]:.1f} y {p[1]:.1f} m height "
                f"{p[2] / float(meta.get('exaggeration', 1.0)):.1f} m   {ex}")
    mpu = float(meta["georef"]["metres_per_unit"][0])
    d = min(9, max(1, math.ceil(math.log10(max(mpu, 1e-9))) + 1))
    crs = str(meta.get("crs") or "")[:40]
    return f"cursor E {at[0]:.{d}f} N {at[1]:.{d}f} ({crs}) height {at[2]:.1f} m   {ex}"
