"""Frame-time feedback on a technique's knob (lodsprite.feedback.KnobFeedback)."""

from __future__ import annotations

import math

import pytest

from lodsprite.errors import InputError
from lodsprite.feedback import KnobFeedback
from lodsprite.techniques.base import Param


class Knobbed:
    """A technique stand-in whose frame time is ``work / sse`` ms."""

    name = "knobbed"

    def __init__(self, sse: float = 1.0, work: float = 60.0) -> None:
        self.sse, self.work = sse, work

    def params(self):
        return {"sse": Param("sse", self.sse, 0.125, 64.0, 1.25, "px")}

    def set_param(self, name, value):
        self.sse = value

    def frame_ms(self) -> float:
        return self.work / self.sse


def test_feedback_settles_the_frame_time_on_its_target():
    t = Knobbed()
    f = KnobFeedback(t, "sse", target_ms=15.0)
    for _ in range(40):
        f.after(t.frame_ms())
    assert t.frame_ms() == pytest.approx(15.0, rel=0.01)
    assert len(f.values) == 40 and f.values[0] == 1.0


def test_a_frame_over_budget_makes_the_knob_cheaper_and_one_under_richer():
    t = Knobbed(sse=2.0)
    f = KnobFeedback(t, "sse", target_ms=10.0, gain=0.5)
    f.after(40.0)  # four times over: log2 4 = 2, half of it: one doubling
    assert t.sse == pytest.approx(4.0)
    f.after(2.5)   # four times under: halved again
    assert t.sse == pytest.approx(2.0)
    g = KnobFeedback(t, "sse", target_ms=10.0, cheaper_up=False)
    g.after(40.0)
    assert t.sse == pytest.approx(1.0)


def test_the_knob_stays_within_its_bounds():
    t = Knobbed(sse=32.0)
    f = KnobFeedback(t, "sse", target_ms=1.0)
    for _ in range(10):
        f.after(1000.0)
    assert t.sse == 64.0
    for _ in range(40):
        f.after(1e-3)
    assert t.sse == 0.125 and math.isfinite(t.sse)


def test_an_unknown_knob_or_a_bad_target_is_an_input_error():
    with pytest.raises(InputError, match="no parameter 'lod'"):
        KnobFeedback(Knobbed(), "lod", 10.0)
    with pytest.raises(InputError, match="> 0 ms"):
        KnobFeedback(Knobbed(), "sse", 0.0)
