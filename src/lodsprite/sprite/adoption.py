"""When a keyframe rendered elsewhere (a keyframe worker, a LOD server, a page's renderers)
replaces the one shown: the one rule the window's worker keyframes, the LOD client and
the scenes' reused layers decide by (the page's JavaScript keeps its own copy: it always
takes the newest).

Swan et al. 2002 show every newer keyframe at once (``newest``).  ``needed`` keeps the
shown keyframe while its error stays under :data:`ADOPT_FRACTION` ε, sparing an upload;
``better`` takes a new keyframe once its error at the viewpoint shown is lower than the
shown one's (a late keyframe, aimed where the viewer was going, may be worse than the
one it would replace).  ``max_error`` refuses a keyframe whose error is that many pixels
or more whatever the mode (a client would replace it by its own at once).  Errors are
taken lazily (a callable each): the estimate of a keyframe costs a reprojection, and
``newest`` needs none.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from lodsprite.errors import InputError
from lodsprite.sprite.policy import keyframe_due

__all__ = ["ADOPT_FRACTION", "ADOPT_MODES", "AdoptionRule"]

ADOPT_MODES = ("needed", "newest", "better")
ADOPT_FRACTION = 0.5
"""``needed``: the shown keyframe is replaced once its error reaches this share of ε."""


@dataclass(frozen=True)
class AdoptionRule:
    """``mode`` (:data:`ADOPT_MODES`), ``epsilon_px`` (the keyframe threshold, pixels),
    ``max_error`` (pixels, None: no cap).  Raises :class:`InputError` for a mode not known."""

    mode: str = "newest"
    epsilon_px: float = 1.0
    max_error: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in ADOPT_MODES:
            raise InputError(f"adopt must be one of {', '.join(ADOPT_MODES)}, got "
                             f"{self.mode!r}")

    @property
    def compares(self) -> bool:
        """Whether deciding needs the new keyframe's error (its ``C'``)."""
        return self.mode != "newest" or self.max_error is not None

    def adopt(self, shown_error: Callable[[], float] | None,
              new_error: Callable[[], float]) -> bool:
        """Whether the new keyframe replaces the shown one; ``shown_error``: the shown
        keyframe's error at the viewpoint now (None: none is shown, or its error cannot
        be told: the new one is taken within ``max_error``), ``new_error``: the new one's
        there.  Each is called at most once, and only when the rule needs it."""
        new = None
        if self.max_error is not None:
            new = new_error()
            if keyframe_due(new, self.max_error):
                return False
        if shown_error is None or self.mode == "newest":
            return True
        err = shown_error()
        if self.mode == "needed":
            return keyframe_due(err, ADOPT_FRACTION * self.epsilon_px)
        return (new_error() if new is None else new) < err
