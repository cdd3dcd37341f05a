"""The reused terrain's model (issue 32, must-have 5): the worker's keyframe rate learned
from delivered keyframes, each setting's predicted error from that rate and the view's
error growth, and the scheduler choosing by it (hand-made measurements, no GL)."""

from __future__ import annotations

import numpy as np
import pytest

from lodsprite.scene.budget import FrameScheduler, LayerBudget, LayerControl
from lodsprite.scene.reuse import REUSE_SETTINGS, KeyframeRate, reuse_model, tolerance_for

EPS = tuple(e for e, _ in REUSE_SETTINGS)


def test_the_keyframe_rate_is_fitted_from_delivered_keyframes():
    rate = KeyframeRate()
    for _ in range(20):
        rate.observe(1.0, 100.0)
        rate.observe(0.5, 200.0)   # half the tolerance, twice the time
    assert rate.alpha == pytest.approx(-1.0, abs=1e-6)
    assert rate.ms(0.5) == pytest.approx(200.0, rel=1e-6)
    assert rate.rate(2.0) == pytest.approx(1e3 / 50.0, rel=1e-6)  # from the fit, not seen


def test_a_slow_worker_raises_the_predicted_error_of_fine_settings():
    m = reuse_model()
    for _ in range(20):
        m.rate.observe(1.0, 100.0)
        m.rate.observe(0.5, 200.0)
    for _ in range(50):
        m.observe_view(40.0, 1.0, 0.1)   # 40 px a second of error growth
    assert m.growth_pxs == pytest.approx(40.0, rel=1e-3)
    # ε 1 (τ 0.5): asked for at 0.5 px, 200 ms to come at 40 px/s: 8.5 px, past ε
    assert m.error_px(1.0) == pytest.approx(0.5 + 0.5 + 40.0 / 5.0, rel=1e-3)
    # ε 8 (τ 4): 25 ms to come, asked at 4 px: the bound holds
    assert m.error_px(8.0) == pytest.approx(tolerance_for(8.0) + 8.0, rel=1e-3)
    # the finest setting is not the best one: its error, and so its benefit, is worse
    errors = [m.error_px(e) for e in EPS]
    assert int(np.argmin(errors)) < len(EPS) - 1
    m.growth_pxs = 0.0   # a still view: the finest setting is the least error
    assert int(np.argmin([m.error_px(e) for e in EPS])) == len(EPS) - 1


def test_the_scheduler_plans_the_reused_terrain_by_its_predicted_error():
    m = reuse_model()
    for _ in range(20):
        m.rate.observe(1.0, 100.0)
        m.rate.observe(0.5, 200.0)
    m.growth_pxs = 40.0
    value = [EPS[0]]

    def set_value(v: float) -> None:
        value[0] = v

    control = LayerControl("terrain", EPS, EPS[0], set_value, model=lambda: m)
    budget = LayerBudget("scheduler", 1000.0)
    assert isinstance(budget.schedule, FrameScheduler)
    for _ in range(10):   # the dead band: a better plan is taken after its dwell
        budget.before([control])
    best = EPS[int(np.argmax([m.benefit(e) for e in EPS]))]
    assert budget.models["terrain"] is m and value[0] == best
    assert m.error_px(best) < m.error_px(EPS[-1])
