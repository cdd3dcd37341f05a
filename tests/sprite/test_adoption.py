"""The one adoption rule (lodsprite.sprite.adoption): each mode's decision, errors taken
lazily and only when the rule needs them, and the cap refusing a keyframe in every mode."""

from __future__ import annotations

import pytest

from lodsprite.errors import InputError
from lodsprite.sprite.adoption import ADOPT_FRACTION, AdoptionRule


class Calls:
    def __init__(self, value: float) -> None:
        self.value, self.n = value, 0

    def __call__(self) -> float:
        self.n += 1
        return self.value


@pytest.mark.parametrize("mode, shown, new, want", [
    ("newest", 0.1, 9.0, True),                     # the paper: every newer keyframe
    ("needed", 0.4, 0.0, False),                    # under ADOPT_FRACTION ε: kept
    ("needed", ADOPT_FRACTION, 9.0, True),          # at it: replaced
    ("better", 2.0, 1.0, True),
    ("better", 1.0, 2.0, False),                    # a late keyframe worse than the shown
    ("better", float("inf"), 1.0, True),
])
def test_each_mode_decides_as_stated(mode, shown, new, want):
    s, n = Calls(shown), Calls(new)
    assert AdoptionRule(mode, 1.0).adopt(s, n) is want
    assert s.n <= 1 and n.n <= 1
    assert n.n == (1 if mode == "better" else 0)  # taken only where it decides
    assert s.n == (0 if mode == "newest" else 1)


@pytest.mark.parametrize("mode", ["newest", "needed", "better"])
def test_the_cap_refuses_a_keyframe_whatever_the_mode_and_nothing_shown_takes_it(mode):
    rule = AdoptionRule(mode, 1.0, max_error=4.0)
    assert rule.compares
    assert rule.adopt(Calls(100.0), Calls(4.0)) is False
    assert rule.adopt(None, Calls(3.9)) is True
    assert AdoptionRule(mode).adopt(None, Calls(1e9)) is True
    assert AdoptionRule("newest").compares is False


def test_an_unknown_mode_is_one_line():
    with pytest.raises(InputError, match="adopt must be one of"):
        AdoptionRule("sometimes")
