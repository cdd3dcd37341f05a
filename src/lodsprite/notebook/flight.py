"""Flying a camera in Python from a streaming widget's input events: the web page's fly
controls (``static/camera.js``) for frames rendered in the kernel.

Keys W/S move along the view, A/D sideways, Q/E (PageDown/PageUp) down and up, the arrow
keys turn; a mouse drag looks around, the wheel moves along the view.  Pure functions of
the viewpoint; :class:`FlyCamera` keeps the held keys and steps by the time elapsed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lodsprite.camera import Viewpoint

__all__ = ["FlyCamera", "look_along"]

YAW_RATE = 1.2
"""Radians per second the arrow keys turn."""
DRAG_RAD_PER_PX = 0.005
WHEEL_M_PER_UNIT = 0.002  # of the speed, per wheel delta unit
MOVE_KEYS = frozenset({"w", "s", "a", "d", "q", "e", "pageup", "pagedown", "arrowup",
                       "arrowdown", "arrowleft", "arrowright"})


def look_along(eye: np.ndarray, forward: np.ndarray) -> Viewpoint:
    """The viewpoint at ``eye`` (metres, (3,)) looking along ``forward`` with +z up."""
    z = -np.asarray(forward, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return Viewpoint(x, np.cross(z, x), z, np.asarray(eye, dtype=np.float64).copy())


@dataclass
class FlyCamera:
    """A flown viewpoint: ``speed`` metres per second; ``keys`` held now."""

    viewpoint: Viewpoint
    speed: float
    keys: set[str] = field(default_factory=set)

    def _angles(self) -> tuple[float, float]:
        f = -self.viewpoint.z
        return math.atan2(f[1], f[0]), math.asin(max(-1.0, min(1.0, float(f[2]))))

    def turn(self, d_yaw: float, d_pitch: float) -> None:
        yaw, pitch = self._angles()
        yaw, pitch = yaw + d_yaw, max(-1.5, min(1.5, pitch + d_pitch))
        f = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw),
                      math.sin(pitch)])
        self.viewpoint = look_along(self.viewpoint.o, f)

    def move(self, along: float = 0.0, side: float = 0.0, up: float = 0.0) -> None:
        vp = self.viewpoint
        o = vp.o - vp.z * along + vp.x * side + np.array([0.0, 0.0, up])
        self.viewpoint = Viewpoint(vp.x, vp.y, vp.z, o)

    def step(self, dt: float) -> bool:
        """Apply the held keys over ``dt`` seconds; whether anything moved."""
        k, s = self.keys, self.speed * dt
        if not (k & MOVE_KEYS) or dt <= 0:
            return False
        along = (("w" in k) - ("s" in k)) * s
        side = (("d" in k) - ("a" in k)) * s
        up = (bool(k & {"e", "pageup"}) - bool(k & {"q", "pagedown"})) * s
        self.move(along, side, up)
        yaw = (("arrowleft" in k) - ("arrowright" in k)) * YAW_RATE * dt
        pitch = (("arrowup" in k) - ("arrowdown" in k)) * YAW_RATE * dt
        if yaw or pitch:
            self.turn(yaw, pitch)
        return True

    def drag(self, dx_px: float, dy_px: float) -> None:
        self.turn(-dx_px * DRAG_RAD_PER_PX, -dy_px * DRAG_RAD_PER_PX)

    def wheel(self, dy: float) -> None:
        self.move(along=-dy * self.speed * WHEEL_M_PER_UNIT)
