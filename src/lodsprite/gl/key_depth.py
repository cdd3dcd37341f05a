"""The keyframe's depth under a spriteframe: what a scene's later layers test against.

A spriteframe leaves the proxy's depth in the depth buffer (the coarse level, or the
adaptive proxy): a keyframe that holds more than that surface (a scene's static objects,
drawn into it after the terrain) would let a walker behind a static tree show through
the tree's sprite.  :class:`KeyDepthPass` replaces the depth buffer, after the
spriteframe, with the depth of what the sprite shows at each fragment: the proxy drawn
again (colour writes off, depth cleared first), each fragment's keyframe texel ``(u, v)``
unprojected with the keyframe's z-buffer to the world point the keyframe saw there, and
that point projected through the frame's view.  So the depth is warped exactly as the
colour is, and a moving object is hidden where the sprite shows something in front of
it.  Where the keyframe saw sky, where the fragment lies outside the keyframe, or where
the coarse level itself hid the fragment in the keyframe's view (the ``coarse``
visibility rule's fallback, which shows the terrain texture there) the fragment keeps
the proxy's own depth.
"""

from __future__ import annotations

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.gl.shaders import _LINEAR_DEPTH, PROXY_VERTEX_COMMON
from lodsprite.gl.sprite import DEFAULT_COARSE_TOL, SpriteDrawer
from lodsprite.gl.terrain import mat_bytes

KEY_DEPTH_VS = "#version 330\n" + PROXY_VERTEX_COMMON + """
uniform mat4 u_mvp;
uniform mat4 u_key_mvp;
out vec4 v_key;
void main() {
    vec2 uv;
    vec3 p = terrain_position(uv);
    gl_Position = u_mvp * vec4(p, 1.0);
    v_key = u_key_mvp * vec4(p, 1.0);
}
"""

KEY_DEPTH_FS = "#version 330\n" + _LINEAR_DEPTH + """
uniform mat4 u_mvp;
uniform mat4 u_key_inv;         // inverse of the keyframe's projection x view
uniform sampler2D u_key_depth;  // the keyframe's z-buffer (terrain and static layers)
uniform sampler2D u_key_coarse; // the keyframe's z-buffer of the coarse level
uniform float u_coarse_tol;
in vec4 v_key;
out vec4 f_color;
void main() {
    float z = gl_FragCoord.z;
    if (seen_by_keyframe(v_key, u_key_coarse, u_coarse_tol) > 0.5) {
        vec2 ndc = v_key.xy / v_key.w;
        float zb = textureLod(u_key_depth, ndc * 0.5 + 0.5, 0.0).r;
        if (zb < 1.0) {
            vec4 q = u_key_inv * vec4(ndc, 2.0 * zb - 1.0, 1.0);
            vec4 c = u_mvp * vec4(q.xyz / q.w, 1.0);
            if (c.w > 0.0) z = clamp(0.5 * c.z / c.w + 0.5, 0.0, 1.0);
        }
    }
    gl_FragDepth = z;
    f_color = vec4(0.0);
}
"""


class KeyDepthPass:
    """The keyframe's depth under ``sprite``'s spriteframes (module doc); ``coarse_tol``
    the coarse visibility rule's tolerance (relative depth)."""

    def __init__(self, sprite: SpriteDrawer, coarse_tol: float = DEFAULT_COARSE_TOL) -> None:
        self.sprite = sprite
        self.coarse_tol = float(coarse_tol)
        self._proxy = None
        self.program: moderngl.Program | None = None

    def _program_for(self, proxy) -> moderngl.Program:
        """The program reading ``proxy``'s vertices (remade when the proxy's kind
        changes)."""
        if self.program is None or type(proxy) is not type(self._proxy):
            if self.program is not None:
                self.program.release()
            self.program = self.sprite.ctx.mgl.program(
                vertex_shader=proxy.twin(KEY_DEPTH_VS), fragment_shader=KEY_DEPTH_FS)
            self.program["u_key_depth"].value = 3
            self.program["u_key_coarse"].value = 4
            self._proxy = proxy
        return self.program

    def draw(self, viewpoint: Viewpoint, projection: Projection) -> None:
        """After :meth:`SpriteDrawer.render_spriteframe` for ``viewpoint`` through
        ``projection`` (the frame's): its target's depth replaced (colour untouched)."""
        key = self.sprite.keyframe
        if key is None:
            raise RuntimeError("the keyframe depth pass needs a keyframe")
        if self.sprite.depth_mesh is not None:
            self._mesh_depth(key, viewpoint, projection)
            return
        proxy = key.proxy or self.sprite.proxy
        prog = self._program_for(proxy)
        fbo = self.sprite.target.fbo
        mgl = self.sprite.ctx.mgl
        fbo.use()
        fbo.color_mask = (False, False, False, False)
        try:
            fbo.clear(depth=1.0)  # glClear honours the colour mask: depth alone
            mgl.enable(moderngl.DEPTH_TEST)
            key.target.depth.use(3)
            key.coarse.depth.use(4)
            mvp = projection.matrix() @ viewpoint.view_matrix()
            prog["u_mvp"].write(mat_bytes(mvp))
            prog["u_key_mvp"].write(mat_bytes(key.view_proj))
            prog["u_key_inv"].write(mat_bytes(np.linalg.inv(key.view_proj)))
            prog["u_key_near_far"].value = (key.projection.near, key.projection.far)
            prog["u_coarse_tol"].value = self.coarse_tol
            proxy.draw(prog, mvp)
        finally:
            fbo.color_mask = (True, True, True, True)

    def _mesh_depth(self, key, viewpoint: Viewpoint, projection: Projection) -> None:
        """With the depth mesh: its surfaces' true depth (both keyframes of a pair),
        rubber sheets left out (where only they are, later layers are drawn over)."""
        fbo = self.sprite.target.fbo
        fbo.use()
        fbo.color_mask = (False, False, False, False)
        try:
            fbo.clear(depth=1.0)
            fbo.use()
            mesh = self.sprite.depth_mesh
            for k in (key, self.sprite.previous if self.sprite.pair else None):
                if k is not None:
                    mesh.draw(k, viewpoint, projection, true_depth=True)
        finally:
            fbo.color_mask = (True, True, True, True)
            fbo.use()

    def release(self) -> None:
        if self.program is not None:
            self.program.release()
            self.program = None
