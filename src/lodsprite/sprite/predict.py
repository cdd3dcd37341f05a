"""Viewpoint extrapolation for keyframes rendered ahead of the viewer.

Chen, Swan & Kaufman (1999, §5) propose rendering the next keyframe "in advance by
predicting where the viewpoint will be ... by extrapolating from the past several
viewpoint locations".  A keyframe placed ahead of the viewer serves the frames on
both sides of it, so the error metric stays under the threshold for longer.
"""

from __future__ import annotations

from lodsprite.camera import Viewpoint, rotated_viewpoint, view_rotation


def extrapolate(prev: Viewpoint, cur: Viewpoint, steps: float) -> Viewpoint:
    """The viewpoint ``steps`` frames after ``cur`` at the motion of ``prev -> cur``.

    The eye moves on linearly; the orientation keeps turning at the same angular velocity
    (the rotation ``prev -> cur`` raised to the power ``steps``).
    """
    from scipy.spatial.transform import Rotation  # on first use: a slow import

    r_prev, r_cur = view_rotation(prev), view_rotation(cur)
    turn = r_cur * r_prev.inv()
    r_new = Rotation.from_rotvec(turn.as_rotvec() * steps) * r_cur
    return rotated_viewpoint(r_new, cur.o + steps * (cur.o - prev.o))
