"""Viewpoint predictors (Swan et al. 2002, §3.3, VIEWPOINT-PREDICTOR).

A keyframe producer (the distributed LOD server, or the viewer's keyframe worker process)
predicts where the viewer will be when a keyframe it starts now reaches the
client, ``δt`` seconds ahead (δt measured by the KEYFRAME-TRANSMITTER).

* :class:`DecayLinearPredictor` - the paper's: orientation is the latest received; the
  eye moves on linearly at a velocity averaged over past samples with exponentially
  decaying weights (half-life ``half_life_s``).
* :class:`KalmanPredictor` - a constant-velocity Kalman filter on the eye (per axis;
  process noise on the acceleration), orientation extrapolated at the latest angular
  velocity.  Better when samples are noisy or irregular in time.

Both take ``observe(t, viewpoint)`` samples (t in seconds, increasing) and return
``predict(dt)``, the viewpoint ``dt`` seconds after the latest sample.
"""

from __future__ import annotations

import math

import numpy as np

from lodsprite.camera import Viewpoint, rotated_viewpoint, view_rotation


class DecayLinearPredictor:
    """Linear extrapolation of the eye with an exponential-decay velocity window."""

    def __init__(self, half_life_s: float = 0.25) -> None:
        self.half_life_s = half_life_s
        self._t: float | None = None
        self._last: Viewpoint | None = None
        self._velocity = np.zeros(3)
        self._weight = 0.0

    def observe(self, t: float, viewpoint: Viewpoint) -> None:
        if self._last is not None and self._t is not None and t > self._t:
            dt = t - self._t
            v = (viewpoint.o - self._last.o) / dt
            decay = 0.5 ** (dt / self.half_life_s)
            # Weighted mean of velocities, older samples weighted down by the decay.
            self._velocity = (decay * self._weight * self._velocity + dt * v) / (
                decay * self._weight + dt)
            self._weight = decay * self._weight + dt
        self._t, self._last = t, viewpoint

    def predict(self, dt: float) -> Viewpoint:
        if self._last is None:
            raise RuntimeError("predict() before any observe()")
        last = self._last
        return Viewpoint(last.x, last.y, last.z, last.o + self._velocity * dt)


class KalmanPredictor:
    """Constant-velocity Kalman filter on the eye; orientation at constant angular velocity.

    ``accel_sigma`` (m/s²) is the process noise, ``measure_sigma`` (m) the noise of an
    observed eye position.
    """

    def __init__(self, accel_sigma: float = 50.0, measure_sigma: float = 1.0) -> None:
        self.q = accel_sigma**2
        self.r = measure_sigma**2
        self._t: float | None = None
        self._x = np.zeros((3, 2))               # per axis: position, velocity
        self._p = np.tile(np.diag([1e6, 1e6]), (3, 1, 1))
        self._last: Viewpoint | None = None
        self._omega = np.zeros(3)                # angular velocity, rad/s (rotation vector)

    def observe(self, t: float, viewpoint: Viewpoint) -> None:
        if self._last is None:
            self._x[:, 0] = viewpoint.o
        elif self._t is not None and t > self._t:
            dt = t - self._t
            f = np.array([[1.0, dt], [0.0, 1.0]])
            g = np.array([0.5 * dt * dt, dt])
            q = self.q * np.outer(g, g)
            self._x = self._x @ f.T
            self._p = f @ self._p @ f.T + q
            # Update with the observed position (H = [1, 0]) on each axis.
            s = self._p[:, 0, 0] + self.r
            k = self._p[:, :, 0] / s[:, None]
            innovation = viewpoint.o - self._x[:, 0]
            self._x = self._x + k * innovation[:, None]
            self._p = self._p - k[:, :, None] * self._p[:, None, 0, :]
            turn = view_rotation(viewpoint) * view_rotation(self._last).inv()
            self._omega = turn.as_rotvec() / dt
        self._t, self._last = t, viewpoint

    def predict(self, dt: float) -> Viewpoint:
        if self._last is None:
            raise RuntimeError("predict() before any observe()")
        from scipy.spatial.transform import Rotation  # on first use: a slow import

        eye = self._x[:, 0] + self._x[:, 1] * dt
        rotation = Rotation.from_rotvec(self._omega * dt) * view_rotation(self._last)
        return rotated_viewpoint(rotation, eye)


PREDICTORS = {"linear": DecayLinearPredictor, "kalman": KalmanPredictor}


def prediction_error(predictor, times: np.ndarray, viewpoints: list[Viewpoint],
                     lead: int) -> dict:
    """Eye error (metres) and orientation error (degrees) of predicting ``lead`` samples
    ahead along a recorded path, after each observation: mean and max."""
    eye_err, ang_err = [], []
    for i in range(len(viewpoints) - lead):
        predictor.observe(float(times[i]), viewpoints[i])
        if i < 2:
            continue
        pred = predictor.predict(float(times[i + lead] - times[i]))
        truth = viewpoints[i + lead]
        eye_err.append(float(np.linalg.norm(pred.o - truth.o)))
        cos = np.clip(np.dot(pred.z, truth.z), -1.0, 1.0)
        ang_err.append(math.degrees(math.acos(cos)))
    return {"eye_m_mean": float(np.mean(eye_err)), "eye_m_max": float(np.max(eye_err)),
            "view_deg_mean": float(np.mean(ang_err)), "view_deg_max": float(np.max(ang_err))}
