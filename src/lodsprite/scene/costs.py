"""Per-layer cost and benefit models for one frame budget (Funkhouser & Séquin 1993, §4).

Funkhouser & Séquin predict, for every object ``O`` at level ``L``, a ``Cost(O, L)``
(seconds to draw it, from a model of the renderer calibrated by measurement) and a
``Benefit(O, L) = Size(O) · Accuracy(O, L) · ...`` (its contribution to the image: the
pixels it covers times how well the level renders them), and choose the levels under a
frame-time budget (:mod:`lodsprite.scene.budget`).  Here the "objects" are the layers of
a scene frame and the "levels" the settings of each layer's knob
(:class:`~lodsprite.scene.budget.LayerControl`):

* :class:`PowerWork` - the layer's work (its own counter) at a knob value, predicted
  from the last measured one: ``work(v) = w_ref · (v / v_ref) ** alpha`` with ``alpha``
  refitted from pairs of measurements (terrain: triangles against ε or the tolerance,
  ``alpha < 0``: -2 for a fine mesh in the limit, -0.2 measured on a small one;
  LOD-sprite: keyframes a frame against ε; objects: triangles against the LODManager's
  exponent, ``alpha < 0``; light fields: nodes drawn against the node budget, ``alpha =
  1``).
* :class:`CostModel` - ``ms(v) = scale · (a + b · work(v))``: ``a``, ``b`` fitted by least
  squares over the recent ``(work, ms)`` samples once they span a range of work (the
  lumigraph's ``raster_base + raster_node · nodes``, the adaptive renderer's ms per
  triangle), and ``scale`` the component's own factor, an exponential moving average
  (gain 0.25; the lumigraph's is 0.3) of measured over predicted ms in the log domain
  (the lumigraph's per-component rescale, Sloan et al. 1997 §5.2: one factor for
  everything caused spikes).
* Benefit models in one unit, *coverage-weighted detail fraction*: ``coverage`` (the
  fraction of the screen the layer covers, 0..1, Funkhouser's ``Size``) times a quality
  ``q(v)`` in 0..1, 1 at full detail (Funkhouser's ``Accuracy``).
  :class:`TerrainBenefit`: ``q = min(1, finest / ε)`` (screen-space error relative to the
  finest setting); :class:`ObjectsBenefit`: ``q = Σ cov_i · lin_i ** p / Σ cov_i``, the
  LOD factor each visible object shows under exponent ``p`` (:func:`~lodsprite.manager.
  core.desired_lod`) weighted by its screen coverage; :class:`LightfieldBenefit`:
  ``q = 1 - 2 ** (-n / n_half)``, diminishing returns of drawn nodes (the lumigraph's
  benefit falls off with a node's distance from the eye's st point).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lodsprite.errors import InputError


@dataclass
class PowerWork:
    """A layer's work (triangles, keyframes a frame, nodes) at a knob value: ``w_ref ·
    (v / v_ref) ** alpha``, the reference the last measurement; ``fit``: refit ``alpha``
    (clamped to ``alpha_range``) from the last two measurements at different values."""

    alpha: float
    v_ref: float = 1.0
    w_ref: float = 1.0
    fit: bool = True
    alpha_range: tuple[float, float] = (-4.0, 4.0)
    gain: float = 0.5
    _last: tuple[float, float] | None = field(default=None, repr=False)

    def predict(self, value: float) -> float:
        """Predicted work at ``value`` (the work unit of the counter observed)."""
        if self.v_ref <= 0 or value <= 0:
            return self.w_ref
        return self.w_ref * (value / self.v_ref) ** self.alpha

    def observe(self, value: float, work: float) -> None:
        """A measurement: the counter read ``work`` with the knob at ``value``."""
        if not (value > 0 and work > 0):
            return
        if self.fit and self._last is not None:
            v0, w0 = self._last
            dv = np.log(value / v0)
            if abs(dv) > 0.05:
                a = float(np.clip(np.log(work / w0) / dv, *self.alpha_range))
                self.alpha += self.gain * (a - self.alpha)
        self._last = (float(value), float(work))
        self.v_ref, self.w_ref = float(value), float(work)


@dataclass
class CostModel:
    """A layer's frame time (ms) at a knob value: ``scale · (a + b · work(v))``.

    ``observe`` takes the measured ms (and the layer's counter, if it has one): the work
    model follows the counter, ``scale`` moves ``gain`` of the way (log domain) towards
    measured / unscaled prediction, and every ``refit_every`` samples whose work spans at
    least ``spread``× ``a`` and ``b`` are refitted (least squares over the last ``window``
    samples, ``b >= 0``, ``a >= a_min``: no layer is free, and a layer with nothing to draw
    must not blow its scale up) and ``scale`` restarts at 1.

    A frame whose knob differs from the last one observed is a switch: what it costs over
    the prediction (the LODManager's extractions after a new exponent, a new ε's tiles)
    moves ``switch_ms`` (``switch_gain`` of the way) and neither the scale nor the fit:
    the transient is kept apart from the steady cost, and the scheduler adds it to any
    setting but the current one."""

    work: PowerWork
    a: float = 0.5
    b: float = 1e-4
    gain: float = 0.25
    a_min: float = 0.2
    scale: float = 1.0
    window: int = 64
    refit_every: int = 32
    spread: float = 1.5
    switch_ms: float = 0.0
    switch_gain: float = 0.3
    samples: deque = field(default_factory=deque, repr=False)
    _since_fit: int = field(default=0, repr=False)
    _value: float | None = field(default=None, repr=False)

    def raw(self, work: float) -> float:
        """Unscaled ms at ``work`` units."""
        return self.a + self.b * work

    def predict(self, value: float) -> float:
        """Predicted ms at knob ``value``, rescaled."""
        return self.scale * self.raw(self.work.predict(value))

    def observe(self, value: float, ms: float, work: float | None = None) -> None:
        """One frame of the layer: knob ``value``, measured ``ms``, counter ``work``."""
        if not (ms > 0):
            return
        if work is not None:
            self.work.observe(value, work)
        w = self.work.predict(value) if work is None else float(work)
        switched = self._value is not None and value != self._value
        self._value = value
        if switched:
            excess = max(float(ms) - self.scale * max(self.raw(w), self.a_min), 0.0)
            self.switch_ms += self.switch_gain * (excess - self.switch_ms)
            return
        ratio = float(np.clip(ms / max(self.raw(w), self.a_min), 0.02, 50.0))
        self.scale = float(np.exp((1 - self.gain) * np.log(self.scale)
                                  + self.gain * np.log(ratio)))
        self.samples.append((w, float(ms)))
        while len(self.samples) > self.window:
            self.samples.popleft()
        self._since_fit += 1
        if self._since_fit >= self.refit_every:
            self._since_fit = 0
            self.refit()

    def refit(self) -> bool:
        """Refit ``a`` and ``b`` from the samples if their work spans ``spread``×;
        True if refitted."""
        if len(self.samples) < 4:
            return False
        w, ms = np.array(self.samples).T
        if w.min() <= 0 or w.max() < self.spread * w.min():
            return False
        b, a = np.polyfit(w, ms, 1)
        if b < 0:
            a, b = float(np.median(ms)), 0.0
        elif a < self.a_min:   # no layer is free: through (0, a_min) instead
            a = self.a_min
            b = float(max(((ms - a) * w).sum() / (w * w).sum(), 0.0))
        self.a, self.b = float(a), float(b)
        self.scale = 1.0
        return True


@dataclass
class TerrainBenefit:
    """Terrain: ``coverage · min(1, finest / ε)`` for an error knob (ε or tolerance,
    pixels: smaller is finer), ``coverage · min(1, level / finest)`` for a resolution knob
    (``resolution=True``: LOD level in quads, larger is finer); ``finest`` the finest
    setting offered."""

    finest: float
    coverage: float = 1.0
    resolution: bool = False

    def __call__(self, value: float) -> float:
        v = max(float(value), 1e-9)
        q = v / self.finest if self.resolution else self.finest / v
        return self.coverage * min(1.0, q)


@dataclass
class ObjectsBenefit:
    """Objects: ``coverage · Σ_drawn cov_i · lin_i ** p / Σ cov_i`` for LOD exponent ``p``.

    ``lin (k,)``: each visible object's distance-linear LOD factor in 0..1, ``cov (k,)``
    its projected screen area (pixels), set by :meth:`update` from the layer's frame;
    before the first update a uniform spread of factors stands in (``q = 1 / (p + 1)``).
    ``setting`` maps a knob value to ``(p, smallest size drawn, px)`` (the objects layer's
    draw counts: an object culled adds nothing), ``size (k,)`` each object's projected
    size (px; default the diameter of its ``cov``); default ``(value, 0)``."""

    coverage: float = 0.1
    lin: np.ndarray | None = None
    cov: np.ndarray | None = None
    setting: Callable[[float], tuple[float, float]] | None = None
    size: np.ndarray | None = None

    def update(self, lin: np.ndarray, cov: np.ndarray, coverage: float | None = None,
               setting: Callable[[float], tuple[float, float]] | None = None,
               size: np.ndarray | None = None) -> None:
        """The visible objects' LOD factors, screen areas (and sizes) this frame."""
        self.lin = np.clip(np.asarray(lin, np.float64), 0.0, 1.0)
        self.cov = np.asarray(cov, np.float64)
        self.size = (2.0 * np.sqrt(self.cov / np.pi) if size is None
                     else np.asarray(size, np.float64))
        if coverage is not None:
            self.coverage = float(coverage)
        if setting is not None:
            self.setting = setting

    def __call__(self, value: float) -> float:
        p, px = (float(value), 0.0) if self.setting is None else self.setting(float(value))
        p = max(p, 1e-6)
        if self.lin is None or self.cov is None or not len(self.lin) or self.cov.sum() <= 0:
            return self.coverage / (p + 1.0)
        drawn = self.size >= px
        return self.coverage * float((self.cov * self.lin ** p)[drawn].sum() / self.cov.sum())


def object_detail(centres: np.ndarray, radii: np.ndarray, eye: np.ndarray,
                  visible: np.ndarray, range_near: float, range_far: float, fov_y_deg: float,
                  size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """What :class:`ObjectsBenefit` weighs, for the visible objects: ``centres (N, 3)``,
    ``radii (N,)`` bounding spheres (metres), ``eye (3,)``, ``visible (N,) bool``, the
    LODManager's ranges (metres), the vertical field of view and the image ``size`` (w, h)
    -> ``lin (k,)`` distance-linear LOD factors in 0..1 (§4.2 of Gumbau et al.), ``cov
    (k,)`` projected sphere areas (pixels) and the fraction of the screen they cover
    (their sum over the image's area, overlaps ignored, at most 1)."""
    c = np.asarray(centres, np.float64)[visible]
    r = np.asarray(radii, np.float64)[visible]
    d = np.maximum(np.linalg.norm(c - np.asarray(eye, np.float64), axis=1), 1e-3)
    lin = np.clip(1.0 - (d - range_near) / max(range_far - range_near, 1e-9), 0.0, 1.0)
    focal = size[1] / 2 / np.tan(np.radians(fov_y_deg) / 2)
    cov = np.pi * (r * focal / d) ** 2
    return lin, cov, float(min(1.0, cov.sum() / (size[0] * size[1])))


@dataclass
class LightfieldBenefit:
    """Light fields: ``coverage · (1 - 2 ** (-n / n_half))`` for a node budget ``n``."""

    n_half: float = 9.0
    coverage: float = 0.05

    def __call__(self, value: float) -> float:
        return self.coverage * (1.0 - 2.0 ** (-max(float(value), 0.0) / self.n_half))


@dataclass
class LayerModel:
    """What the scheduler knows of a layer: its ``cost`` and ``benefit`` models, and
    ``work_table`` (``(values, work (n,))``, optional): the layer's own prediction of its
    counter at every setting (the objects layer's triangles from the objects in view),
    which replaces the power law of ``cost.work`` where given (Funkhouser & Séquin's cost
    from each level's triangle count), times ``work_ratio``: the moving average (log
    domain, gain ``work_gain``) of the counter measured over the table's prediction for
    the setting drawn (what the table misses: LODs still being updated, a type's own
    LOD rule)."""

    cost: CostModel
    benefit: TerrainBenefit | ObjectsBenefit | LightfieldBenefit
    work_table: tuple[tuple[float, ...], np.ndarray] | None = None
    work_ratio: float = 1.0
    work_gain: float = 0.3

    def table_work(self, value: float) -> float | None:
        """The work table's counter at ``value``, uncorrected (None: no table, or no such
        setting in it)."""
        if self.work_table is None:
            return None
        values, work = self.work_table
        for v, w in zip(values, work, strict=True):
            if abs(v - value) < 1e-9:
                return float(w)
        return None

    def observe_work(self, value: float, work: float) -> None:
        """The counter measured at ``value``: corrects :attr:`work_ratio`."""
        w = self.table_work(value)
        if w is None or not (w > 0 and work > 0):
            return
        ratio = float(np.clip(work / w, 0.05, 20.0))
        self.work_ratio = float(np.exp((1 - self.work_gain) * np.log(self.work_ratio)
                                       + self.work_gain * np.log(ratio)))

    def predict(self, value: float) -> float:
        """Predicted ms at knob ``value``."""
        w = self.table_work(value)
        if w is not None:
            return self.cost.scale * max(self.cost.raw(w * self.work_ratio), self.cost.a_min)
        return self.cost.predict(value)

    def planned(self, value: float, current: float) -> float:
        """What a plan predicts the layer costs at knob ``value`` coming from ``current``
        (ms): the steady cost plus the switch cost (``CostModel.switch_ms``) if the
        setting changes."""
        return float(self.predict(value)) + self.cost.switch_ms * (value != current)

    def tables(self, values: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Predicted ms and benefit of every knob setting, two ``(n,)`` float64 arrays."""
        return (np.array([self.predict(v) for v in values]),
                np.array([self.benefit(v) for v in values]))


def default_model(name: str, values: tuple[float, ...]) -> LayerModel:
    """Priors for a layer named ``terrain``, ``objects`` or ``lightfields`` (the names
    LayeredTechnique gives) whose knob takes ``values``; measurements correct them."""
    if not values:
        raise InputError(f"layer {name!r} offers no knob settings")
    # priors from ``benchmarks/scene_budget.py calibrate`` (llvmpipe, 128², loaded
    # machine): ~0.15-0.3 µs a triangle for both; triangles ~ ε^-0.2 on fractal:1024's
    # few levels, ~ p^-0.15 for the 300-ogre crowd, ~ level² for a LOD level (the
    # online fit takes over)
    if name == "terrain":    # values ascending in quality: ε falls, a LOD level rises
        resolution = len(values) > 1 and values[-1] > values[0]
        return LayerModel(CostModel(PowerWork(2.0 if resolution else -0.5, values[-1], 2e5),
                                    1.0, 2e-4),
                          TerrainBenefit(values[-1], resolution=resolution))
    if name == "objects":
        return LayerModel(CostModel(PowerWork(-0.2, 1.0, 2e5), 1.0, 2e-4),
                          ObjectsBenefit())
    if name == "lightfields":  # raster_base + raster_node · nodes
        return LayerModel(CostModel(PowerWork(1.0, 1.0, 1.0, fit=False), 1.0, 0.2),
                          LightfieldBenefit())
    raise InputError(f"no cost model for layer {name!r}: use terrain, objects, lightfields")
