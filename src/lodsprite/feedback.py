"""Frame-time feedback on one knob of a technique: what holds a renderer to a display rate
when nothing predicts its cost.

After each frame the knob moves in the log domain by ``gain · log2(ms / target_ms)``
(the LODManager's frame-rate feedback, :class:`lodsprite.scene.budget.IndependentFeedback`'s
rule on a continuous knob): a frame over its budget makes the knob cheaper (a larger
screen-space tolerance, say), one under it richer, clamped to the knob's bounds
(:class:`~lodsprite.techniques.Param`).  The played loop calls :meth:`KnobFeedback.after`
outside the frame's clock (:func:`lodsprite.playback.run_played`'s ``control``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from lodsprite.errors import InputError

if TYPE_CHECKING:
    from lodsprite.techniques.base import Technique


class KnobFeedback:
    """Holds ``technique`` near ``target_ms`` a frame by its parameter ``knob``;
    ``cheaper_up``: a larger value is cheaper (a tolerance; False for a detail level).
    ``values`` keeps the setting each frame was drawn with."""

    def __init__(self, technique: Technique, knob: str, target_ms: float, gain: float = 0.5,
                 cheaper_up: bool = True) -> None:
        if not target_ms > 0:
            raise InputError(f"a frame-time target must be > 0 ms, got {target_ms}")
        params = technique.params()
        if knob not in params:
            raise InputError(f"{technique.name} has no parameter {knob!r} to control; it has "
                             f"{', '.join(params) or 'none'}")
        self.technique, self.knob = technique, knob
        self.target_ms, self.gain = float(target_ms), float(gain)
        self.sign = 1.0 if cheaper_up else -1.0
        self.values: list[float] = []

    @property
    def value(self) -> float:
        return float(self.technique.params()[self.knob].value)

    def after(self, ms: float) -> None:
        """The frame just drawn took ``ms``: move the knob for the next one."""
        p = self.technique.params()[self.knob]
        self.values.append(float(p.value))
        if not ms > 0:
            return
        step = self.sign * self.gain * math.log2(ms / self.target_ms)
        v = min(max(p.value * 2.0 ** step, p.lo), p.hi)
        if p.integer:
            v = float(round(v))
        if v != p.value:
            self.technique.set_param(self.knob, v)


__all__ = ["KnobFeedback"]
