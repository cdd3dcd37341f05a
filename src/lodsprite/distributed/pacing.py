"""Keyframe pacing on the LOD server: render a keyframe when the client will need one.

The 2002 server's KEYFRAME-RENDERER (Figure 6) renders keyframes back to back, as fast
as the queue and the link take them.  That matched a server slower than the viewer's
motion (the paper: 34 spriteframes per keyframe).  A server faster than that sends
keyframes the client does not need: the keyframe it shows would still serve within the
error threshold.  Each one costs the link its bytes and the client a receive and an
upload, and the uploads make the client's frame time uneven.

With pace ``needed`` the renderer applies the LOD-sprite error metric of Chen, Swan &
Kaufman (1999, Eq. 2: ``sqrt(mean θ²) / β`` in pixels, :mod:`lodsprite.sprite.metric`)
to the keyframe it rendered last, at the viewpoint predicted for when a new keyframe
would arrive (δt ahead).  It renders a new one only when that error reaches
``PACE_FRACTION`` ε: the 1999 algorithm's own keyframe rule, applied where the keyframe
will be shown.  The rule and the error are the keyframe policy's
(:func:`lodsprite.sprite.policy.keyframe_needed`), the same that the in-process engine and
the client's own keyframes follow.  Pace ``continuous`` is the paper's behaviour.

The keyframe the client shows need not be this server's: with several servers it is
the newest from any of them.  The client names the keyframe it shows (its eye and the
server's slot) in each viewpoint message, and a keyframe is due only when neither that
keyframe nor the one this server rendered last (perhaps still on its way) serves the
predicted viewpoint.  Servers take turns: the one after the shown keyframe's slot renders
at ``PACE_FRACTION`` ε; the others only at ε itself, to help when the one whose turn it
is cannot keep up.
"""

from __future__ import annotations

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.sprite.metric import ErrorMetric
from lodsprite.sprite.policy import keyframe_needed
from lodsprite.terrain.heightfield import HeightField

PACES = ("needed", "continuous")
DEFAULT_PACE = "needed"
PACE_FRACTION = 0.8  # of ε: margin for prediction error and for the time a keyframe takes


class KeyframePacer:
    """Decides whether a keyframe is due (``pace`` ``needed``) or always (``continuous``).

    ``epsilon_px`` is the client's error threshold in pixels; ``height_px`` the image
    height that sets the pixel angle β.
    """

    def __init__(self, hf: HeightField, lod: int, epsilon_px: float, height_px: int,
                 pace: str = DEFAULT_PACE, fraction: float = PACE_FRACTION) -> None:
        self.pace = pace
        self.limit_px = fraction * epsilon_px
        self.epsilon_px = epsilon_px
        self.height_px = height_px
        self.metric = ErrorMetric.for_level(hf, lod) if pace == "needed" else None
        self._c_prime: np.ndarray | None = None  # C' of the last keyframe rendered
        self._own_eye: tuple[float, ...] | None = None
        self._shown: tuple[tuple[float, ...], np.ndarray] | None = None  # eye, C'

    def due(self, viewpoint: Viewpoint, projection: Projection,
            shown_eye: np.ndarray | None = None, turn: bool = True) -> bool:
        """Whether a keyframe for ``viewpoint`` (the predicted one) should be rendered.

        ``shown_eye (3,)`` metres: the eye of the keyframe the client shows, when it said;
        ``turn``: whether this server is the next to render (always, with one server).
        """
        if self.metric is None or self._c_prime is None:
            return True
        limit = self.limit_px if turn else self.epsilon_px
        return keyframe_needed(self.metric, (self._c_prime, self._shown_c_prime(shown_eye)),
                               viewpoint, projection, self.height_px, limit)

    def _shown_c_prime(self, eye: np.ndarray | None) -> np.ndarray | None:
        """``C'`` of the client's shown keyframe, computed once per keyframe eye."""
        if eye is None or self.metric is None:
            return None
        key = tuple(float(v) for v in eye)
        if key == self._own_eye:
            return None  # this server's own keyframe, tested already
        if self._shown is None or self._shown[0] != key:
            self._shown = key, self.metric.reproject(np.asarray(key))
        return self._shown[1]

    def rendered(self, viewpoint: Viewpoint) -> None:
        """Note the keyframe just rendered (its ``C'`` is computed once, here)."""
        if self.metric is not None:
            self._c_prime = self.metric.reproject(viewpoint.o)
            self._own_eye = tuple(float(v) for v in viewpoint.o)
