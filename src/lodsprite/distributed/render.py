"""GL work of the distributed programs: the servers' keyframe services.

A keyframe is rendered from the predicted viewpoint and its colour read back, so that it
can cross the network as plain arrays.  For the default ``coarse`` visibility rule it
carries the coarse level's z-buffer from the same view (all that rule reads) instead of
the full one, so the client only uploads.  Images are read in OpenGL's bottom-up row
order and sent as they are.

Two services draw them: :class:`KeyframeService` the working grid whole at full
resolution (a small in-memory terrain), :class:`AdaptiveKeyframeService` the adaptive
renderer at ``key_sse`` over a terrain store's level 0, or over an in-memory grid of more
than :data:`ADAPTIVE_ABOVE` quads a side as a pyramid (what the window's
``sprite-adaptive`` keyframes are): level-0 detail where it shows, never tens of millions
of triangles a keyframe.  :func:`keyframe_service` picks one.
"""

from __future__ import annotations

from lodsprite.camera import Viewpoint
from lodsprite.distributed.pacing import KeyframePacer
from lodsprite.distributed.protocol import Keyframe, LoadArgs, check_load_args
from lodsprite.distributed.served import heights_shaded, is_object_scene
from lodsprite.gl.context import GLContext
from lodsprite.gl.target import RenderTarget
from lodsprite.gl.terrain_gl import TerrainGL
from lodsprite.scene.spec import SceneSpec, open_spec
from lodsprite.terrain.heightfield import DEFAULT_GRID

__all__ = ["ADAPTIVE_ABOVE", "LIGHTFIELD_NODES", "MEMORY_FRACTION", "AdaptiveKeyframeService",
           "KeyframeService",
           "SceneKeyframeService", "adaptive_scene_bytes", "check_load_args",
           "check_scene_memory", "estimate_scene_bytes", "key_size",
           "keyframe_kind", "keyframe_scene_bytes", "keyframe_service", "memory_available",
           "scene_args", "scene_file_bytes"]

ADAPTIVE_ABOVE = 1024
"""Working grids (quads a side) above which an in-memory terrain's keyframes are drawn
adaptively (a 1024² grid drawn whole is 2.1 M triangles; 4096² is 33.5 M, about 6 s a
keyframe on llvmpipe)."""
LIGHTFIELD_NODES = 16
"""Nodes each light field in a scene's keyframes is reconstructed from (the arbitrary
method's largest budget, :data:`lodsprite.layered.lightfields.NODES`)."""
MEMORY_FRACTION = 0.8
"""Share of the available memory a scene may take (its estimate)."""

SCENE_KEYS = ("terrain", "texture", "grid", "exaggeration", "size", "fov_y_deg")
SPRITE_KEYS = ("lod", "visibility", "border", "epsilon", "pace")


def scene_args(scene: SceneSpec, size: tuple[int, int], fov_y_deg: float = 45.0) -> dict:
    """The scene part of the ``load`` control message's arguments: the scene's description
    (:class:`~lodsprite.scene.spec.SceneSpec`, e.g. :func:`~lodsprite.scene.spec.describe`
    of a scene), the keyframe size and field of view (the client adds its
    ``SPRITE_KEYS``: coarse level, visibility rule, border ribbons, ε in pixels, pace)."""
    return {"terrain": scene.terrain, "texture": scene.texture, "grid": scene.grid,
            "exaggeration": scene.exaggeration, "size": list(size), "fov_y_deg": fov_y_deg}


def key_size(args: LoadArgs) -> tuple[int, int]:
    """The keyframe's size ``(w, h)`` pixels: ``size`` times ``key_scale`` (as
    :attr:`lodsprite.gl.sprite.SpriteDrawer.key_size` without a guard band)."""
    return tuple(int(round(args.key_scale * n)) for n in args.size)


def working_grid(args: LoadArgs) -> int:
    """The working grid (quads per side) ``args`` asks for (as :func:`load_terrain`)."""
    if args.grid is not None:
        return args.grid
    from lodsprite.terrain.loaders import parse_fractal_spec

    parsed = parse_fractal_spec(args.terrain)
    return parsed[0] if parsed is not None else DEFAULT_GRID


def estimate_scene_bytes(args: LoadArgs, source: tuple[int, int] | None,
                         texture: tuple[int, int] | None) -> int:
    """A generous estimate of the memory (bytes, host and GL together: llvmpipe keeps GL
    objects in host memory) that loading ``args`` takes at its peak.

    ``source`` (rows, cols) of the terrain as stored, ``texture`` (rows, cols) of an image
    texture (None: the ``terrain`` texture, one texel per working sample).  Terms, per
    element: source samples 48 bytes (int/float64 copies while validating and filling,
    fractal generation's float32 bands), working samples 64 bytes (float64 resampling,
    float32 heights, hillshade and tint temporaries, the height texture), texels 16
    bytes (RGB array, its upload copy, RGBA texture with mipmaps), render pixels 48
    bytes (colour and depth targets, the coarse target, read-back buffers).
    """
    n = working_grid(args) + 1
    src = source[0] * source[1] if source is not None else n * n
    texels = texture[0] * texture[1] if texture is not None else n * n
    w, h = key_size(args)
    pixels = w * h
    return 48 * src + 64 * n * n + 16 * texels + 48 * pixels + 64 * 2**20


def adaptive_scene_bytes(args: LoadArgs) -> int:
    """A generous estimate of what an :class:`AdaptiveKeyframeService` of ``args`` holds
    (bytes): its tile caches (the declared ``gpu_mb`` and ``host_mb``: llvmpipe keeps GL
    objects in host memory), 64 bytes a sample of the grid it keeps (a store's light grid,
    an in-memory terrain's whole grid with its pyramid), 48 a pixel, 64 MiB besides."""
    from lodsprite.scene.model import LIGHT_SIDE
    from lodsprite.techniques.builtin import GPU_MB, HOST_MB
    from lodsprite.terrain.store import is_store

    n = max(LIGHT_SIDE, working_grid(args) + 1) if is_store(args.terrain) else (
        working_grid(args) + 1)
    caches = (GPU_MB.default + HOST_MB.default) * 2**20
    w, h = key_size(args)
    return int(caches) + 64 * n * n + 48 * w * h + 64 * 2**20


def scene_file_bytes(args: LoadArgs) -> int:
    """A generous estimate of what a :class:`SceneKeyframeService` holds (bytes): the
    adaptive terrain's caches, a working grid of the default size, 48 bytes a pixel,
    128 MiB for the objects' meshes, LOD buffers and the GL state (the session caps bound
    the objects a scene file may hold)."""
    from lodsprite.techniques.builtin import GPU_MB, HOST_MB

    caches = (GPU_MB.default + HOST_MB.default) * 2**20
    n = DEFAULT_GRID + 1
    w, h = key_size(args)
    return int(caches) + 64 * n * n + 48 * w * h + 128 * 2**20


def keyframe_scene_bytes(args: LoadArgs, source: tuple[int, int] | None,
                         texture: tuple[int, int] | None) -> int:
    """What drawing ``args``' keyframes holds (bytes), as :func:`keyframe_kind` draws them:
    :func:`adaptive_scene_bytes` or :func:`estimate_scene_bytes`."""
    kind = keyframe_kind(args)
    if kind == "scene":
        return scene_file_bytes(args)
    if kind == "adaptive":
        return adaptive_scene_bytes(args)
    return estimate_scene_bytes(args, source, texture)


def memory_available() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes; None where there is no such file."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_scene_memory(args: LoadArgs, source: tuple[int, int] | None,
                       texture: tuple[int, int] | None, held: int = 0,
                       who: str = "this machine") -> str | None:
    """Why ``who`` cannot hold the scene of ``args`` (source and texture shapes as
    :func:`estimate_scene_bytes` takes), or None; ``held``: bytes of a scene that goes
    first (counted as available).  The one memory check of server, web hub and worker."""
    need = estimate_scene_bytes(args, source, texture)
    available = memory_available()
    if available is not None and need > MEMORY_FRACTION * (available + held):
        return (f"the scene needs about {need / 2**20:.0f} MiB, {who} has "
                f"{(available + held) / 2**20:.0f} MiB available")
    return None


class KeyframeService:
    """Full-resolution keyframes of one scene, drawn on one thread that creates and uses it.

    It draws and finishes with the GIL released (the project's unlocked draws:
    ``glDrawElementsInstanced`` and ``glFinish`` through ctypes), so the threads beside
    it run while a keyframe renders: a pool worker's heartbeats and a LOD server's
    control, viewpoint and transmitter threads.  A 4096² terrain seen whole is about
    33 M triangles, shaded for seconds on the calling thread by llvmpipe; drawn through
    moderngl (which holds the GIL) it silenced the worker past the broker's liveness.
    Only the readback of the finished, small keyframe holds the GIL."""

    def __init__(self, args: LoadArgs | dict, ctx: GLContext | None = None) -> None:
        """``args``: the ``load`` arguments, terrain and texture as loader specs (the
        server resolves the names a client sends first, :mod:`.datasets`).  ``ctx``: a
        context to share (None: its own).  Several renderers alive in one process must
        share one: each standalone context is not made current again before drawing, so
        with two the older would draw into the newer's (render workers keep a few)."""
        args = check_load_args(args)
        scene = open_spec(args)  # the load's scene description (a SceneSpec)
        size = key_size(args)
        self.terrain_gl = TerrainGL(scene, size, args.fov_y_deg, ctx)
        self.terrain_gl.drawer.unlocked_draws = True  # the threads beside it run meanwhile
        try:
            self.lod = args.lod
            self.border = args.border
            self.coarse_z = args.visibility == "coarse"
            self.coarse = (RenderTarget(self.terrain_gl.ctx, *size, color=False) if self.coarse_z
                           else None)
            # ε in display pixels: the frame's height, not the keyframe's texels
            self.pacer = KeyframePacer(scene.hf, self.lod, args.epsilon, args.size[1], args.pace)
        except BaseException:
            self.terrain_gl.release()
            raise

    def projection(self, viewpoint: Viewpoint):
        return self.terrain_gl.drawer.projection(viewpoint)

    def render(self, viewpoint: Viewpoint, seq: int, t0: float) -> Keyframe:
        """The keyframe of ``viewpoint``: colour ``(h, w, 3) uint8`` and the z-buffer its
        visibility rule reads ``(h, w) float32``, rows bottom-up."""
        r = self.terrain_gl.drawer
        projection = r.projection(viewpoint)
        r.render(viewpoint, None, projection)
        if self.coarse is not None:
            r.render_proxy(viewpoint, self.lod, self.border, projection, self.coarse)
        # Wait for the draws without the GIL: a readback through moderngl would wait
        # for them holding it.
        self.terrain_gl.ctx.finish_unlocked()
        color = r.target.read_color(copy=False)
        if self.coarse is not None:
            depth, zbuffer = self.coarse.read_depth(copy=False), "coarse"
        else:
            depth, zbuffer = r.target.read_depth(copy=False), "full"
        self.pacer.rendered(viewpoint)
        return Keyframe(seq, t0, viewpoint, projection, color, depth, zbuffer)

    def release(self) -> None:
        if self.coarse is not None:
            self.coarse.release()
        self.terrain_gl.release()


class AdaptiveKeyframeService:
    """Keyframes of one terrain drawn by the adaptive renderer at ``key_sse`` pixels
    (:class:`~lodsprite.techniques.adaptive_worker.StoreKeyframes`, the window's worker
    keyframes over a store): a store's level 0 streamed through its caches (``gpu_mb``,
    ``host_mb``: held between keyframes), an in-memory grid as a pyramid.  The first
    keyframe waits for its view's tiles; later ones use what has arrived and say what they
    lack (:attr:`deficit_px`, pixels of error beyond ``key_sse``).  Same interface as
    :class:`KeyframeService`; ``ctx`` shared as there."""

    def __init__(self, args: LoadArgs | dict, ctx: GLContext | None = None,
                 key_sse: float | None = None, gpu_mb: float | None = None,
                 host_mb: float | None = None) -> None:
        from lodsprite.scene.model import load_scene
        from lodsprite.sprite.worker_settings import StoreKeys, WorkerSettings
        from lodsprite.techniques.adaptive_worker import StoreKeyframes
        from lodsprite.techniques.builtin import GPU_MB, HOST_MB
        from lodsprite.techniques.defaults import STORE_DEFAULTS
        from lodsprite.techniques.terrain import clipped

        args = check_load_args(args)
        # as the window's shading "auto": a store's terrain texture is its level 0's own
        # heights shaded; an in-memory grid keeps its texture
        heights = heights_shaded(args.terrain, args.texture, args.terrain)
        scene = load_scene(args.terrain, args.texture, args.grid, args.exaggeration,
                           light=True, textured=not heights)
        keys = StoreKeys("", args.terrain,
                         STORE_DEFAULTS["key_sse"] if key_sse is None else key_sse,
                         GPU_MB.default if gpu_mb is None else gpu_mb,
                         HOST_MB.default if host_mb is None else host_mb, heights,
                         not heights and clipped(args.terrain, args.texture))
        settings = WorkerSettings(tuple(args.size), args.fov_y_deg, args.lod,
                                  args.visibility, args.border, 0, store=keys,
                                  key_scale=args.key_scale)
        self.keys = StoreKeyframes(scene.hf, scene.texture, settings, ctx)
        self.lod, self.deficit_px = args.lod, 0.0

    def projection(self, viewpoint: Viewpoint):
        return self.keys.terrain.projection(viewpoint)

    def render(self, viewpoint: Viewpoint, seq: int, t0: float) -> Keyframe:
        """The keyframe of ``viewpoint`` (as :meth:`KeyframeService.render`); what it lacks
        while tiles stream in :attr:`deficit_px`.  No ``C'`` is taken (the submitter
        paces), and the images are read back once, as the wire sends them."""
        key = self.keys.keyframe(viewpoint)
        zbuffer = self.keys.zbuffer
        color = key.target.read_color(copy=False)
        depth = (key.coarse if zbuffer == "coarse" else key.target).read_depth(copy=False)
        self.deficit_px = float(self.keys.adaptive.deficit_px())
        return Keyframe(seq, t0, viewpoint, key.projection, color, depth, zbuffer,
                        self.deficit_px)

    def release(self) -> None:
        self.keys.release()


class SceneKeyframeService:
    """Keyframes of a scene file's static layers (its terrain and standing objects) and
    its light fields in view (from :data:`LIGHTFIELD_NODES` nodes each), with their full
    z-buffer (:class:`~lodsprite.layered.scene_keys.SceneKeyframes`, what the window's
    scene worker draws, light fields aside): the moving objects are the page's to draw,
    depth tested against the keyframe's surface.  A light field is view dependent: the page
    shows the keyframe's view of it through the keyframe's depth mesh until the next.
    The terrain is drawn adaptively at ``key_sse`` over a
    store or a grid above :data:`ADAPTIVE_ABOVE`, else whole; a scene file opens confined
    to ``root`` (the data folder).  Same interface as :class:`KeyframeService`."""

    def __init__(self, args: LoadArgs | dict, ctx: GLContext | None = None,
                 root: str | None = None, key_sse: float | None = None) -> None:
        from lodsprite.distributed.served import open_object_scene
        from lodsprite.layered.scene_keys import SceneKeyframes, SceneKeys
        from lodsprite.sprite.worker_settings import WorkerSettings
        from lodsprite.techniques.defaults import STORE_DEFAULTS
        from lodsprite.terrain.store import is_store

        args = check_load_args(args)
        scene = open_object_scene(args.terrain, root, keyframes=True)
        hf = scene.hf
        adaptive = hf is not None and (bool(scene.terrain_spec) and is_store(scene.terrain_spec)
                                       or hf.quads > ADAPTIVE_ABOVE)
        keys = SceneKeys(str(scene.source or args.terrain), "adaptive" if adaptive else "full",
                         {"sse": STORE_DEFAULTS["key_sse"] if key_sse is None else key_sse}
                         if adaptive else {}, lightfields=LIGHTFIELD_NODES)
        settings = WorkerSettings(tuple(args.size), args.fov_y_deg, args.lod, "fragment",
                                  args.border, 0,  # the full z-buffer: any rule but coarse
                                  key_scale=args.key_scale)
        self.keys = SceneKeyframes(scene, keys, settings, None if ctx is None else ctx.mgl)
        self.lod, self.deficit_px = args.lod, 0.0

    def projection(self, viewpoint: Viewpoint):
        return self.keys.renderer.projection(viewpoint)

    def render(self, viewpoint: Viewpoint, seq: int, t0: float) -> Keyframe:
        """The keyframe of ``viewpoint``: colour and its full z-buffer (rows bottom-up),
        what the adaptive terrain lacks in :attr:`deficit_px`."""
        key, _ = self.keys.keyframe(viewpoint)
        color = key.target.read_color(copy=False)
        depth = key.target.read_depth(copy=False)
        self.deficit_px = self.keys.deficit_px()
        return Keyframe(seq, t0, viewpoint, key.projection, color, depth, "full",
                        self.deficit_px)

    def release(self) -> None:
        self.keys.release()


def keyframe_kind(args: LoadArgs) -> str:
    """How ``args``' keyframes are drawn (module doc): ``scene`` (a scene file's static
    layers), ``adaptive`` over a store or a working grid above :data:`ADAPTIVE_ABOVE`,
    else ``whole``."""
    from lodsprite.terrain.store import is_store

    if is_object_scene(args.terrain):
        return "scene"

    return ("adaptive" if is_store(args.terrain) or working_grid(args) > ADAPTIVE_ABOVE
            else "whole")


KEYFRAME_WAYS = ("auto", "adaptive", "whole")


def keyframe_service(args: LoadArgs, ctx: GLContext | None = None, way: str = "auto",
                     root: str | None = None):
    """The service that draws ``args``' keyframes: a scene file's static layers
    (:class:`SceneKeyframeService`, opened confined to ``root``), else as
    :func:`keyframe_kind` says (``way="auto"``), or ``adaptive`` / ``whole`` whatever the
    terrain (to compare them)."""
    if way not in KEYFRAME_WAYS:
        raise ValueError(f"keyframes are drawn {', '.join(KEYFRAME_WAYS)}, not {way!r}")
    if is_object_scene(args.terrain):
        return SceneKeyframeService(args, ctx, root)
    if (keyframe_kind(args) if way == "auto" else way) == "adaptive":
        return AdaptiveKeyframeService(args, ctx)
    return KeyframeService(args, ctx)
