"""Two-plane lumigraph geometry (Gortler et al. 1996; Sloan, Cohen & Gortler 1997, §2.2,
Figures 1-2), GL-free.

A slab is a pair of parallel planes in a local frame ``(x, y, z)`` of the world: the *uv*
plane at ``z = 0`` through the object's centre and the *st* plane at ``z = st_distance``,
in front of it (towards the viewer).  A ray crossing both is the 4D point ``(s, t, u, v)``
(metres in each plane, centred).  A lumigraph may hold up to six slabs round the object
(:data:`SIX_SLABS`); a view uses the one facing the eye (:func:`facing_slab`).  An st
*node* ``(i, j)`` sits on a regular ``n_st x n_st`` grid over ``[-st_size/2,
st_size/2]²``; its *uv image* (``n_uv x n_uv`` pixels over ``[-uv_size/2, uv_size/2]²``)
holds the colour of every ray from the node through the uv plane: it is a pinhole image
taken from the node with an off-axis frustum whose image plane is the uv square
(:func:`node_frustum`).

Reconstruction (§2.3) needs, per eye, where the ray from the eye through a point of the st
plane meets the uv plane (:func:`uv_through`), and with depth correction where the ray
from a node through a point ``X`` of the approximate geometry meets it (the same function
from the node).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lodsprite.errors import InputError


@dataclass(frozen=True)
class Slab:
    """One st/uv plane pair: ``frame (4, 4)`` local-to-world (rotation and origin at the
    uv plane's centre), plane sizes and the st plane's distance (metres), and the node
    grid ``n_st`` and image size ``n_uv``."""

    frame: np.ndarray
    st_size: float
    uv_size: float
    st_distance: float
    n_st: int
    n_uv: int

    def __post_init__(self) -> None:
        f = np.asarray(self.frame, dtype=np.float64).reshape(4, 4)
        r = f[:3, :3]
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or not np.allclose(f[3], [0, 0, 0, 1]):
            raise InputError("a slab's frame must be a rigid transform")
        for name in ("st_size", "uv_size", "st_distance"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"slab {name} must be > 0, got {getattr(self, name)}")
        if not (2 <= self.n_st <= 256 and 2 <= self.n_uv <= 4096):
            raise InputError(f"slab resolution out of range: {self.n_st} st nodes per side, "
                             f"{self.n_uv} uv pixels per side")
        object.__setattr__(self, "frame", f)

    @property
    def to_local(self) -> np.ndarray:
        """World-to-local ``(4, 4)``."""
        return np.linalg.inv(self.frame)

    def st_coords(self) -> np.ndarray:
        """Node coordinates along s (or t), ``(n_st,)`` metres, centred."""
        return np.linspace(-self.st_size / 2, self.st_size / 2, self.n_st)

    def node_local(self) -> np.ndarray:
        """Node positions in the local frame, ``(n_st, n_st, 3)``; ``[i, j]`` is node
        ``(s_i, t_j)`` on the st plane (``z = st_distance``)."""
        s = self.st_coords()
        ss, tt = np.meshgrid(s, s, indexing="ij")
        return np.stack([ss, tt, np.full_like(ss, self.st_distance)], axis=-1)

    def node_world(self) -> np.ndarray:
        """Node positions in world space, ``(n_st, n_st, 3)`` metres."""
        p = self.node_local()
        return p @ self.frame[:3, :3].T + self.frame[:3, 3]


def uv_through(origin_local: np.ndarray, point_local: np.ndarray) -> np.ndarray:
    """Where the line from ``origin`` through ``point`` (local frame, ``(..., 3)``) meets
    the uv plane ``z = 0``: ``(..., 2)`` metres; NaN where the line is parallel to it."""
    o = np.asarray(origin_local, dtype=np.float64)
    p = np.asarray(point_local, dtype=np.float64)
    d = p - o
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(np.abs(d[..., 2]) > 1e-12, -o[..., 2] / d[..., 2], np.nan)
    return o[..., :2] + k[..., None] * d[..., :2]


def uv_to_texture(uv: np.ndarray, uv_size: float) -> np.ndarray:
    """uv-plane metres to texture coordinates in ``[0, 1]²`` (u right, v up; GL rows)."""
    return np.asarray(uv, dtype=np.float64) / uv_size + 0.5


def node_frustum(node_local: np.ndarray, uv_size: float, near: float, far: float
                 ) -> np.ndarray:
    """Off-axis projection ``(4, 4)`` of a camera at ``node_local (3,)`` looking down
    ``-z`` whose image is exactly the uv square (``glFrustum`` form); the camera's view
    is a translation by ``-node_local`` in the local frame."""
    s, t, d = (float(v) for v in node_local)
    if not (0 < near < d < far):
        raise InputError(f"node frustum needs 0 < near < st distance < far, got near {near}, "
                         f"distance {d}, far {far}")
    h = uv_size / 2
    left, right = (-h - s) * near / d, (h - s) * near / d
    bottom, top = (-h - t) * near / d, (h - t) * near / d
    m = np.zeros((4, 4))
    m[0, 0] = 2 * near / (right - left)
    m[1, 1] = 2 * near / (top - bottom)
    m[0, 2] = (right + left) / (right - left)
    m[1, 2] = (top + bottom) / (top - bottom)
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2 * far * near / (far - near)
    m[3, 2] = -1.0
    return m


def node_view(slab: Slab, i: int, j: int) -> np.ndarray:
    """World-to-eye ``(4, 4)`` of node ``(i, j)``: the local frame moved to the node."""
    p = slab.node_local()[i, j]
    move = np.eye(4)
    move[:3, 3] = -p
    return move @ slab.to_local


def grid_triangles(n: int) -> np.ndarray:
    """The st plane's triangulation: ``(2 (n-1)², 3) int32`` node indices ``i * n + j``,
    two triangles per grid square (Figure 2)."""
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b, c, d = a + n, a + 1, a + n + 1
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)


def slab_facing(centre: np.ndarray, radius: float, direction: np.ndarray,
                n_st: int = 32, n_uv: int = 256, st_scale: float = 2.0,
                distance_scale: float = 2.5, uv_scale: float = 1.0) -> Slab:
    """A slab for an object of bounding ``radius`` at ``centre`` seen from ``direction``
    (unit, from the object towards the viewers): the uv square spans the object, the st
    plane ``distance_scale`` radii in front of its centre, ``st_scale`` times as wide."""
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2], frame[:3, 3] = x, y, z, centre
    return Slab(frame, st_scale * 2 * radius, uv_scale * 2 * radius, distance_scale * radius,
                n_st, n_uv)


#: Six slabs round an object (beyond the paper, which uses one): the st planes are wider
#: (``st_scale``) and the uv squares larger (``uv_scale``) than a single slab's so that
#: the slab facing an eye anywhere on an orbit at 2.2 st distances still covers its rays;
#: their node spacing is correspondingly coarser.
SIX_SLABS = {"st_scale": 4.0, "uv_scale": 1.5, "distance_scale": 2.5}
SIX_DIRECTIONS = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0],
                           [0, -1, 0]], dtype=np.float64)


def facing_slab(slabs: list[Slab], eye_world: np.ndarray) -> int:
    """The index of the slab whose axis points most nearly at ``eye_world (3,)``."""
    best, score = 0, -np.inf
    for k, s in enumerate(slabs):
        d = np.asarray(eye_world, float) - s.frame[:3, 3]
        v = float(s.frame[:3, 2] @ d) / max(float(np.linalg.norm(d)), 1e-12)
        if v > score:
            best, score = k, v
    return best
