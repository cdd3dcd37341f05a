"""The LOD-sprite keyframe policy, free of GL (Chen, Swan & Kaufman 1999, §3.1-3.2, Eq. 2).

Which image a viewer may show is decided from geometry alone: the error metric of
:mod:`lodsprite.sprite.metric` measures a keyframe's ``C'`` at a viewpoint, in pixels.
The in-process engine, the distributed server's pacer and the distributed client all
decide through this module.
"""

from __future__ import annotations

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.sprite.metric import ErrorMetric


def keyframe_error_px(metric: ErrorMetric, c_prime: np.ndarray, viewpoint: Viewpoint,
                      projection: Projection, height_px: int) -> float:
    """Error (pixels, Eq. 2) of showing the keyframe whose reprojected centres are
    ``c_prime (n*n, 3)`` metres at ``viewpoint`` seen through ``projection`` on an
    image ``height_px`` pixels high."""
    view_proj = projection.matrix() @ viewpoint.view_matrix()
    beta = projection.pixel_angle_rad(height_px)
    return metric.error_px(c_prime, viewpoint.o, view_proj, beta)
