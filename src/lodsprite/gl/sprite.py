"""GL side of LOD-sprite: keyframes kept on the GPU and projective spriteframes.

A keyframe is rendered at full resolution straight into a render target whose
colour texture *is* the sprite texture and whose depth texture is the
keyframe z-buffer: no copy, no round trip through numpy (Chen et al. 1999 used
glCopyTexImage2D for the same purpose).  Two keyframe targets alternate so a
new keyframe never overwrites the one being shown.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import SPRITE_FS, SPRITE_GS, SPRITE_VS, SPRITE_VS_FRAGMENT
from lodsprite.gl.target import RenderTarget
from lodsprite.gl.terrain import SKY_RGB, FrameStats, TerrainRenderer, mat_bytes

DEFAULT_VERTEX_TOL = 0.01
DEFAULT_FRAGMENT_TOL = 0.03
DEFAULT_COARSE_TOL = 0.002
VISIBILITY_MODES = {"triangle": 0, "fragment": 1, "coarse": 2}
DEFAULT_VISIBILITY = "coarse"


@dataclass(frozen=True)
class GLKeyframe:
    """The keyframe tuple of Swan et al. (2002): sprite texture and z-buffer (GPU-resident, in
    ``target``), view and projection, and the time it was started (``t0``, seconds);
    ``coarse`` holds the coarse level's z-buffer from the same view."""

    target: RenderTarget
    coarse: RenderTarget
    viewpoint: Viewpoint
    projection: Projection
    view_proj: np.ndarray
    t0: float


class SpriteRenderer:
    """Renders keyframes (full resolution) and spriteframes (coarse level + keyframe sprite).

    ``visibility`` chooses where a spriteframe takes the sprite rather than the terrain
    texture (Chen et al. 1999 §3.3):

    * ``"triangle"``: the paper's rule.  A triangle takes the sprite only if its three
      vertices lie inside the keyframe frustum and are not behind the keyframe z-buffer by
      more than ``vertex_tol`` (relative to their depth).  Coarse vertices are exact
      full-resolution samples, so the test is exact up to that tolerance.
    * ``"fragment"``: the same test per fragment of the coarse surface; needs the looser
      ``fragment_tol`` because the coarse surface departs from the full one between vertices.
    * ``"coarse"`` (default): per fragment, inside the keyframe frustum and not hidden *by
      the coarse level itself* in the keyframe view (a coarse z-buffer rendered with each
      keyframe, tolerance ``coarse_tol``).  Surfaces hidden only by full-resolution detail
      keep the sprite, which there shows the occluding detail - as the viewer still sees
      it - instead of the terrain texture of a surface that stays hidden; surfaces the
      coarse model itself hid (revealed geometry) take the terrain texture.  From the
      keyframe viewpoint this reproduces the keyframe everywhere but along silhouettes.
    """

    def __init__(self, terrain: TerrainRenderer, coarse_quads: int = 16,
                 visibility: str = DEFAULT_VISIBILITY, vertex_tol: float = DEFAULT_VERTEX_TOL,
                 fragment_tol: float = DEFAULT_FRAGMENT_TOL,
                 coarse_tol: float = DEFAULT_COARSE_TOL) -> None:
        if visibility not in VISIBILITY_MODES:
            raise InputError(f"visibility must be one of {', '.join(VISIBILITY_MODES)}, "
                             f"got {visibility!r}")
        self.terrain = terrain
        self.ctx: GLContext = terrain.ctx
        self.coarse_quads = coarse_quads
        self.visibility = visibility
        mgl = self.ctx.mgl
        if visibility == "triangle":
            self.program = mgl.program(vertex_shader=SPRITE_VS, geometry_shader=SPRITE_GS,
                                       fragment_shader=SPRITE_FS)
            self.program["u_vertex_tol"].value = vertex_tol
        else:
            self.program = mgl.program(vertex_shader=SPRITE_VS_FRAGMENT,
                                       fragment_shader=SPRITE_FS)
        self.program["u_visibility"].value = VISIBILITY_MODES[visibility]
        for name, value in (("u_fragment_tol", fragment_tol), ("u_coarse_tol", coarse_tol)):
            if name in self.program:
                self.program[name].value = value
        w, h = terrain.target.size
        self.key_targets = [RenderTarget(self.ctx, w, h), RenderTarget(self.ctx, w, h)]
        self.coarse_targets = [RenderTarget(self.ctx, w, h, color=False),
                               RenderTarget(self.ctx, w, h, color=False)]
        for t in self.key_targets + self.coarse_targets:
            t.depth.compare_func = ""  # sample raw depth values, no shadow comparison
            t.depth.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._next = 0
        self._vaos: dict[int, moderngl.VertexArray] = {}
        self.keyframe: GLKeyframe | None = None
        self._upload: np.ndarray | None = None  # reused RGBA staging array for uploads

    @property
    def target(self) -> RenderTarget:
        """Where spriteframes are drawn."""
        return self.terrain.target

    def render_keyframe(self, viewpoint: Viewpoint, t0: float,
                        projection: Projection | None = None) -> FrameStats:
        """Render the full-resolution terrain into the next keyframe target and keep it."""
        target, coarse = self.key_targets[self._next], self.coarse_targets[self._next]
        self._next ^= 1
        projection = projection or self.terrain.projection(viewpoint)
        if self.visibility == "coarse":
            self.terrain.render(viewpoint, self.coarse_quads, projection, coarse)
        stats = self.terrain.render(viewpoint, None, projection, target)
        self.keyframe = GLKeyframe(target, coarse, viewpoint, projection,
                                   projection.matrix() @ viewpoint.view_matrix(), t0)
        return stats

    def upload_keyframe(self, viewpoint: Viewpoint, projection: Projection, color: np.ndarray,
                        depth: np.ndarray, t0: float) -> None:
        """Make a keyframe rendered elsewhere (the distributed server) the current one.

        ``color (H, W, 3) uint8`` and ``depth (H, W) float32`` (window depth), row 0 at
        the top, must match this renderer's image size.  The coarse z-buffer of the
        ``coarse`` visibility rule is rendered here from the keyframe's viewpoint.
        """
        w, h = self.target.size
        if color.shape != (h, w, 3) or depth.shape != (h, w):
            raise InputError(f"keyframe images must be {w}x{h}, got colour {color.shape}, "
                             f"depth {depth.shape}")
        target, coarse = self.key_targets[self._next], self.coarse_targets[self._next]
        self._next ^= 1
        if self._upload is None:
            self._upload = np.full((h, w, 4), 255, np.uint8)
        self._upload[..., :3] = color[::-1]  # GL rows run bottom-up; one pass, no new array
        target.color.write(self._upload)
        if self.visibility != "coarse":  # the coarse rule never reads the full z-buffer
            target.depth.write(np.ascontiguousarray(depth[::-1], dtype=np.float32))
        else:
            self.terrain.render(viewpoint, self.coarse_quads, projection, coarse)
        self.keyframe = GLKeyframe(target, coarse, viewpoint, projection,
                                   projection.matrix() @ viewpoint.view_matrix(), t0)

    def render_spriteframe(self, viewpoint: Viewpoint,
                           projection: Projection | None = None) -> FrameStats:
        """Render the coarse level textured from the current keyframe into :attr:`target`."""
        key = self.keyframe
        if key is None:
            raise RuntimeError("render_spriteframe needs a keyframe first")
        projection = projection or self.terrain.projection(viewpoint)
        mgl = self.ctx.mgl
        self.target.use(SKY_RGB)
        mgl.enable(moderngl.DEPTH_TEST)
        geo = self.terrain.geometry
        geo.color_tex.use(0)
        geo.height_tex.use(1)
        key.target.color.use(2)
        key.target.depth.use(3)
        key.coarse.depth.use(4)
        prog = self.program
        prog["u_color"].value, prog["u_height"].value = 0, 1
        for name, unit in (("u_sprite", 2), ("u_key_depth", 3), ("u_key_coarse", 4)):
            if name in prog:
                prog[name].value = unit
        prog["u_key_mvp"].write(mat_bytes(key.view_proj))
        prog["u_key_near_far"].value = (key.projection.near, key.projection.far)
        return self.terrain.draw(prog, self._vaos, viewpoint, projection, self.coarse_quads)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        self.program.release()
        for t in self.key_targets + self.coarse_targets:
            t.release()
        self.keyframe = None
