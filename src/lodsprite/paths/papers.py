"""The papers' camera paths: Chen et al. (1999) Figure 7 and Swan et al. (2002).

See :mod:`lodsprite.paths` for what each reproduces.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from lodsprite.camera import Viewpoint, look_at
from lodsprite.paths.core import CHEN1999_FRAMES, SWAN2002_FRAMES, CameraPath, _check_frames
from lodsprite.terrain.heightfield import HeightField

# --------------------------------------------------------------------------- Chen 1999

# Frame counts of the three segments of Figure 7 (460 frames in all).
_CHEN_SEGMENTS = (100, 280, 80)
# Knots in s = i / (frames - 1): with 460 frames, frames 0..99 are segment 1,
# 100..379 segment 2 and 380..459 segment 3, the last frame of each segment
# landing exactly on its end value.
_CHEN_S1 = (_CHEN_SEGMENTS[0] - 1) / (CHEN1999_FRAMES - 1)  # 99/459
_CHEN_S2 = (_CHEN_SEGMENTS[0] + _CHEN_SEGMENTS[1] - 1) / (CHEN1999_FRAMES - 1)  # 379/459


def chen1999(hf: HeightField, frames: int = CHEN1999_FRAMES) -> CameraPath:
    """Chen, Swan & Kaufman (1999) Figure 7: an orbit of the terrain's centre.

    ``L = hf.extent`` (metres); the camera always looks at the target
    ``(0, 0, hf.height_at(0, 0))``.  With elevation ``e`` and azimuth ``a``
    (degrees, azimuth counter-clockwise from east) the eye is at
    ``target + D d`` with ``d = (cos e cos a, cos e sin a, sin e)``:

    1. frames 0-99 (of 460): ``e`` from 90° (zenith) down to 10°, ``a = -90°``
       (camera south of the target, looking north), ``D = 1.5 L``;
    2. frames 100-379: ``a`` from -90° to +180° (270° anticlockwise),
       ``e = 10°``, ``D = 1.5 L``;
    3. frames 380-459: ``D`` from 1.5 L down to 0.4 L, ``e = 10°``, ``a = 180°``.

    Exact parametrisation: frame ``i`` is at ``s = i / (frames - 1)`` and the
    segment knots are at ``s1 = 99/459`` and ``s2 = 379/459`` (not 100/460 and
    380/460, which would not land on frames), so for 460 frames frame 99 is
    exactly at 10°, frame 379 exactly at 180° and frame 459 at 0.4 L.  Within a
    segment the angle or distance is linear in ``s`` (uniform speed).  Any
    ``frames >= 2`` samples the same geometric curve (Figure 10 uses 115 to
    1840 frames).

    Screen-up is the unit tangent of increasing elevation,
    ``(-sin e cos a, -sin e sin a, cos e)``, which is continuous through the
    zenith (there it points north, away from the camera's final side).  The
    axes are built directly: ``z = d``, ``y = up``, ``x = y × z``.

    Returns a :class:`CameraPath` named ``"chen1999"``; raises
    :class:`PathError` if ``frames < 2``.
    """
    n = _check_frames(frames)
    L = hf.extent
    target = np.array([0.0, 0.0, float(hf.height_at(0.0, 0.0))])
    s = np.arange(n, dtype=np.float64) / (n - 1)
    seg1, seg3 = s <= _CHEN_S1, s > _CHEN_S2
    t1 = np.clip(s / _CHEN_S1, 0.0, 1.0)
    t2 = np.clip((s - _CHEN_S1) / (_CHEN_S2 - _CHEN_S1), 0.0, 1.0)
    t3 = np.clip((s - _CHEN_S2) / (1.0 - _CHEN_S2), 0.0, 1.0)
    elev = np.where(seg1, 90.0 - 80.0 * t1, 10.0)
    azim = np.where(seg1, -90.0, -90.0 + 270.0 * t2)
    dist = np.where(seg3, 1.5 * L - 1.1 * L * t3, 1.5 * L)
    e, a = np.radians(elev), np.radians(azim)
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    up = np.stack([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)], axis=1)
    right = np.cross(up, d)
    eyes = target + dist[:, None] * d
    vps = tuple(Viewpoint(right[i], up[i], d[i], eyes[i]) for i in range(n))
    return CameraPath("chen1999", vps)


# --------------------------------------------------------------------------- Swan 2002

_SWAN_ZOOM_END = 0.20  # fraction of the path spent zooming in from far away
_SWAN_ARM = 0.35  # distance (x L) from the peak to each plain end point
_SWAN_MARGIN = 0.05  # plain end points stay this far (x L) inside the terrain
_SWAN_PEAK_BORDER = 0.15  # peak searched in the interior, away from this border fraction
_SWAN_SMOOTH = 0.02  # Gaussian sigma for finding the peak, fraction of the grid
_SWAN_RELIEF_WINDOW = 0.05  # window for local relief, fraction of the grid
_SWAN_DIRECTIONS = 16  # candidate lines through the peak, over 180 degrees
_SWAN_CROSSING_WEIGHT = 0.25  # weight of the mean height along a candidate line
_SWAN_START_DIST = 2.0  # far start: distance (x L) from the start plain point
_SWAN_START_ELEV = 35.0  # degrees, elevation of the far start seen from the start plain
_SWAN_PITCH = 17.0  # degrees, downward pitch of the forward look in low flight
_SWAN_CLEARANCE = 0.025  # x L, clearance above the highest terrain near the eye
_SWAN_RADIUS = 0.03  # x L, radius around the eye's ground point that must be cleared
_SWAN_LOOKAHEAD = 0.06  # x L, half-width of the running max along the flight line


def _sample_grid(hf: HeightField, grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a ``(rows, cols)`` array aligned with ``hf`` at world ``x, y``."""
    r, c = hf.grid_index(x, y)
    r = np.clip(r, 0.0, hf.rows - 1.0)
    c = np.clip(c, 0.0, hf.cols - 1.0)
    return ndimage.map_coordinates(grid, [np.ravel(r), np.ravel(c)], order=1,
                                   mode="nearest").reshape(np.shape(r))


def _ray_length_in_box(p: np.ndarray, u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Largest ``r >= 0`` with ``p + r u`` inside the 2-D box ``[lo, hi]`` (``p`` inside)."""
    r = math.inf
    for k in range(2):
        if u[k] > 1e-12:
            r = min(r, (hi[k] - p[k]) / u[k])
        elif u[k] < -1e-12:
            r = min(r, (lo[k] - p[k]) / u[k])
    return max(r, 0.0)


def _swan_flight_line(hf: HeightField) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Peak ``(2,)``, unit flight direction ``(2,)`` and arm lengths (metres) to both plains."""
    L = hf.extent
    h = hf.heights.astype(np.float64)
    sigma = (max(1.0, _SWAN_SMOOTH * hf.rows), max(1.0, _SWAN_SMOOTH * hf.cols))
    hs = ndimage.gaussian_filter(h, sigma, mode="nearest")
    # Peak: highest smoothed sample away from the border (the flight needs room).
    r0, r1 = int(_SWAN_PEAK_BORDER * (hf.rows - 1)), int(math.ceil((1 - _SWAN_PEAK_BORDER)
                                                                     * (hf.rows - 1)))
    c0, c1 = int(_SWAN_PEAK_BORDER * (hf.cols - 1)), int(math.ceil((1 - _SWAN_PEAK_BORDER)
                                                                     * (hf.cols - 1)))
    inner = hs[r0:r1 + 1, c0:c1 + 1]
    span = float(hs.max() - hs.min())
    if span <= 1e-9 * max(1.0, float(np.abs(hs).max())):
        peak = np.zeros(2)  # flat terrain: fly through the centre
    else:
        pr, pc = np.unravel_index(int(np.argmax(inner)), inner.shape)
        px, py = hf.world_xy(pr + r0, pc + c0)
        peak = np.array([float(px), float(py)])
    # Plain-ness: low local relief and low elevation, both normalised to [0, 1].
    win = (max(3, int(_SWAN_RELIEF_WINDOW * hf.rows) | 1),
           max(3, int(_SWAN_RELIEF_WINDOW * hf.cols) | 1))
    relief = ndimage.maximum_filter(h, win, mode="nearest") - ndimage.minimum_filter(
        h, win, mode="nearest")
    badness = (relief / max(float(relief.max()), 1e-12)
               + (hs - hs.min()) / max(span, 1e-12))
    # Candidate lines through the peak; ends kept inside the terrain with a margin.
    m = _SWAN_MARGIN * L
    lo = np.array([-hf.width / 2 + m, -hf.depth / 2 + m])
    hi = np.array([hf.width / 2 - m, hf.depth / 2 - m])
    lo, hi = np.minimum(lo, 0.0), np.maximum(hi, 0.0)
    inside = np.clip(peak, lo, hi)
    arm = _SWAN_ARM * L
    theta = np.arange(_SWAN_DIRECTIONS) * math.pi / _SWAN_DIRECTIONS
    dirs = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    arms = np.array([[min(arm, _ray_length_in_box(inside, sgn * u, lo, hi)) for sgn in (1, -1)]
                     for u in dirs])  # (K, 2): forward arm, backward arm
    ends = peak[None, None, :] + arms[:, :, None] * np.stack([dirs, -dirs], axis=1)
    bad_ends = _sample_grid(hf, badness, ends[..., 0], ends[..., 1])  # (K, 2)
    shortfall = 1.0 - arms / max(arm, 1e-12)
    # Tie-breaker: the mean normalised height along the line is lowest for the
    # line that crosses the range most directly (across a ridge, not along it).
    f = np.linspace(-1.0, 1.0, 33)
    arm_f = np.where(f[None, :] >= 0, arms[:, :1], arms[:, 1:]) * f[None, :]  # (K, 33)
    line = peak[None, None, :] + arm_f[:, :, None] * dirs[:, None, :]
    elev = (hs - hs.min()) / max(span, 1e-12)
    crossing = _sample_grid(hf, elev, line[..., 0], line[..., 1]).mean(axis=1)
    score = (bad_ends + 2.0 * shortfall).sum(axis=1) + _SWAN_CROSSING_WEIGHT * crossing
    k = int(np.argmin(score))
    # Start over the better plain of the chosen line.
    fwd_bad = bad_ends[k, 0] + 2.0 * shortfall[k, 0]
    back_bad = bad_ends[k, 1] + 2.0 * shortfall[k, 1]
    if fwd_bad < back_bad:  # forward end is the better plain: start there, fly backwards
        return peak, -dirs[k], float(arms[k, 0]), float(arms[k, 1])
    return peak, dirs[k], float(arms[k, 1]), float(arms[k, 0])


def _swan_floor(hf: HeightField, peak: np.ndarray, u: np.ndarray, t_f: float,
                t_b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The altitude floor of :func:`swan2002` on a dense sampling ``td`` of the flight
    line (metres along ``u`` from ``peak``, ``t_f`` to ``t_b``): ``(td, floor, need)``;
    ``need`` is the highest ground within ``0.03 L`` plus the clearance, ``floor`` its
    running maximum over the look-ahead, smoothed and never below ``need`` (float64
    metres)."""
    L = hf.extent
    step = 0.5 * min(hf.dx, hf.dy)
    n_dense = int(min(max(math.ceil((t_b - t_f) / step) + 1, 512), 1 << 16))
    td = np.linspace(t_f, t_b, n_dense)
    step = float(td[1] - td[0])
    rad = _SWAN_RADIUS * L
    size = (2 * (math.ceil(rad / hf.dy) + 1) + 1, 2 * (math.ceil(rad / hf.dx) + 1) + 1)
    hmax = ndimage.maximum_filter(hf.heights, size, mode="nearest")
    gx, gy = peak[0] + td * u[0], peak[1] + td * u[1]
    need = _sample_grid(hf, hmax, gx, gy).astype(np.float64) + _SWAN_CLEARANCE * L
    hw = max(1, round(_SWAN_LOOKAHEAD * L / step))
    floor = ndimage.maximum_filter1d(need, 2 * hw + 1, mode="nearest")
    floor = ndimage.gaussian_filter1d(floor, hw / 3.0, mode="nearest", truncate=3.0)
    floor = np.maximum(floor, need)  # guard against rounding of the kernel radius
    return td, floor, need


def swan2002(hf: HeightField, frames: int = SWAN2002_FRAMES) -> CameraPath:
    """Swan et al. (2002): zoom in, fly low over a plain, over the range, onto the plain beyond.

    The path is found from the data (``L = hf.extent``, metres):

    * **Range.** Heights are smoothed with a Gaussian (sigma 2 % of the grid);
      the peak is the highest smoothed sample outside a 15 % border.
    * **Plains and flight line.** "Badness" = local relief (max - min of the raw
      heights in a window of 5 % of the grid) / its maximum + smoothed height
      normalised to [0, 1].  Of 16 lines through the peak (every 11.25°) with
      ends ``0.35 L`` from the peak (shortened to stay ``0.05 L`` inside the
      terrain, a shortened arm is penalised), the one with the lowest summed
      end badness wins, plus 0.25 x the mean normalised height along the line
      (which breaks ties towards crossing a ridge rather than following it);
      the flight starts at the better (lower-badness) end
      ``A``, crosses the peak and ends at the other end ``B``.  The whole
      path's ground track is this straight line (extended outwards for the
      approach).
    * **Altitude floor.** Along the line, the maximum of the heights within a
      square of half-width ``0.03 L`` (+1 cell) around the ground point, plus a
      clearance of ``0.025 L``; then a running maximum over ``±0.06 L`` and a
      Gaussian of the same support (so the floor never drops below the
      requirement and the climb starts before the range).

    Schedule, by ``s = i / (frames - 1)``:

    * ``0 <= s <= 0.2``: zoom in.  The eye starts ``2 L`` from ``A`` at 35°
      elevation on the outside of the terrain, beyond ``A``, looking at ``A``;
      it first dollies along that line of sight, then levels out onto the floor
      above ``A``.  Horizontal progress ``p`` in [0, 1] over ``sigma = s / 0.2``
      has speed ``m + 3 (1 - m) (1 - sigma)^2``, ``m`` the cruise speed, so
      the zoom decelerates smoothly onto the cruise (no jump in speed or
      acceleration); the height above the floor is ``E (1 - p)^2 (1 + p)``
      (slope of the line of sight at the start, level at the end).  The pitch
      eases (smoothstep) from 35° down to 17°.
    * ``0.2 < s <= 1``: constant horizontal speed from ``A`` to ``B`` at the
      floor altitude: low over the start plain, up over the range (the peak is
      crossed at ``s = 0.2 + 0.8 |A - peak| / |B - A|``, 0.6 for equal arms, so
      roughly 45-75 % is spent within ``0.13 L`` of the peak), then down onto
      the plain beyond.

    The camera looks forward along the flight heading, pitched down 17°
    (:func:`~lodsprite.camera.look_at` with up ``+z``).  Positions and velocity
    are continuous (also at ``s = 0.2``); the climb over the range starts
    about ``0.15 L`` before the terrain rises (look-ahead of the floor).
    Returns a :class:`CameraPath` named ``"swan2002"``; raises :class:`PathError` if ``frames < 2``.
    """
    n = _check_frames(frames)
    L = hf.extent
    peak, u, arm_a, arm_b = _swan_flight_line(hf)
    # Flight coordinate t (metres) along u from the peak: A at -arm_a, B at +arm_b.
    ce, se = math.cos(math.radians(_SWAN_START_ELEV)), math.sin(math.radians(_SWAN_START_ELEV))
    t_a, t_b = -arm_a, arm_b
    t_f = t_a - _SWAN_START_DIST * L * ce
    h_a = float(hf.height_at(*(peak + t_a * u)))
    z_f = h_a + _SWAN_START_DIST * L * se

    td, floor, need = _swan_floor(hf, peak, u, t_f, t_b)

    s = np.arange(n, dtype=np.float64) / (n - 1)
    zoom = s <= _SWAN_ZOOM_END
    # Cruise: constant horizontal speed from A to B.
    sc = np.clip((s - _SWAN_ZOOM_END) / (1.0 - _SWAN_ZOOM_END), 0.0, 1.0)
    t = t_a + sc * (t_b - t_a)
    # Zoom: horizontal progress p(sigma) in [0, 1] with speed p' = m1 + 3 (1 - m1) (1 - sigma)^2,
    # which decelerates onto the cruise speed m1 with zero acceleration at sigma = 1.
    sig = np.clip(s / _SWAN_ZOOM_END, 0.0, 1.0)
    span = t_a - t_f
    m1 = min((t_b - t_a) * _SWAN_ZOOM_END / (1.0 - _SWAN_ZOOM_END) / span, 1.0)
    p = m1 * sig + (1.0 - m1) * (1.0 - (1.0 - sig) ** 3)
    t = np.where(zoom, t_f + p * span, t)
    # C2 cubic interpolation of the floor (linear interpolation would put kinks in
    # steep climbs); never below the linearly interpolated requirement.
    from scipy.interpolate import make_interp_spline  # lazy: a slow import

    z_floor = np.maximum(make_interp_spline(td, floor, k=3)(t), np.interp(t, td, need))
    extra0 = max(z_f - float(floor[0]), 0.0)
    extra = np.where(zoom, extra0 * (1.0 - p) ** 2 * (1.0 + p), 0.0)
    z = z_floor + extra
    # Pitch: at the start look at A, ease to the cruise pitch by the end of the zoom.
    pitch0 = math.atan2(float(z[0]) - h_a, t_a - t_f)
    ease = sig * sig * (3.0 - 2.0 * sig)
    pitch = np.where(zoom, pitch0 + (math.radians(_SWAN_PITCH) - pitch0) * ease,
                     math.radians(_SWAN_PITCH))
    eyes = np.stack([peak[0] + t * u[0], peak[1] + t * u[1], z], axis=1)
    fwd = np.stack([np.cos(pitch) * u[0], np.cos(pitch) * u[1], -np.sin(pitch)], axis=1)
    vps = tuple(look_at(eyes[i], eyes[i] + fwd[i]) for i in range(n))
    return CameraPath("swan2002", vps)


