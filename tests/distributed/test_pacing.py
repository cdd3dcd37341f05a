"""Server-side keyframe pacing with the 1999 error metric (pure numpy, no GL)."""

import numpy as np
import pytest

from conftest import make_field
from lodsprite.camera import Projection, look_at
from lodsprite.distributed.pacing import PACE_FRACTION, KeyframePacer
from lodsprite.distributed.protocol import encode
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

def test_a_view_where_nothing_can_be_measured_makes_a_keyframe_due(hf):
    """The pacer decides with the keyframe policy's rule: an error that cannot be measured
    (no terrain in view: the metric says ``inf``) is not small, so a keyframe is due, from
    this server and from any other (the shown keyframe does not serve either)."""
    pacer = KeyframePacer(hf, 8, 1.0, HEIGHT, "needed")
    pacer.rendered(eye_at(0.0))
    sky = look_at(eye_at(0.0).o, (0.0, -3000.0, 3000.0))  # turned up, away from the terrain
    assert not pacer.due(eye_at(0.0), PROJ)
    assert pacer.due(sky, PROJ)
    assert pacer.due(sky, PROJ, np.asarray(eye_at(100.0).o), turn=False)


def test_a_shown_keyframe_from_another_server_counts_as_covering(hf):
    """With two servers the client may show the other server's keyframe: a keyframe is due
    only when neither the shown one nor this server's own last one serves the viewpoint."""
    pacer = KeyframePacer(hf, 8, 1.0, HEIGHT, "needed")
    pacer.rendered(eye_at(-700.0))
    moves = np.linspace(-700.0, 700.0, 141)
    step = next(d for d in moves if pacer.due(eye_at(d), PROJ))
    assert -700.0 < step < 700.0
    shown = np.asarray(eye_at(step).o)
    # The client shows a keyframe taken at ``step``: nothing is due there any more ...
    assert not pacer.due(eye_at(step), PROJ, shown)
    # ... until the viewer has left both keyframes behind.
    later = [d for d in moves if d > step and pacer.due(eye_at(d), PROJ, shown)]
    assert later and later[0] > step + 0.5 * (step + 700.0)
    # The client naming this server's own keyframe changes nothing.
    assert pacer.due(eye_at(step), PROJ, np.asarray(eye_at(-700.0).o))


def test_a_server_out_of_turn_renders_only_at_the_full_threshold(hf):
    pacer = KeyframePacer(hf, 8, 1.0, HEIGHT, "needed")
    pacer.rendered(eye_at(-700.0))
    metric = ErrorMetric.for_level(hf, 8)
    c_prime = metric.reproject(eye_at(-700.0).o)
    beta = PROJ.pixel_angle_rad(HEIGHT)
    moves = np.linspace(-700.0, 700.0, 141)
    errors = np.array([metric.error_px(c_prime, eye_at(d).o,
                                       PROJ.matrix() @ eye_at(d).view_matrix(), beta)
                       for d in moves])
    out_of_turn = [pacer.due(eye_at(d), PROJ, turn=False) for d in moves]
    assert out_of_turn == [e >= 1.0 for e in errors]
    assert any(PACE_FRACTION <= e < 1.0 for e in errors)  # where the two rules differ


class _FakeService:
    def __init__(self, pacer):
        self.pacer = pacer

    def projection(self, vp):
        return PROJ


@pytest.mark.parametrize("slot, shown_slot, turn", [(0, 1, True), (1, 0, True),
                                                     (0, 0, False), (1, 1, False)])
def test_two_servers_take_turns_after_the_shown_keyframes_server(hf, slot, shown_slot, turn):
    from lodsprite.distributed.server import LodServer

    server = LodServer(bind="127.0.0.1:59990")
    try:
        reply = server._control([bytes(f) for f in encode(
            {"kind": "control", "seq": 1, "op": "load",
             "args": {"terrain": "fractal:64", "slot": slot, "slots": 2}})])
        assert reply["ok"], reply["error"]
        calls = []

        class Pacer:
            def due(self, vp, proj, eye, turn):
                calls.append((eye, turn))
                return True

        eye = np.asarray(eye_at(0.0).o)
        assert server._producer.due(_FakeService(Pacer()), eye_at(10.0), (eye, shown_slot))
        assert calls[-1][1] is turn and calls[-1][0] is eye
        server._producer.due(_FakeService(Pacer()), eye_at(10.0), None)  # nothing shown yet
        assert calls[-1] == (None, True)
    finally:
        server._ctx.term()
