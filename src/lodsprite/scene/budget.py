"""One frame budget over a scene's layers (Funkhouser & Séquin 1993, adaptive display).

Funkhouser & Séquin choose every object's level of detail each frame *predictively*: from
the predicted cost and benefit of each level (:mod:`lodsprite.scene.costs`) they pick the
levels that maximise total benefit within the target frame time, a multiple-choice
knapsack solved greedily (the most benefit per unit cost first, §4.2); predicting, not
correcting after a missed frame, removes reactive feedback's oscillation.  A dead band
round the budget (this module's, against flipping between neighbouring settings on noisy
predictions) keeps the settings unless over budget or a better plan leaves headroom.

* :class:`LayerControl` - what the budget may turn on a layer: one knob, its settings in
  ascending quality (and cost).
* :func:`greedy_plan` - the knapsack: from the cheapest setting of every layer, the
  increment with the highest benefit/cost ratio that fits, until none fits.
* :class:`FrameScheduler` - every frame :meth:`~FrameScheduler.plan` (the knapsack under
  ``target_ms`` minus the frame's measured overhead, with hysteresis), then
  :meth:`~FrameScheduler.observe` each layer's measured ms to rescale its cost model.
* :class:`IndependentFeedback` - the baseline: each layer's own reactive feedback moves
  its knob towards a fixed share of the target; :class:`NoSchedule` - nothing turns.
* :class:`LayerBudget` - what a layered technique runs: a schedule, a model per layer,
  the frame's measurements fed back, the plan's predictions, the summary's shares.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from lodsprite.errors import InputError
from lodsprite.scene.costs import LayerModel, default_model

SCHEDULES = ("scheduler", "independent", "none")
#: :class:`IndependentFeedback`'s default shares of the target by layer (normalised over
#: the layers present).
DEFAULT_SHARES = {"terrain": 0.5, "objects": 0.35, "lightfields": 0.15}


@dataclass
class LayerControl:
    """One layer's knob: ``values`` its settings in ascending quality (and cost; e.g. a
    terrain's ε from coarse to fine, ``(8, 4, 2, 1)`` pixels), ``value`` the current one,
    ``set`` applies a setting to the layer; ``detail`` (optional, the objects layer's)
    gives what its benefit model weighs, ``(lin, cov, coverage[, setting])`` of
    :func:`~lodsprite.scene.costs.object_detail`, called before each plan; ``work``
    (optional, the objects layer's) the layer's predicted counter at every setting
    ``(n,)``; ``coverage`` (optional) its measured screen fraction, its benefit's ``Size``
    (:mod:`lodsprite.layered.coverage`; None before it has one); ``model`` (optional)
    makes the layer's own :class:`~lodsprite.scene.costs.LayerModel` (default: priors)."""

    name: str
    values: tuple[float, ...]
    value: float
    set: Callable[[float], None]
    detail: Callable[[], tuple | None] | None = None
    work: Callable[[], np.ndarray | None] | None = None
    coverage: Callable[[], float | None] | None = None
    model: Callable[[], LayerModel] | None = None

    def index(self, value: float | None = None) -> int:
        """The index in :attr:`values` of ``value`` (default: the current one), or of the
        nearest setting."""
        v = self.value if value is None else value
        return int(np.argmin(np.abs(np.asarray(self.values, np.float64) - v)))


def greedy_plan(costs: list[np.ndarray], benefits: list[np.ndarray], budget_ms: float
                ) -> list[int]:
    """The multiple-choice knapsack, greedily: ``costs[i]``, ``benefits[i]`` ``(n_i,)`` the
    predicted ms and benefit of layer ``i``'s settings (ascending quality).  Every layer
    starts at setting 0; each step takes the move ``j -> k > j`` of one layer with the
    highest ``Δbenefit / Δcost`` whose cost keeps the total within ``budget_ms``
    (ties: the larger ``Δbenefit``), until none does.  Returns each layer's index; if the
    cheapest settings already exceed the budget, all zeros."""
    pick = [0] * len(costs)
    total = float(sum(c[0] for c in costs))
    while True:
        best: tuple[float, float, int, int] | None = None
        for i, (c, b) in enumerate(zip(costs, benefits, strict=True)):
            j = pick[i]
            dc = c[j + 1:] - c[j]
            db = b[j + 1:] - b[j]
            ok = (db > 0) & (total + dc <= budget_ms + 1e-9)
            for k in np.flatnonzero(ok):
                ratio = db[k] / dc[k] if dc[k] > 0 else np.inf
                key = (ratio, db[k], i, j + 1 + int(k))
                if best is None or key[:2] > best[:2]:
                    best = key
        if best is None:
            return pick
        _, _, i, k = best
        total += float(costs[i][k] - costs[i][pick[i]])
        pick[i] = k


class FrameScheduler:
    """Predictive benefit/cost selection of every layer's knob under ``target_ms``.

    Hysteresis, a dead band round the budget: the current settings are replaced at once
    if predicted over ``budget · (1 + tolerance)``, and by a plan of more benefit only if
    that one fits ``budget · (1 - hysteresis)`` for ``dwell`` frames running.
    ``overhead_gain``: the moving average of the frame's time outside the layers
    (:meth:`observe_frame`), taken off the budget.

    The median trim (``trim_gain``; 0: off): settings are discrete and the plan fits under
    the budget, so frames come in under the target by up to a setting's step and by what
    the models over-predict.  After each frame, when the median of the last
    ``trim_window`` frames lies outside ``[1 - trim_band, 1 + trim_band / 2]`` of the
    target, the budget's factor ``1 + trim`` moves ``trim_gain`` of that relative miss
    (``trim`` within ``trim_range``): a slow correction of the predictions' bias toward a
    median at the target, outside the band only, so that a steady scene stays steady."""

    def __init__(self, target_ms: float, hysteresis: float = 0.03, tolerance: float = 0.03,
                 dwell: int = 3, overhead_gain: float = 0.1, trim_gain: float = 0.05,
                 trim_window: int = 30, trim_band: float = 0.03,
                 trim_range: tuple[float, float] = (-0.3, 0.3)) -> None:
        if not (target_ms > 0):
            raise InputError(f"the frame budget must be > 0 ms, got {target_ms}")
        self.target_ms = float(target_ms)
        self.hysteresis, self.tolerance, self.dwell = hysteresis, tolerance, int(dwell)
        self.overhead_gain = overhead_gain
        self.overhead_ms = 0.0
        self.models: Mapping[str, LayerModel] = {}
        self.predicted: dict[str, float] = {}
        self.share_sums: dict[str, float] = {}
        self.plans = 0
        self._wanting = 0
        self.trim_gain, self.trim_band = float(trim_gain), float(trim_band)
        self.trim_range = trim_range
        self.trim = 0.0
        self._recent: deque[float] = deque(maxlen=max(1, int(trim_window)))

    @property
    def budget_ms(self) -> float:
        """The layers' budget this frame: the trimmed target less the measured overhead."""
        return max(self.target_ms * (1.0 + self.trim) - self.overhead_ms, 0.0)

    def plan(self, controls: Iterable[LayerControl], models: Mapping[str, LayerModel]
             ) -> dict[str, float]:
        """Each layer's knob setting for the next frame (also applied with ``set``)."""
        controls = list(controls)
        self.models = models
        tables = [models[c.name].tables(c.values) for c in controls]
        cur = [c.index() for c in controls]
        # a setting other than the current one costs its switch too (CostModel.switch_ms)
        costs = [t[0] + models[c.name].cost.switch_ms * (np.arange(len(t[0])) != k)
                 for t, c, k in zip(tables, controls, cur, strict=True)]
        benefits = [t[1] for t in tables]
        budget = self.budget_ms
        pick = self._hysteresis(cur, costs, benefits, budget)
        out = {}
        for c, k, cost in zip(controls, pick, costs, strict=True):
            v = c.values[k]
            if v != c.value:
                c.set(v)
                c.value = v
            out[c.name] = v
            self.predicted[c.name] = float(cost[k])
            self.share_sums[c.name] = self.share_sums.get(c.name, 0.0) + cost[k] / self.target_ms
        self.plans += 1
        return out

    def _hysteresis(self, cur: list[int], costs, benefits, budget: float) -> list[int]:
        """A dead band round the budget: over ``budget · (1 + tolerance)`` the plan under
        the budget replaces the current settings at once; a plan of more benefit under
        ``budget · (1 - hysteresis)`` (headroom) replaces them after ``dwell`` frames."""
        cost_cur = sum(float(c[k]) for c, k in zip(costs, cur, strict=True))
        if cost_cur > budget * (1 + self.tolerance):
            self._wanting = 0
            return greedy_plan(costs, benefits, budget)  # over budget: change now
        up = greedy_plan(costs, benefits, budget * (1 - self.hysteresis))
        gain = sum(float(b[k]) - float(b[j]) for b, k, j in zip(benefits, up, cur, strict=True))
        if gain > 1e-12:
            self._wanting += 1
            if self._wanting >= self.dwell:
                self._wanting = 0
                return up
        else:
            self._wanting = 0
        return cur

    def observe(self, layer: str, value: float, ms: float, work: float | None = None
                ) -> None:
        """After the frame: layer ``layer`` took ``ms`` at knob ``value`` (``work``: its
        counter, e.g. triangles); rescales that layer's cost model."""
        if layer in self.models:
            self.models[layer].cost.observe(value, ms, work)

    def observe_frame(self, frame_ms: float, layers_ms: float) -> None:
        """After the frame: the whole frame took ``frame_ms``, its layers ``layers_ms``."""
        extra = max(frame_ms - layers_ms, 0.0)
        self.overhead_ms += self.overhead_gain * (extra - self.overhead_ms)
        self._recent.append(float(frame_ms))
        if self.trim_gain > 0 and len(self._recent) == self._recent.maxlen:
            m = float(np.median(self._recent)) / self.target_ms
            if m < 1.0 - self.trim_band or m > 1.0 + self.trim_band / 2:
                self.trim = float(np.clip(self.trim + self.trim_gain * (1.0 - m),
                                          *self.trim_range))

    def shares(self) -> dict[str, float]:
        """Each layer's mean planned share of the target so far (fractions)."""
        return {k: v / max(self.plans, 1) for k, v in self.share_sums.items()}


class IndependentFeedback:
    """Today's behaviour, the baseline: each layer's own reactive feedback drives its knob
    towards ``shares[layer] · target_ms`` (shares default to :data:`DEFAULT_SHARES`
    normalised over the layers planned).  After each frame the knob's position (in
    settings, ascending quality) moves by ``-gain · log2(ms / share_ms)`` (the LODManager's
    log-domain frame-rate feedback), and the nearest setting is used."""

    def __init__(self, target_ms: float, shares: Mapping[str, float] | None = None,
                 gain: float = 0.5) -> None:
        if not (target_ms > 0):
            raise InputError(f"the frame budget must be > 0 ms, got {target_ms}")
        if shares is not None and any(not (s > 0) for s in shares.values()):
            raise InputError(f"layer shares must be > 0, got {dict(shares)}")
        self.target_ms, self.gain = float(target_ms), float(gain)
        self.fixed = dict(shares) if shares is not None else None
        self.position: dict[str, float] = {}
        self.controls: dict[str, LayerControl] = {}

    def share(self, layer: str) -> float:
        """``layer``'s fixed share of the target (fraction)."""
        names = list(self.controls) or [layer]
        base = self.fixed if self.fixed is not None else {
            n: DEFAULT_SHARES.get(n, 0.2) for n in names}
        total = sum(base.get(n, 0.0) for n in names) or 1.0
        return base.get(layer, 0.0) / total

    def plan(self, controls: Iterable[LayerControl],
             models: Mapping[str, LayerModel] | None = None) -> dict[str, float]:
        """Each layer's knob setting from its own feedback (``models`` unused)."""
        out = {}
        for c in controls:
            self.controls[c.name] = c
            pos = self.position.setdefault(c.name, float(c.index()))
            v = c.values[int(np.clip(round(pos), 0, len(c.values) - 1))]
            if v != c.value:
                c.set(v)
                c.value = v
            out[c.name] = v
        return out

    def observe(self, layer: str, value: float, ms: float, work: float | None = None
                ) -> None:
        """After the frame: move ``layer``'s knob position towards its share."""
        c = self.controls.get(layer)
        if c is None or not (ms > 0):
            return
        share_ms = self.share(layer) * self.target_ms
        step = -self.gain * float(np.log2(ms / max(share_ms, 1e-6)))
        self.position[layer] = float(np.clip(self.position[layer] + step, 0,
                                             len(c.values) - 1))

    def observe_frame(self, frame_ms: float, layers_ms: float) -> None:
        """Unused: each layer watches its own time."""

    def shares(self) -> dict[str, float]:
        return {n: self.share(n) for n in self.controls}


class NoSchedule:
    """No budget: every knob stays at its setting."""

    target_ms = float("nan")

    def plan(self, controls: Iterable[LayerControl],
             models: Mapping[str, LayerModel] | None = None) -> dict[str, float]:
        return {c.name: c.value for c in controls}

    def observe(self, layer: str, value: float, ms: float, work: float | None = None
                ) -> None:
        pass

    def observe_frame(self, frame_ms: float, layers_ms: float) -> None:
        pass

    def shares(self) -> dict[str, float]:
        return {}


def make_schedule(kind: str, target_ms: float | None,
                  shares: Mapping[str, float] | None = None
                  ) -> FrameScheduler | IndependentFeedback | NoSchedule:
    """The schedule ``kind`` names (:data:`SCHEDULES`); ``target_ms`` is required unless
    ``kind`` is ``none``."""
    if kind not in SCHEDULES:
        raise InputError(f"unknown schedule {kind!r}: use one of {', '.join(SCHEDULES)}")
    if kind == "none":
        return NoSchedule()
    if target_ms is None:
        raise InputError(f"schedule {kind!r} needs a target frame rate (--target-fps)")
    if kind == "scheduler":
        return FrameScheduler(target_ms)
    return IndependentFeedback(target_ms, shares)


class LayerBudget:
    """The budget a layered technique runs each frame: the ``schedule`` (:data:`SCHEDULES`)
    under ``target_ms``, a :class:`~lodsprite.scene.costs.LayerModel` per layer (priors
    from :func:`~lodsprite.scene.costs.default_model`, made on the layer's first frame),
    and the per-layer sums :meth:`summary` reports.

    Per frame: ``before(controls)`` sets every knob, the layers draw, then ``after({name:
    (value, ms, work)}, frame_ms)`` feeds the measurements back and returns the frame's
    ``predicted_ms_<layer>`` columns.  A layer may refine its benefit model between
    frames (``models["objects"].benefit.update(lin, cov)``, ``benefit.coverage = ...``)."""

    def __init__(self, schedule: str = "none", target_ms: float | None = None,
                 shares: Mapping[str, float] | None = None) -> None:
        self.kind = schedule
        self.schedule = make_schedule(schedule, target_ms, shares)
        self.models: dict[str, LayerModel] = {}
        self.ms_sums: dict[str, float] = {}
        self.last_knob: dict[str, float] = {}
        self.changes: dict[str, int] = {}
        self.knob_sums: dict[str, np.ndarray] = {}   # (n, Σ value, Σ value²) a layer
        self.frame_ms_sum, self.frames = 0.0, 0
        self.predicted: dict[str, float] = {}  # ms each layer's setting was planned at

    @property
    def target_ms(self) -> float:
        return self.schedule.target_ms

    def before(self, controls: Iterable[LayerControl]) -> dict[str, float]:
        """Plan and apply every layer's knob for the coming frame."""
        controls = list(controls)
        for c in controls:
            if c.name not in self.models:
                self.models[c.name] = (c.model() if c.model is not None
                                       else default_model(c.name, tuple(c.values)))
            benefit = self.models[c.name].benefit
            if c.detail is not None and hasattr(benefit, "update"):
                seen = c.detail()
                if seen is not None:
                    benefit.update(*seen)
            if c.coverage is not None and (size := c.coverage()) is not None:
                benefit.coverage = float(size)
            if c.work is not None:
                w = c.work()
                self.models[c.name].work_table = (None if w is None else
                                                  (tuple(c.values), np.asarray(w, np.float64)))
        plan = self.schedule.plan(controls, self.models)
        planned = getattr(self.schedule, "predicted", {})  # the scheduler's, switch included
        self.predicted = {n: float(planned[n]) if n in planned else self.models[n].planned(
            v, self.last_knob.get(n, v)) for n, v in plan.items()}
        return plan

    def after(self, layers: Mapping[str, tuple[float, float, float | None]],
              frame_ms: float) -> dict[str, float]:
        """The frame's measurements: ``layers[name] = (knob value, ms, work counter or
        None)``, ``frame_ms`` the whole frame; returns ``predicted_ms_<layer>``: what
        :meth:`before` predicted for the setting drawn (the scheduler's plan, its switch
        cost included; without one the same sum, :meth:`~lodsprite.scene.costs.
        LayerModel.planned`)."""
        out = {f"predicted_ms_{n}": self.predicted[n] for n in layers if n in self.predicted}
        for name, (value, ms, work) in layers.items():
            self.schedule.observe(name, value, ms, work)
            if name in self.models and work is not None:
                self.models[name].observe_work(value, work)
            self.ms_sums[name] = self.ms_sums.get(name, 0.0) + float(ms)
            last = self.last_knob.get(name, value)
            self.changes[name] = self.changes.get(name, 0) + int(value != last)
            self.last_knob[name] = value
            self.knob_sums.setdefault(name, np.zeros(3))[:] += (1.0, value, value * value)
        self.schedule.observe_frame(frame_ms, sum(ms for _, ms, _ in layers.values()))
        self.frame_ms_sum += float(frame_ms)
        self.frames += 1
        return out

    def summary(self) -> dict[str, float | int | str]:
        """``schedule``, ``target_ms`` (NaN without one), ``share_<layer>`` (the layer's
        measured fraction of the frame time, mean ms over mean frame ms) and, under a
        schedule, ``budget_share_<layer>`` (the share of the target it was given: the
        scheduler's mean planned share, the independent feedback's fixed share);
        ``knob_changes_<layer>``: frames whose knob differed from the frame before, and
        ``knob_std_<layer>`` the standard deviation of its setting (oscillation)."""
        out: dict[str, float | int | str] = {"schedule": self.kind, "target_ms": self.target_ms}
        total = max(self.frame_ms_sum, 1e-9)
        for name, ms in self.ms_sums.items():
            out[f"share_{name}"] = ms / total
            out[f"knob_changes_{name}"] = self.changes.get(name, 0)
            n, s1, s2 = self.knob_sums[name]
            out[f"knob_std_{name}"] = float(np.sqrt(max(s2 / n - (s1 / n) ** 2, 0.0)))
        for name, share in self.schedule.shares().items():
            out[f"budget_share_{name}"] = float(share)
        return out


def steadiness(knobs: np.ndarray, frame_ms: np.ndarray) -> dict[str, float]:
    """Oscillation of a run: ``knobs (frames,)`` one layer's knob settings,
    ``frame_ms (frames,)`` frame times -> ``changes`` (frames whose knob differs from the
    one before), ``knob_std`` and ``ms_std`` (standard deviations)."""
    k = np.asarray(knobs, np.float64)
    return {"changes": float(np.count_nonzero(np.diff(k))) if len(k) else 0.0,
            "knob_std": float(k.std()) if len(k) else 0.0,
            "ms_std": float(np.std(frame_ms)) if len(frame_ms) else 0.0}
