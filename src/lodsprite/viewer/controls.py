"""Camera controls of the interactive viewer: fly and orbit, free of any window or GL library.

:class:`CameraController` turns abstract input events (held keys, mouse look and drag,
scroll-wheel steps and frame time) into a :class:`~lodsprite.camera.Viewpoint`.  The window
layer of ``lodsprite view`` translates its library's events into the key names below and
calls :meth:`CameraController.update` once per shown frame.

Orientation is kept as a heading (radians counter-clockwise from world ``+x``, seen from
above) and a pitch (radians above the horizontal), so the camera never rolls: the screen
``x`` axis stays horizontal, and the pitch is clamped to ±89° so the up vector never flips.

* fly mode: ``w``/``s`` move along the view direction, ``a``/``d`` left/right, ``q``/``e``
  down/up along world ``z``; the mouse looks around; the wheel scales the speed.
* orbit mode: the eye circles the pivot ``centre`` and looks at it; ``w``/``s`` zoom in/out,
  ``a``/``d`` move the azimuth, ``q``/``e`` the elevation; dragging orbits (it grabs the
  world: dragging right moves the eye left, dragging down raises it); the wheel zooms.

Holding ``shift`` makes every key motion 4× faster; ``r`` resets to the home view and speed
(in fly mode) and ``tab`` toggles the mode.  Given a ``ground`` height function the eye is
kept ``clearance_m`` above it.

:class:`FlightRecorder` keeps the viewpoint of every shown frame and writes them as a JSON
camera path (:mod:`lodsprite.paths.core`), so a recorded flight replays as a benchmark path
with ``lodsprite render --path FILE.json``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import numpy as np

from lodsprite.camera import Viewpoint, look_at
from lodsprite.errors import InputError
from lodsprite.paths.core import CameraPath
from lodsprite.terrain.heightfield import HeightField

MODES = ("fly", "orbit")
MOVE_KEYS = frozenset({"w", "s", "a", "d", "q", "e", "shift"})
MAX_DT_S = 0.25                # a stalled frame never moves the camera further than this
SHIFT_BOOST = 4.0
MAX_PITCH = math.radians(89.0)
MIN_ELEVATION, MAX_ELEVATION = math.radians(1.0), math.radians(89.0)
ORBIT_RAD_PER_S = math.radians(60.0)   # a/d and q/e in orbit mode
ZOOM_PER_S = 1.0               # w/s in orbit mode: the distance e-folds once per second
SPEED_STEP, ZOOM_STEP = 1.25, 0.85     # per scroll step
SPEED_RANGE = (0.01, 100.0)    # fly speed relative to the home speed
MAX_DISTANCE_FACTOR = 1000.0   # orbit distance relative to the home eye's distance

Ground = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _positive(value: float, what: str, zero_ok: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not zero_ok):
        raise InputError(f"{what} must be a finite {'non-negative' if zero_ok else 'positive'} "
                         f"number, got {value!r}")
    return v


def _oriented(heading: float, pitch: float, eye: np.ndarray) -> Viewpoint:
    """The roll-free viewpoint at ``eye (3,)`` looking along ``heading``, ``pitch`` (rad)."""
    ch, sh, cp, sp = math.cos(heading), math.sin(heading), math.cos(pitch), math.sin(pitch)
    z = -np.array([cp * ch, cp * sh, sp])
    x = np.array([sh, -ch, 0.0])
    return Viewpoint(x, np.cross(z, x), z, eye)


def _heading_pitch(vp: Viewpoint) -> tuple[float, float]:
    """Heading and pitch (rad, pitch clamped to ±89°) of the view direction of ``vp``."""
    f = vp.forward
    pitch = float(np.clip(math.asin(float(np.clip(f[2], -1.0, 1.0))), -MAX_PITCH, MAX_PITCH))
    if math.hypot(f[0], f[1]) > 1e-9:
        return math.atan2(f[1], f[0]), pitch
    up = vp.y if f[2] < 0 else -vp.y  # looking straight down, screen-up is the heading
    return math.atan2(up[1], up[0]), pitch


class CameraController:
    """Fly and orbit controls: events in, a valid :class:`Viewpoint` out.

    ``home`` is the view :meth:`reset` returns to; ``centre (3,)`` metres the orbit pivot;
    ``speed_mps`` the fly speed (metres per second) restored by :meth:`reset`; ``ground``
    an optional vectorised ``(x, y) -> height`` (metres) that the eye stays ``clearance_m``
    above; ``look_deg_per_px`` the mouse sensitivity; ``min_distance_m`` the closest the
    orbiting eye gets to the centre.
    """

    def __init__(self, home: Viewpoint, centre: np.ndarray, speed_mps: float,
                 ground: Ground | None = None, *, clearance_m: float = 2.0,
                 look_deg_per_px: float = 0.2, min_distance_m: float = 1.0) -> None:
        if not isinstance(home, Viewpoint):
            raise InputError(f"home must be a Viewpoint, got {type(home).__name__}")
        c = np.asarray(centre, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InputError(f"orbit centre must be 3 finite numbers, got {centre!r}")
        self.home = home
        self.centre = c
        self.home_speed = _positive(speed_mps, "camera speed")
        self.ground = ground
        self.clearance_m = _positive(clearance_m, "ground clearance", zero_ok=True)
        self.look_rad_per_px = math.radians(_positive(look_deg_per_px, "look sensitivity"))
        self.min_distance_m = _positive(min_distance_m, "minimum orbit distance")
        self.max_distance_m = MAX_DISTANCE_FACTOR * max(
            float(np.linalg.norm(home.o - c)), self.min_distance_m)
        self._held: set[str] = set()
        self.reset()

    @classmethod
    def from_home(cls, home) -> CameraController:
        """The controller a scene's :class:`~lodsprite.scene.CameraHome` describes."""
        return cls(home.home, home.centre, home.speed_mps, home.ground,
                   clearance_m=home.clearance_m, min_distance_m=home.min_distance_m)

    @classmethod
    def for_terrain(cls, hf: HeightField, home: Viewpoint | None = None,
                    **kwargs: float) -> CameraController:
        """Defaults for ``hf``: home south of and above the terrain looking at its centre,
        speed ``width / 8`` m/s, pivot at the centre at mean height, ``hf.height_at`` as
        ground.  ``kwargs`` go to the constructor (``clearance_m`` ...)."""
        _, hi = hf.bounds()
        mean = float(hf.heights.mean())
        centre = np.array([0.0, 0.0, mean])
        if home is None:
            home = look_at((0.0, -0.9 * hf.depth, float(hi[2]) + 0.5 * hf.width), centre)
        return cls(home, centre, hf.width / 8.0, hf.height_at, **kwargs)

    @property
    def mode(self) -> str:
        """``"fly"`` or ``"orbit"``."""
        return self._mode

    @property
    def viewpoint(self) -> Viewpoint:
        """The current viewpoint."""
        return self._vp

    def reset(self) -> None:
        """Back to the home viewpoint and speed, in fly mode."""
        self._mode = "fly"
        self.speed_mps = self.home_speed
        self._eye = self.home.o.copy()
        self._heading, self._pitch = _heading_pitch(self.home)
        self._vp = self.home
        self._az = self._el = 0.0
        self._dist = self.min_distance_m

    def toggle_mode(self) -> None:
        """Fly → orbit keeps the eye and turns to the centre; orbit → fly keeps the view."""
        if self._mode == "fly":
            self._mode = "orbit"
            self._orbit_from_eye(self._eye)
            self._place_orbit()
        else:
            self._mode = "fly"

    def key(self, name: str, pressed: bool) -> None:
        """A key went down (``pressed``) or up; names as in the module docstring."""
        k = str(name).lower()
        if k in MOVE_KEYS:
            (self._held.add if pressed else self._held.discard)(k)
        elif pressed and k == "r":
            self.reset()
        elif pressed and k == "tab":
            self.toggle_mode()

    def update(self, dt_s: float) -> Viewpoint:
        """Move by the held keys over ``dt_s`` seconds (clamped to [0, 0.25]); the new view."""
        dt = float(dt_s)
        dt = min(max(dt, 0.0), MAX_DT_S) if math.isfinite(dt) else 0.0
        held = self._held
        fwd = ("w" in held) - ("s" in held)
        side = ("d" in held) - ("a" in held)
        up = ("e" in held) - ("q" in held)
        if dt == 0.0 or not (fwd or side or up):
            return self._vp
        boost = SHIFT_BOOST if "shift" in held else 1.0
        if self._mode == "fly":
            h, p = self._heading, self._pitch
            forward = np.array([math.cos(p) * math.cos(h), math.cos(p) * math.sin(h),
                                math.sin(p)])
            move = fwd * forward + side * np.array([math.sin(h), -math.cos(h), 0.0])
            move[2] += up
            move /= max(1.0, float(np.linalg.norm(move)))
            self._eye = self._lift(self._eye + move * (self.speed_mps * boost * dt))
            self._vp = _oriented(h, p, self._eye)
        else:
            self._dist *= math.exp(-fwd * ZOOM_PER_S * boost * dt)
            self._az += side * ORBIT_RAD_PER_S * boost * dt
            self._el = self._clamp_elevation(self._el + up * ORBIT_RAD_PER_S * boost * dt)
            self._place_orbit()
        return self._vp

    def look(self, dx_px: float, dy_px: float) -> None:
        """Mouse look by ``(dx, dy)`` pixels (window coordinates, ``y`` down): right turns
        right, down pitches down.  In orbit mode the same as :meth:`drag`."""
        if self._mode == "orbit":
            self.drag(dx_px, dy_px)
            return
        dx, dy = float(dx_px), float(dy_px)
        if not (math.isfinite(dx) and math.isfinite(dy)):
            return
        self._heading = (self._heading - dx * self.look_rad_per_px) % math.tau
        self._pitch = min(max(self._pitch - dy * self.look_rad_per_px, -MAX_PITCH), MAX_PITCH)
        self._vp = _oriented(self._heading, self._pitch, self._eye)

    def drag(self, dx_px: float, dy_px: float) -> None:
        """Orbit mode: turn the eye about the centre by ``(dx, dy)`` pixels (elevation kept in
        [1°, 89°]), still looking at it.  Fly mode: the same as :meth:`look`."""
        if self._mode == "fly":
            self.look(dx_px, dy_px)
            return
        dx, dy = float(dx_px), float(dy_px)
        if not (math.isfinite(dx) and math.isfinite(dy)):
            return
        self._az -= dx * self.look_rad_per_px
        self._el = self._clamp_elevation(self._el + dy * self.look_rad_per_px)
        self._place_orbit()

    def scroll(self, steps: float) -> None:
        """Wheel ``steps``: fly speed ×1.25**steps (0.01–100× home), orbit distance
        ×0.85**steps (at least ``min_distance_m``)."""
        s = float(steps)
        if not math.isfinite(s):
            return
        if self._mode == "fly":
            lo, hi = (math.log(f * self.home_speed) for f in SPEED_RANGE)
            log_v = math.log(self.speed_mps) + s * math.log(SPEED_STEP)
            self.speed_mps = math.exp(min(max(log_v, lo), hi))
        else:
            log_d = math.log(self._dist) + s * math.log(ZOOM_STEP)
            self._dist = math.exp(min(log_d, math.log(self.max_distance_m)))
            self._place_orbit()

    # ---------------------------------------------------------------------------- helpers

    def _lift(self, eye: np.ndarray) -> np.ndarray:
        """``eye`` raised to ``clearance_m`` above the ground where it is lower."""
        if self.ground is None:
            return eye
        g = float(np.asarray(self.ground(np.asarray(eye[0]), np.asarray(eye[1]))))
        if math.isfinite(g) and eye[2] < g + self.clearance_m:
            eye = eye.copy()
            eye[2] = g + self.clearance_m
        return eye

    def _clamp_elevation(self, el: float) -> float:
        # An eye entering orbit below 1° elevation may stay there but not go lower.
        return min(max(el, min(MIN_ELEVATION, self._el)), MAX_ELEVATION)

    def _orbit_from_eye(self, eye: np.ndarray) -> None:
        off = eye - self.centre
        dist = float(np.linalg.norm(off))
        if dist < 1e-9:
            off, dist = -self._vp.forward, 1.0
        self._dist = dist
        self._az = math.atan2(off[1], off[0])
        el = math.asin(float(np.clip(off[2] / dist, -1.0, 1.0)))
        self._el = min(max(el, -MAX_ELEVATION), MAX_ELEVATION)

    def _orbit_eye(self) -> np.ndarray:
        self._dist = min(max(self._dist, self.min_distance_m), self.max_distance_m)
        self._az %= math.tau
        ce = math.cos(self._el)
        return self.centre + self._dist * np.array(
            [ce * math.cos(self._az), ce * math.sin(self._az), math.sin(self._el)])

    def _place_orbit(self) -> None:
        eye = self._orbit_eye()
        lifted = self._lift(eye)
        if lifted is not eye:
            self._orbit_from_eye(lifted)
            # the round trip through angles (and the elevation limit) can lose the lift
            eye = self._lift(self._orbit_eye())
        self._eye = eye
        self._heading, self._pitch = (self._az + math.pi) % math.tau, -self._el
        self._vp = _oriented(self._heading, self._pitch, eye)


class FlightRecorder:
    """The viewpoints of a user's flight, one per shown frame, saved as a JSON camera path."""

    def __init__(self) -> None:
        self._frames: list[Viewpoint] = []

    def append(self, viewpoint: Viewpoint) -> None:
        """Record the viewpoint of one shown frame."""
        if not isinstance(viewpoint, Viewpoint):
            raise InputError(f"can only record Viewpoints, got {type(viewpoint).__name__}")
        self._frames.append(viewpoint)

    def __len__(self) -> int:
        return len(self._frames)

    def clear(self) -> None:
        """Forget every recorded frame."""
        self._frames.clear()

    def save(self, file: str | os.PathLike, fov_y_deg: float, name: str = "flight"
             ) -> CameraPath:
        """Write the flight to ``file`` as a JSON camera path with vertical field of view
        ``fov_y_deg`` (degrees) and return it; needs at least 2 recorded frames."""
        if len(self._frames) < 2:
            raise InputError(f"cannot save flight '{name}': {len(self._frames)} frame(s) "
                             "recorded, a camera path needs at least 2")
        path = CameraPath(name, tuple(self._frames), fov_y_deg)
        path.to_json(file)
        return path
