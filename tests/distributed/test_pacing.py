"""Server-side keyframe pacing with the 1999 error metric (pure numpy, no GL)."""

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, look_at
from lodsprite.distributed.pacing import PACE_FRACTION, KeyframePacer
from lodsprite.sprite.metric import ErrorMetric

PROJ = Projection(45.0, 1.0, 10.0, 20000.0)
HEIGHT = 256


def eye_at(dx: float):
    return look_at((dx, -1500.0, 1200.0), (dx, 0.0, 0.0))


@pytest.fixture
def hf():
    return make_field(64, kind="ridges", relief=150.0)


def test_continuous_pace_is_always_due(hf):
    pacer = KeyframePacer(hf, 8, 1.0, HEIGHT, "continuous")
    pacer.rendered(eye_at(0.0))
    assert pacer.due(eye_at(0.0), PROJ)


def test_needed_pace_waits_until_the_error_reaches_its_share_of_epsilon(hf):
    pacer = KeyframePacer(hf, 8, 1.0, HEIGHT, "needed")
    assert pacer.due(eye_at(0.0), PROJ)  # nothing rendered yet
    pacer.rendered(eye_at(0.0))
    assert not pacer.due(eye_at(0.0), PROJ)
    # Along a sideways move the first due position is where the metric reaches 0.8 ε.
    metric = ErrorMetric.for_level(hf, 8)
    c_prime = metric.reproject(eye_at(0.0).o)
    beta = PROJ.pixel_angle_rad(HEIGHT)
    moves = np.linspace(0.0, 1200.0, 61)
    errors = [metric.error_px(c_prime, eye_at(d).o, PROJ.matrix() @ eye_at(d).view_matrix(),
                              beta) for d in moves]
    due = [pacer.due(eye_at(d), PROJ) for d in moves]
    assert any(due) and not all(due)
    assert due == [e >= PACE_FRACTION for e in errors]

