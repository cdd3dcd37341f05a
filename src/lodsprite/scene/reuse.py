"""The terrain's cost and benefit when its static layers are reused from keyframes a worker
renders (issue 32; Swan et al. 2002's LOD server, Funkhouser & Séquin 1993's cost and
benefit; Maciel & Shirley 1995: impostors as one more level of a time-critical choice).

With ``--keyframes worker`` the terrain layer's knob sets two things together: ε, the
error (pixels) at which the display asks for a new keyframe, and the keyframe tolerance
τ, the adaptive renderer's screen-space error (pixels) the worker draws keyframes at
(:data:`REUSE_SETTINGS`, ascending quality).  The display's own cost hardly depends on
either (a spriteframe is the same proxy whatever ε); what they change is the worker's
work and the error shown:

* :class:`KeyframeRate` - the worker's keyframe time against τ, ``ms(τ) = ms_ref · (τ /
  τ_ref) ** alpha`` refitted from the keyframes delivered (``observe``, as the run goes),
  and so the keyframes it can deliver a second, ``rate(τ) = 1000 / ms(τ)``;
* the view's error growth ``g`` (pixels a second: the shown keyframe's error over its
  age, a moving average) makes ``need(ε) = g / ε`` keyframes a second to hold ε;
* the predicted error of a setting: ``τ + max(ε, f · ε + g / rate(τ))`` pixels: a
  keyframe is asked for at ``f · ε`` (the worker engine's request fraction) and comes
  ``1 / rate`` seconds later, the error growing by ``g / rate`` meanwhile, so a worker
  slower than the view lets the error pass ε; the keyframe itself is τ from level 0;
* its benefit ``coverage · min(1, e_min / error)`` (``e_min`` the finest setting's
  ``τ + ε``: the same unit as :class:`~lodsprite.scene.costs.TerrainBenefit`);
* its cost, the display's ms: ``scale · (a + b · work)`` (:class:`~lodsprite.scene.costs.
  CostModel`), ``work`` the worker's ms a display frame (keyframes a frame at the rate
  the setting gets, ``min(need, rate) · frame_s``, times ``ms(τ)``): the worker shares
  the machine with the display, and ``b`` (fitted from the measured frames) is what a
  millisecond of the worker's costs the display's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lodsprite.scene.costs import CostModel, LayerModel, PowerWork

#: (ε, τ) pixels, ascending quality: ε in √2 steps, τ half of ε (at least 0.5 px).
REUSE_SETTINGS = ((16.0, 8.0), (11.3, 5.7), (8.0, 4.0), (5.7, 2.8), (4.0, 2.0),
                  (2.8, 1.4), (2.0, 1.0), (1.4, 0.71), (1.0, 0.5), (0.71, 0.5), (0.5, 0.5))
GROWTH_GAIN = 0.2   # weight of the newest error-growth sample in its moving average
REQUEST_FRACTION = 0.5  # f: the worker engine's (DEFAULT_REQUEST_FRACTION)


def tolerance_for(epsilon: float) -> float:
    """The keyframe tolerance τ (px) :data:`REUSE_SETTINGS` pairs with ``epsilon`` (the
    nearest ε's)."""
    eps = np.array([e for e, _ in REUSE_SETTINGS])
    return REUSE_SETTINGS[int(np.argmin(np.abs(eps - epsilon)))][1]


@dataclass
class KeyframeRate:
    """The worker's time a keyframe (ms) against the keyframe tolerance τ (px):
    ``ms_ref · (τ / τ_ref) ** alpha`` (``alpha < 0``: a finer tolerance, more triangles);
    ``observe`` refits ``ms_ref`` (a moving average at that τ) and ``alpha`` (from two
    tolerances measured, clamped to ``alpha_range``)."""

    ms_ref: float = 100.0
    tau_ref: float = 1.0
    alpha: float = -0.5
    gain: float = 0.3
    alpha_range: tuple[float, float] = (-3.0, 0.0)
    delivered: int = 0
    _by_tau: dict = field(default_factory=dict, repr=False)

    def ms(self, tau: float) -> float:
        """Predicted worker ms for one keyframe at ``tau``."""
        return self.ms_ref * (max(tau, 1e-3) / self.tau_ref) ** self.alpha

    def rate(self, tau: float) -> float:
        """Keyframes a second the worker can deliver at ``tau``."""
        return 1e3 / max(self.ms(tau), 1e-3)

    def observe(self, tau: float, ms: float) -> None:
        """A keyframe delivered: rendered at ``tau`` in ``ms`` (the worker's clock)."""
        if not (tau > 0 and ms > 0):
            return
        self.delivered += 1
        old = self._by_tau.get(tau)
        self._by_tau[tau] = ms if old is None else float(np.exp(
            (1 - self.gain) * np.log(old) + self.gain * np.log(ms)))
        self.tau_ref, self.ms_ref = float(tau), self._by_tau[tau]
        if len(self._by_tau) >= 2:
            t = np.log(np.array(list(self._by_tau)))
            m = np.log(np.array(list(self._by_tau.values())))
            if np.ptp(t) > 0.05:
                self.alpha = float(np.clip(np.polyfit(t, m, 1)[0], *self.alpha_range))


@dataclass
class ReuseBenefit:
    """``coverage · min(1, e_min / error(v))`` with ``error`` the model's predicted error
    (:meth:`ReuseModel.error_px`)."""

    model: ReuseModel
    coverage: float = 1.0

    def __call__(self, value: float) -> float:
        e_min = min(sum(s) for s in REUSE_SETTINGS)
        return self.coverage * min(1.0, e_min / max(self.model.error_px(value), 1e-9))


@dataclass
class ReuseModel(LayerModel):
    """The reused terrain's :class:`~lodsprite.scene.costs.LayerModel` (module doc):
    ``rate`` the worker's keyframe rate, ``growth_pxs`` the view's error growth (px/s),
    ``frame_s`` the display's frame interval (s, a moving average of measured frames)."""

    rate: KeyframeRate = field(default_factory=KeyframeRate)
    growth_pxs: float = 0.0
    frame_s: float = 0.1

    def need(self, epsilon: float) -> float:
        """Keyframes a second that hold ``epsilon`` at the measured error growth."""
        return self.growth_pxs / max(epsilon, 1e-9)

    def error_px(self, value: float) -> float:
        """Predicted error (px) of the setting whose ε is ``value``."""
        tau = tolerance_for(value)
        late = REQUEST_FRACTION * value + self.growth_pxs / self.rate.rate(tau)
        return tau + max(value, late)

    def worker_ms(self, value: float) -> float:
        """The worker's ms a display frame at the setting ``value``."""
        tau = tolerance_for(value)
        return min(self.need(value), self.rate.rate(tau)) * self.frame_s * self.rate.ms(tau)

    def predict(self, value: float) -> float:
        return self.cost.scale * max(self.cost.raw(self.worker_ms(value)), self.cost.a_min)

    def observe_view(self, error_px: float, age_s: float, frame_s: float) -> None:
        """A frame: the shown keyframe's error ``error_px`` ``age_s`` seconds after it
        was adopted, the frame ``frame_s`` seconds after the one before."""
        g = GROWTH_GAIN
        if age_s > 0 and np.isfinite(error_px):
            self.growth_pxs += g * (error_px / age_s - self.growth_pxs)
        if frame_s > 0:
            self.frame_s += g * (frame_s - self.frame_s)


def reuse_model() -> ReuseModel:
    """A :class:`ReuseModel` with priors (a spriteframe ~1 ms, the worker's ms costing the
    display a fifth of its own); the measurements correct them."""
    model = ReuseModel(CostModel(PowerWork(0.0, fit=False), 1.0, 0.2), None)
    model.benefit = ReuseBenefit(model)
    return model
