"""GL side of LOD-sprite: keyframes kept on the GPU and projective spriteframes.

A keyframe is rendered at full resolution straight into a render target whose
colour texture *is* the sprite texture and whose depth texture is the
keyframe z-buffer: no copy, no round trip through numpy (Chen et al. 1999 used
glCopyTexImage2D for the same purpose).  Keyframes live in a pool of slots
(colour + depth target and coarse z-buffer each, made as first needed): without a
keyframe cache two slots alternate so a new keyframe never overwrites the one being
shown; with one (:mod:`lodsprite.sprite.cache`) the cache names the slot of each new
keyframe and which kept one to show (:meth:`SpriteDrawer.show`).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from lodsprite.camera import Projection, Viewpoint, texels_per_pixel, widened
from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.depth_mesh import DEFAULT_CUT_DEG, DepthMesh
from lodsprite.gl.shaders import (
    PROXY_VERTEX_COMMON,
    SPRITE_FS,
    SPRITE_GS,
    SPRITE_VS,
    SPRITE_VS_FRAGMENT,
)
from lodsprite.gl.target import RenderTarget
from lodsprite.gl.terrain import SKY_RGB, TerrainDrawer, draw_stats, mat_bytes
from lodsprite.record import Frame

SRGB8 = 0x8C41  # GL internal format of uploaded keyframes drawn on the depth mesh

DEFAULT_VERTEX_TOL = 0.01
DEFAULT_FRAGMENT_TOL = 0.03
DEFAULT_COARSE_TOL = 0.002
VISIBILITY_MODES = {"triangle": 0, "fragment": 1, "coarse": 2}
DEFAULT_VISIBILITY = "coarse"
DEFAULT_GUARD_PX = 32
DEFAULT_SPRITE_MIPMAPS = False  # benchmarks/sprite_mipmaps.py: see SpriteDrawer
KEY_SCALES = (1.0, 1.5, 2.0)  # keyframe texels a display pixel side

# The coarse z-buffer: a proxy's depth alone, from the keyframe's view.
PROXY_DEPTH_VS = "#version 330\n" + PROXY_VERTEX_COMMON + """
uniform mat4 u_mvp;
out vec2 v_uv;  // unused but kept: every proxy's vertex layout stays bound
void main() {
    gl_Position = u_mvp * vec4(terrain_position(v_uv), 1.0);
}
"""
PROXY_DEPTH_FS = """#version 330
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = vec4(v_uv, 0.0, 1.0); }
"""


class UniformProxy:
    """The default sprite proxy geometry: the uniform coarse level of ``level_quads`` quads
    (with its border ribbons if ``border``), :meth:`TerrainDrawer.draw_proxy`'s mesh.

    A proxy geometry object has ``twin(vertex_shader) -> str`` (the shader reading its
    vertices through ``terrain_position``, in place of ``PROXY_VERTEX_COMMON``) and
    ``draw(program, view_proj) -> triangles``; it may have ``for_keyframe(slot, viewpoint,
    projection) -> geometry``, the geometry frozen for the keyframe rendered into ``slot``
    (a view-dependent proxy, :class:`lodsprite.gl.adaptive.AdaptiveProxy`)."""

    def __init__(self, terrain: TerrainDrawer, level_quads: int, border: bool) -> None:
        self.terrain, self.level_quads, self.border = terrain, level_quads, border
        self._vaos: dict[int, dict] = {}  # program -> TerrainDrawer.draw_proxy's cache

    @staticmethod
    def twin(vertex_shader: str) -> str:
        return vertex_shader  # the sprite shaders read PROXY_VERTEX_COMMON already

    def draw(self, program: moderngl.Program, view_proj: np.ndarray) -> int:
        return self.terrain.draw_proxy(program, self._vaos.setdefault(program.glo, {}),
                                       view_proj, self.level_quads, self.border)

    def release(self) -> None:
        for cache in self._vaos.values():
            for vao in cache.values():
                vao.release()
        self._vaos.clear()


@dataclass(frozen=True)
class GLKeyframe:
    """The keyframe tuple of Swan et al. (2002): sprite texture and z-buffer (GPU-resident, in
    ``target``), view and projection, and the time it was started (``t0``, seconds);
    ``coarse`` holds the coarse level's z-buffer from the same view; ``color`` is the sprite
    texture (``target``'s own colour, or an uploaded RGB texture)."""

    target: RenderTarget
    coarse: RenderTarget
    viewpoint: Viewpoint
    projection: Projection
    view_proj: np.ndarray
    t0: float
    color: moderngl.Texture
    proxy: object = None  # the proxy geometry its spriteframes draw (frozen with it)


class SpriteDrawer:
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

    The sprite is sampled bilinearly with ``textureGrad`` (derivatives taken before the
    visibility branch).  ``mipmaps=True`` builds the sprite texture's mipmaps with each
    keyframe and samples it trilinearly, which can help only where a spriteframe shrinks the
    keyframe (flying away from it).

    ``proxy`` is the geometry spriteframes and coarse z-buffers draw (a proxy geometry
    object, :class:`UniformProxy`; default: the uniform coarse level of ``coarse_quads``
    with its border ribbons); :meth:`set_proxy` changes it.

    ``key_scale`` (:data:`KEY_SCALES`): keyframe texels a display pixel side.  A keyframe
    is rendered at ``key_scale`` times the frame's size (guard band included), through
    the same projection: at 2, 4 samples a display pixel, 4x the memory of a slot
    (:meth:`keyframe_bytes`).  A keyframe at a scale other than 1 is never shown as it
    is: its frame is a spriteframe drawn from it (:attr:`keyframe_is_frame`).

    ``depth_stride`` (None: the proxy geometry): spriteframes draw the keyframe's own depth
    as a mesh (:class:`~lodsprite.gl.depth_mesh.DepthMesh`, a vertex every ``depth_stride``
    keyframe texels, rubber sheets at ``depth_cut_deg``); the proxy geometry's spriteframe
    is drawn under it and shows where the mesh does not reach (outside the keyframe, and
    where a rubber sheet would stretch too far). ``pair`` (with the depth mesh): the
    keyframe shown before the current one (:attr:`previous`) is drawn too, by priority: the
    older keyframe shows only where the newer drew nothing (outside it, or where its rubber
    sheets stretched too far to be drawn).
    """

    def __init__(self, terrain: TerrainDrawer, coarse_quads: int = 16,
                 visibility: str = DEFAULT_VISIBILITY, vertex_tol: float = DEFAULT_VERTEX_TOL,
                 fragment_tol: float = DEFAULT_FRAGMENT_TOL,
                 coarse_tol: float = DEFAULT_COARSE_TOL, border: bool = True,
                 guard_px: int = DEFAULT_GUARD_PX,
                 mipmaps: bool = DEFAULT_SPRITE_MIPMAPS, proxy=None,
                 key_scale: float = 1.0, depth_stride: int | None = None,
                 depth_cut_deg: float = DEFAULT_CUT_DEG, pair: bool = False) -> None:
        if visibility not in VISIBILITY_MODES:
            raise InputError(f"visibility must be one of {', '.join(VISIBILITY_MODES)}, "
                             f"got {visibility!r}")
        if not (isinstance(guard_px, int) and guard_px >= 0):
            raise InputError(f"guard band must be a whole number of pixels >= 0, got {guard_px}")
        if float(key_scale) not in KEY_SCALES:
            raise InputError(f"the keyframe scale is one of {', '.join(map(str, KEY_SCALES))}"
                             f", not {key_scale!r}")
        self.terrain = terrain
        self.ctx: GLContext = terrain.ctx
        self.coarse_quads = coarse_quads
        self.visibility = visibility
        self.border = border
        self.guard_px = guard_px
        self.mipmaps = bool(mipmaps)
        self._tols = {"u_vertex_tol": vertex_tol, "u_fragment_tol": fragment_tol,
                      "u_coarse_tol": coarse_tol}
        self._default_proxy = UniformProxy(terrain, coarse_quads, border)
        self.proxy = self._default_proxy if proxy is None else proxy
        self.program = self._program(visibility, self._tols)
        self.depth_program = self.ctx.mgl.program(vertex_shader=PROXY_DEPTH_VS,
                                                  fragment_shader=PROXY_DEPTH_FS)
        self.key_scale = float(key_scale)
        self.key_size: tuple[int, int] = tuple(
            int(round(self.key_scale * (n + 2 * guard_px))) for n in terrain.target.size)
        self.depth_mesh = (None if depth_stride is None
                           else DepthMesh(self.ctx, depth_stride, depth_cut_deg))
        self.fallback_passes = 0  # spriteframes that drew the proxy under the depth mesh
        self._slots: list[tuple[RenderTarget, RenderTarget]] = []  # (keyframe, coarse z)
        self._kept: dict[int, GLKeyframe] = {}  # slot -> the keyframe it holds
        self._shown = -1  # the slot of the keyframe shown
        self._previous: tuple[int, GLKeyframe] | None = None  # (slot, keyframe) shown before
        self.pair = bool(pair) and self.depth_mesh is not None
        self.slot_targets(0), self.slot_targets(1)  # the two alternating slots, made up front
        self.keyframe: GLKeyframe | None = None
        self._uploads: list[moderngl.Texture] = []  # RGB sprite textures of uploaded keyframes
        # Mixed by its alpha into fragments that fell back to the terrain texture (the
        # viewer's tint toggle); alpha 0 draws them as they are.
        self.fallback_tint: tuple[float, float, float, float] = (1.0, 0.0, 1.0, 0.0)

    def use_depth_proxy(self, proxy: str) -> None:
        """Draw spriteframes as the ``--proxy`` choice says: ``geometry`` and ``depth``
        as made, ``depth-refined`` the depth mesh refined where depth is not planar,
        ``search`` the search per fragment (both need ``depth_stride``)."""
        if proxy == "search":
            self.use_search()
        elif proxy == "depth-refined":
            if self.depth_mesh is None:
                raise InputError("the refined depth mesh needs a depth stride")
            self.depth_mesh.refine()

    def use_search(self, steps: int | None = None) -> None:
        """Draw spriteframes by a search per fragment through the keyframe's depth
        (:class:`~lodsprite.gl.depth_search.DepthSearch`) instead of the depth mesh (the
        mesh's stride kept for the depth estimate's samples).  Needs ``depth_stride``."""
        from lodsprite.gl.depth_search import DEFAULT_STEPS, DepthSearch

        if self.depth_mesh is None:
            raise InputError("the depth search draws the keyframe's own depth: it needs "
                             "a depth stride (--proxy search sets one)")
        search = DepthSearch(self.ctx, self.depth_mesh.stride,
                             DEFAULT_STEPS if steps is None else steps)
        self.depth_mesh.release()
        self.depth_mesh = search

    @property
    def key_px(self) -> tuple[int, int]:
        """A keyframe's size in display pixels, guard band included (:attr:`key_size`
        over the keyframe scale): what the error metric's resampling term sees, since a
        keyframe at scale k sampled with k x k texels a pixel matches the reference's
        filter, no loss at an identity warp."""
        return tuple(n + 2 * self.guard_px for n in self.terrain.target.size)

    @property
    def keyframe_is_frame(self) -> bool:
        """Whether a keyframe can be shown as it is (its scale is 1)."""
        return self.key_scale == 1.0

    def keyframe_bytes(self) -> int:
        """GPU bytes of one keyframe slot: RGBA8 colour (4 B/texel, a third more with
        mipmaps), its depth and the coarse depth (4 B/texel each: 24-bit depth is stored
        in 32 bits) at the keyframe size ``(w + 2g) x (h + 2g)``."""
        w, h = self.key_size
        color = 4 * w * h * (4 if self.mipmaps else 3) // 3
        return color + 2 * 4 * w * h

    @property
    def key_targets(self) -> list[RenderTarget]:
        """The keyframe targets made so far (colour + depth), in slot order."""
        return [key for key, _ in self._slots]

    def slot_targets(self, i: int) -> tuple[RenderTarget, RenderTarget]:
        """Slot ``i``'s targets, made (with every slot below it) when first asked for."""
        while len(self._slots) <= i:
            w, h = self.key_size
            pair = (RenderTarget(self.ctx, w, h, srgb=self.depth_mesh is not None),
                    RenderTarget(self.ctx, w, h, color=False))
            for t in pair:
                t.depth.compare_func = ""  # sample raw depth values, no shadow comparison
                # Window depth is affine across a triangle in screen space, so bilinear
                # samples of a z-buffer are exact inside triangles: no moire where the
                # keyframe sees a surface at a grazing angle (nearest samples there err by
                # up to half a texel's depth slope, far beyond the tolerances).
                t.depth.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._slots.append(pair)
        return self._slots[i]

    def _free_slot(self, slot: int | None) -> int:
        """``slot``, or (None) the one of slots 0 and 1 not shown: they alternate.  (A
        keyframe cache never names the slot of the keyframe it shows.)"""
        if slot is None:
            return 1 if self._shown == 0 else 0
        return slot

    def show(self, slot: int) -> None:
        """Make the keyframe kept in ``slot`` the one spriteframes are drawn from (the one
        shown until now becomes :attr:`previous`)."""
        if self._shown >= 0 and self._shown != slot:
            self._previous = self._shown, self.keyframe
        self.keyframe, self._shown = self._kept[slot], slot

    @property
    def previous(self) -> GLKeyframe | None:
        """The keyframe shown before the current one, while its slot still holds it."""
        if self._previous is None:
            return None
        slot, key = self._previous
        return key if self._kept.get(slot) is key and slot != self._shown else None
    def set_proxy(self, proxy) -> None:
        """Draw spriteframes and coarse z-buffers with ``proxy`` (a proxy geometry object,
        :class:`UniformProxy`; None: the uniform coarse level again), from the next
        keyframe on."""
        proxy = self._default_proxy if proxy is None else proxy
        if proxy is self.proxy:
            return
        self.proxy = proxy
        for prog in (self.program, self.depth_program):
            prog.release()
        self.program = self._program(self.visibility, self._tols)
        self.depth_program = self.ctx.mgl.program(vertex_shader=proxy.twin(PROXY_DEPTH_VS),
                                                  fragment_shader=PROXY_DEPTH_FS)

    def _program(self, visibility: str, tols: dict[str, float]) -> moderngl.Program:
        mgl = self.ctx.mgl
        twin = self.proxy.twin
        if visibility == "triangle":
            prog = mgl.program(vertex_shader=twin(SPRITE_VS), geometry_shader=SPRITE_GS,
                               fragment_shader=SPRITE_FS)
        else:
            prog = mgl.program(vertex_shader=twin(SPRITE_VS_FRAGMENT),
                               fragment_shader=SPRITE_FS)
        prog["u_visibility"].value = VISIBILITY_MODES[visibility]
        units = {"u_color": 0, "u_sprite": 2, "u_key_depth": 3, "u_key_coarse": 4}
        for name, value in [*tols.items(), *units.items()]:
            if name in prog:
                prog[name].value = value
        return prog

    @property
    def target(self) -> RenderTarget:
        """Where spriteframes are drawn."""
        return self.terrain.target

    def key_projection(self, projection: Projection, spread: float = 1.0) -> Projection:
        """The keyframe's projection for a frame projection: widened by the guard band
        (``spread`` times wider again at the same texels, :func:`~lodsprite.camera.widened`)."""
        w, h = self.target.size
        return widened(projection, w, h, self.guard_px, spread)

    def texel_scale(self, key: GLKeyframe) -> float:
        """Keyframe texels a display pixel side for ``key``: :attr:`key_scale`, less where
        the keyframe was spread wider than its guard band (worker keyframes whose guard
        band follows the predictor's error)."""
        return texels_per_pixel(key.projection.fov_y_deg, self.terrain.fov_y_deg,
                                key.target.size[1], self.target.size[1])

    def _keep(self, slot: int, viewpoint: Viewpoint, projection: Projection, t0: float,
              color: moderngl.Texture | None = None, coarse_ready: bool = False) -> None:
        target, coarse = self._slots[slot]
        freeze = getattr(self.proxy, "for_keyframe", None)
        proxy = self.proxy if freeze is None else freeze(target, viewpoint, projection)
        if self.visibility == "coarse" and not coarse_ready:
            self.render_coarse_depth(viewpoint, projection, coarse, proxy)
        color = target.color if color is None else color
        if self.mipmaps:
            color.build_mipmaps()
            color.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._kept[slot] = GLKeyframe(target, coarse, viewpoint, projection,
                                      projection.matrix() @ viewpoint.view_matrix(), t0, color,
                                      proxy)
        self.show(slot)

    def render_coarse_depth(self, viewpoint: Viewpoint, projection: Projection,
                            target: RenderTarget, proxy=None) -> None:
        """The z-buffer of the proxy (default: :attr:`proxy`; the uniform coarse level and
        its border ribbons unless :meth:`set_proxy` chose another) from a keyframe's view
        into ``target``: what the ``coarse`` visibility rule compares against."""
        target.use(SKY_RGB)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        (proxy or self.proxy).draw(self.depth_program,
                                   projection.matrix() @ viewpoint.view_matrix())

    def render_keyframe(self, viewpoint: Viewpoint, t0: float,
                        projection: Projection | None = None,
                        slot: int | None = None, spread: float = 1.0) -> Frame:
        """Render the full-resolution terrain into keyframe slot ``slot`` (None: the one of
        the two alternating slots not shown; never the slot shown) and show it.

        ``projection`` is the frame's; the keyframe is rendered through it widened by the
        guard band (``guard_px`` pixels on every side, same pixel angle; ``spread`` times
        wider at the same texels, :meth:`key_projection`), so that frames turning away from
        the keyframe still find their borders in the sprite.
        """
        slot = self._free_slot(slot)
        target = self.slot_targets(slot)[0]
        projection = self.key_projection(projection or self.terrain.projection(viewpoint),
                                         spread)
        if self.keyframe_drawer is not None:
            stats = self.keyframe_drawer(viewpoint, projection, target)
        else:
            stats = self.terrain.render(viewpoint, None, projection, target)
        if self.after_keyframe is not None:
            self.after_keyframe(viewpoint, projection, target)
        self._keep(slot, viewpoint, projection, t0)
        return stats

    #: Draws keyframes instead of the full-resolution terrain when set:
    #: ``(viewpoint, projection, target) -> draw statistics`` (the adaptive renderer's
    #: :meth:`~lodsprite.techniques.adaptive_terrain.AdaptiveTerrain.render_into`).
    keyframe_drawer = None
    #: Draws over each keyframe after its terrain when set (a scene's static layers):
    #: ``(viewpoint, projection, target) -> None``, whichever drawer drew the terrain.
    after_keyframe = None

    def upload_keyframe(self, viewpoint: Viewpoint, projection: Projection, color: np.ndarray,
                        depth: np.ndarray, t0: float, zbuffer: str = "full") -> None:
        """Make a keyframe rendered elsewhere (the distributed server) the current one.

        ``color (H, W, 3) uint8`` and ``depth (H, W) float32`` (window depth), row 0 at
        the top, must match this renderer's keyframe size (the image size plus the guard
        band), and ``projection`` is the keyframe's own.  ``zbuffer`` says whose depth
        ``depth`` is: ``full`` (the full-resolution terrain's; the ``coarse`` rule then
        renders its coarse z-buffer here) or ``coarse`` (the coarse level's, as
        :meth:`render_coarse_depth` draws it; only for the ``coarse`` rule).  Arrays that
        are ``[::-1]`` views of contiguous rows (decoded keyframes) go to the textures
        without a copy.
        """
        w, h = self.key_size
        if color.shape != (h, w, 3) or depth.shape != (h, w):
            raise InputError(f"keyframe images must be {w}x{h}, got colour {color.shape}, "
                             f"depth {depth.shape}")
        if zbuffer not in ("full", "coarse") or (zbuffer == "coarse"
                                                 and self.visibility != "coarse"):
            raise InputError(f"a {zbuffer!r} z-buffer does not serve the {self.visibility!r} "
                             "visibility rule")
        slot = self._free_slot(None)
        target, coarse = self._slots[slot]
        if not self._uploads:
            srgb = SRGB8 if self.depth_mesh is not None else None  # as the slots' colour
            self._uploads = [self.ctx.mgl.texture((w, h), 3, alignment=1,
                                                  internal_format=srgb) for _ in range(2)]
            for tex in self._uploads:
                tex.repeat_x = tex.repeat_y = False
        tex = self._uploads[slot]
        tex.write(np.ascontiguousarray(color[::-1], dtype=np.uint8))  # GL rows: bottom-up
        if zbuffer == "coarse" or self.visibility != "coarse" or self.depth_mesh is not None:
            rows = np.ascontiguousarray(depth[::-1], dtype=np.float32)
            (coarse if zbuffer == "coarse" else target).depth.write(rows)
        self._keep(slot, viewpoint, projection, t0, tex, zbuffer == "coarse")

    def keyframe_depth(self) -> np.ndarray:
        """The current keyframe's window depth ``(h, w) float32`` with its guard band, at
        its own scale, row 0 at the top (a read-back: once a keyframe, for its error
        estimate)."""
        if self.keyframe is None:
            raise RuntimeError("no keyframe yet")
        return self.keyframe.target.read_depth(copy=False)

    def keyframe_image(self) -> np.ndarray:
        """The current keyframe's colour ``(h, w, 3) uint8`` with its guard band, at its
        own scale, row 0 at the top, as rendered here (a read-back: once a keyframe, for
        its error estimate; an uploaded keyframe's colour is the caller's already)."""
        if self.keyframe is None:
            raise RuntimeError("no keyframe yet")
        return self.keyframe.target.read_color(copy=False)

    def keyframe_color(self) -> np.ndarray:
        """The current keyframe's colour without its guard band: ``(H, W, 3) uint8``, the
        frame size times :attr:`key_scale`, row 0 at the top."""
        if self.keyframe is None:
            raise RuntimeError("no keyframe yet")
        g = int(round(self.guard_px * self.key_scale))
        tex = self.keyframe.color
        w, h = tex.size
        data = np.frombuffer(tex.read(alignment=1), np.uint8).reshape(h, w, tex.components)
        img = data[::-1, :, :3]
        return (img[g:h - g, g:w - g] if g else img).copy()

    def render_spriteframe(self, viewpoint: Viewpoint,
                           projection: Projection | None = None) -> Frame:
        """Render the proxy geometry (the coarse level and its border ribbons, or the
        proxy set) textured from the current keyframe into :attr:`target`; with the depth
        mesh, that under the keyframe's mesh (and the previous keyframe's, paired)."""
        key = self.keyframe
        if key is None:
            raise RuntimeError("render_spriteframe needs a keyframe first")
        projection = projection or self.terrain.projection(viewpoint)
        self.target.use(SKY_RGB)
        self.ctx.mgl.enable(moderngl.DEPTH_TEST)
        if self.depth_mesh is None:
            return self._draw_proxy(key, viewpoint, projection)
        # the proxy geometry's spriteframe under the mesh: where it does not reach
        tris = self._draw_proxy(key, viewpoint, projection).triangles
        self._clear_depth()
        self.fallback_passes += 1
        size = self.target.size
        tris += self.depth_mesh.draw(key, viewpoint, projection, self.fallback_tint,
                                     frame_px=size, key_scale=self.texel_scale(key))
        prev = self.previous if self.pair else None
        if prev is not None:  # shown only where the newer keyframe drew nothing
            tris += self.depth_mesh.draw(prev, viewpoint, projection, self.fallback_tint,
                                         older=True, frame_px=size,
                                         key_scale=self.texel_scale(prev))
        return draw_stats(tris, 1, projection)

    def _clear_depth(self) -> None:
        fbo = self.target.fbo
        fbo.color_mask = (False, False, False, False)
        try:
            fbo.clear(depth=1.0)  # glClear honours the colour mask: depth alone
        finally:
            fbo.color_mask = (True, True, True, True)
            fbo.use()  # the mask reaches GL when the framebuffer is bound

    def _draw_proxy(self, key: GLKeyframe, viewpoint: Viewpoint,
                    projection: Projection) -> Frame:
        """The proxy geometry textured from ``key`` into the bound target."""
        self.terrain.geometry.color_tex.use(0)
        key.color.use(2)
        key.target.depth.use(3)
        key.coarse.depth.use(4)
        prog = self.program
        prog["u_key_mvp"].write(mat_bytes(key.view_proj))
        prog["u_key_near_far"].value = (key.projection.near, key.projection.far)
        prog["u_color_levels"].value = self.terrain.geometry.color_tex_levels
        prog["u_fallback_tint"].value = self.fallback_tint
        prog["u_sprite_linear"].value = int(self.depth_mesh is not None)
        # fragments the keyframe did not see: the terrain texture or terrain_shade
        for name, value in (("u_shading", int(self.terrain.shading == "heights")),
                            ("u_range", self.terrain.geometry.height_range)):
            if name in prog:
                prog[name].value = value
        tris = (key.proxy or self.proxy).draw(prog, projection.matrix()
                                              @ viewpoint.view_matrix())
        return draw_stats(tris, 1, projection)

    def release(self) -> None:
        if self.depth_mesh is not None:
            self.depth_mesh.release()
        self._default_proxy.release()
        self.program.release()
        self.depth_program.release()
        for pair in self._slots:
            for t in pair:
                t.release()
        self._slots.clear()
        self._kept.clear()
        for tex in self._uploads:
            tex.release()
        self._uploads.clear()
        self.keyframe = None
