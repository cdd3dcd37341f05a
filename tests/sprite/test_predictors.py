import numpy as np
import pytest

from lodsprite.camera import Viewpoint, look_at
from lodsprite.sprite.predictors import (
    DecayLinearPredictor,
    KalmanPredictor,
    prediction_error,
)


def straight(n=40, dt=0.05):
    t = np.arange(n) * dt
    start = look_at((0.0, -2000.0, 400.0), (0.0, 0.0, 0.0))
    v = np.array([30.0, 45.0, -5.0])  # metres per second
    return t, [Viewpoint(start.x, start.y, start.z, start.o + v * ti) for ti in t], v


@pytest.mark.parametrize("predictor", [DecayLinearPredictor(), KalmanPredictor()])
def test_straight_constant_speed_path_is_predicted_exactly(predictor):
    t, vps, v = straight()
    for ti, vp in zip(t, vps, strict=True):
        predictor.observe(float(ti), vp)
    pred = predictor.predict(0.7)
    np.testing.assert_allclose(pred.o, vps[-1].o + 0.7 * v, atol=1e-3)
    for k in "xyz":
        np.testing.assert_allclose(getattr(pred, k), getattr(vps[-1], k), atol=1e-9)


def circle(n=200, dt=0.05, radius=3000.0, period=20.0):
    t = np.arange(n) * dt
    a = 2 * np.pi * t / period
    vps = [look_at((radius * np.cos(x), radius * np.sin(x), 800.0), (0.0, 0.0, 0.0)) for x in a]
    return t, vps


def test_errors_on_a_curve_are_reported_and_bounded():
    t, vps = circle()
    lead = 10  # half a second ahead
    linear = prediction_error(DecayLinearPredictor(), t, vps, lead)
    kalman = prediction_error(KalmanPredictor(), t, vps, lead)
    speed = 2 * np.pi * 3000.0 / 20.0
    for err in (linear, kalman):
        assert 0 < err["eye_m_mean"] < 0.05 * speed * 0.5 * lead
        assert np.isfinite(err["view_deg_max"])
    # Kalman extrapolates the turn of the orientation; the paper's keeps the latest.
    assert kalman["view_deg_mean"] < linear["view_deg_mean"]



def test_the_keyframe_worker_starts_without_scipy_spatial():
    """``scipy.spatial`` (0.55 s of every process start) comes in only when a rotation is
    predicted, not with the predictors' module (it did before)."""
    from conftest import imported_by

    code = "import lodsprite.sprite.keyframe_worker, lodsprite.sprite.predictors"
    assert imported_by(code, ("scipy.spatial",)) == []
