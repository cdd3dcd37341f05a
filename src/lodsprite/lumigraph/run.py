"""Capturing a lumigraph and rendering it along a camera path: the engine behind
``lodsprite lumigraph capture`` and ``lodsprite lumigraph render``.

Capture renders every st node's uv image of an object (built-in ``still-life``, or a
mesh file) and stores it (:mod:`lodsprite.lumigraph.store`) with the approximate
geometry: the mesh simplified with fast-simplification (``proxy_faces`` triangles).  The
object itself is kept too (``object.npz``), so that renders can be compared with the
ground truth: the mesh drawn directly from the same eye.

Rendering reconstructs every frame with one of the methods of
:mod:`lodsprite.lumigraph.methods` (``full``, §2.3, by default), with depth correction from
the approximate geometry unless switched off, timed up to ``finish()``.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import atomic_write_bytes
from lodsprite.lumigraph.capture import ColorMesh, capture, still_life
from lodsprite.lumigraph.geometry import SIX_DIRECTIONS, SIX_SLABS, slab_facing
from lodsprite.lumigraph.paths import default_path
from lodsprite.lumigraph.reference import OBJECT_FILE
from lodsprite.lumigraph.store import Lumigraph, save
from lodsprite.paths import CameraPath

BUILTIN_OBJECTS = ("still-life",)
DEFAULT_PROXY_FACES = 2000
Progress = Callable[[int, int], None]


def load_object(spec: str) -> ColorMesh:
    """``still-life`` or a mesh file (OBJ, PLY, OFF, STL, GLB, GLTF) with its colours:
    per-vertex or per-face colours as given, a texture sampled at each vertex's texture
    coordinate (trimesh), otherwise one colour; lit by the capture's light either way."""
    if spec in BUILTIN_OBJECTS:
        return still_life()
    import trimesh

    from lodsprite.meshes import MeshError, load_mesh, vertex_colors

    try:
        load_mesh(spec)  # validates the file (one clear line for anything wrong)
        tm = trimesh.load(str(spec), force="mesh", process=False)
        colors = vertex_colors(tm)
    except MeshError as exc:
        raise InputError(str(exc)) from exc
    vertices = np.asarray(tm.vertices, dtype=np.float64)
    faces = np.asarray(tm.faces, dtype=np.int32)
    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals
    if colors is None:
        colors = np.tile([0.8, 0.72, 0.6], (len(vertices), 1))
    return ColorMesh(vertices, faces, colors, np.asarray(normals))


def simplified(mesh: ColorMesh, faces: int) -> ColorMesh:
    """The approximate geometry: ``mesh`` simplified to about ``faces`` triangles."""
    if len(mesh.faces) <= faces:
        return mesh
    import fast_simplification

    v, f = fast_simplification.simplify(mesh.vertices.astype(np.float64),
                                        mesh.faces.astype(np.int64), target_count=int(faces))
    v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int32)
    zeros = np.zeros_like(v)
    return ColorMesh(v, f, zeros, zeros)


def capture_lumigraph(model: str, out_dir: Path, n_st: int = 32, n_uv: int = 256,
                      codec: str = "jpeg", quality: int = 90,
                      proxy_faces: int = DEFAULT_PROXY_FACES, slabs: int = 1,
                      progress: Progress | None = None) -> dict:
    """Capture ``model`` into the lumigraph folder ``out_dir`` with 1 slab (in front,
    +z) or 6 (round it); returns a summary."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.lumigraph import ColorMeshDrawer
    from lodsprite.gl.target import RenderTarget

    if slabs not in (1, 6):
        raise InputError(f"--slabs must be 1 or 6, got {slabs}")
    mesh = load_object(model)
    if slabs == 1:
        planes = [slab_facing(mesh.centre, mesh.radius, SIX_DIRECTIONS[0], n_st, n_uv)]
    else:
        planes = [slab_facing(mesh.centre, mesh.radius, d, n_st, n_uv, **SIX_SLABS)
                  for d in SIX_DIRECTIONS]
    near = 0.05 * planes[0].st_distance
    far = planes[0].st_distance + 2 * mesh.radius * (2.0 if slabs > 1 else 1.0)
    per = n_st * n_st
    t0 = time.perf_counter()
    with GLContext() as gl:
        obj = ColorMeshDrawer(gl, mesh.vertices, mesh.faces, mesh.colors, mesh.normals)
        target = RenderTarget(gl, n_uv, n_uv)
        try:
            images = [capture(obj, slab, target, near, far,
                              (lambda d, t, k=k: progress(k * per + d, slabs * per))
                              if progress else None)
                      for k, slab in enumerate(planes)]
            gl.finish()
        finally:
            target.release()
            obj.release()
    capture_s = time.perf_counter() - t0
    save(out_dir, planes, images, simplified(mesh, proxy_faces), model, near, far, codec,
         quality, capture_s)
    buf = io.BytesIO()
    np.savez_compressed(buf, vertices=mesh.vertices.astype(np.float32), faces=mesh.faces,
                        colors=mesh.colors.astype(np.float32),
                        normals=mesh.normals.astype(np.float32))
    atomic_write_bytes(Path(out_dir) / OBJECT_FILE, buf.getvalue())
    return {"object": model, "nodes": slabs * per, "slabs": slabs, "uv": n_uv,
            "codec": codec, "capture_s": capture_s, "faces": int(len(mesh.faces))}


def render_lumigraph(folder: Path, out_dir: Path, frames: int = 120,
                     size: tuple[int, int] = (512, 512), path: CameraPath | None = None,
                     ground_truth: bool = False, depth_correction: bool = True,
                     method: str = "full", quality_every: int = 1,
                     progress: Progress | None = None, flip: bool = False,
                     **options) -> dict:
    """``lodsprite lumigraph render``, a shortcut onto the batch driver
    (:func:`lodsprite.run.run_scene`): reconstruct every frame of ``path`` (default:
    :func:`~lodsprite.lumigraph.paths.default_path`) with ``method``
    (:data:`~lodsprite.lumigraph.methods.METHODS`; ``options`` go to
    :func:`~lodsprite.lumigraph.methods.make_method`); write ``frames.csv`` and
    ``summary.json`` to ``out_dir`` and return the summary.  With ``ground_truth``, every
    ``quality_every``-th frame is compared (in the harness's untimed replay) with the
    object drawn directly."""
    return _measure(folder, method, path, frames, size, ground_truth, depth_correction,
                    quality_every, progress, flip, Path(out_dir), **options).summary


def measure(folder: Path, method: str = "full", path: CameraPath | None = None,
            frames: int = 120, size: tuple[int, int] = (512, 512), ground_truth: bool = False,
            depth_correction: bool = True, quality_every: int = 1,
            progress: Progress | None = None, flip: bool = False, **options
            ) -> tuple[list[dict], dict]:
    """Run ``method`` along ``path`` through the batch driver, nothing written: the
    per-frame rows and their summary (see :func:`render_lumigraph`); with ``flip``,
    compared frames get FLIP too (0.4 s a 512² frame here)."""
    result = _measure(folder, method, path, frames, size, ground_truth, depth_correction,
                      quality_every, progress, flip, None, **options)
    return result.rows, result.summary


def _measure(folder, method, path, frames, size, ground_truth, depth_correction,
             quality_every, progress, flip, out_dir, **options):
    from lodsprite import techniques
    from lodsprite.driver import Measure
    from lodsprite.lumigraph.technique import viewer_path
    from lodsprite.run import run_scene
    from lodsprite.scene import LightField, Scene

    lf = Lumigraph(folder)
    path = path or default_path(lf, frames)
    if ground_truth and not (Path(folder) / OBJECT_FILE).is_file():
        raise InputError(f"{folder} holds no {OBJECT_FILE}: no ground truth to compare with")
    if f"lumigraph-{method}" not in techniques.names(["lightfield"]):
        raise InputError(f"unknown lumigraph method {method!r}: use one of "
                         f"{', '.join(s.short for s in techniques.specs(['lightfield']))}")
    scene = Scene(lightfields=(LightField(Path(folder)),))
    # the registry's technique; every method option passes (the critical method's own
    # knobs too), checked by its declaration
    return run_scene(scene, f"lumigraph-{method}",
                     {"depth_correction": depth_correction, **options},
                     viewer_path(path), tuple(size), out_dir,
                     Measure(ground_truth, max(1, quality_every), flip), progress=progress,
                     summary={"method": method, "lumigraph": str(folder),
                              "object": lf.header.object, "bad_nodes": len(lf.bad_nodes),
                              "size": list(size), "depth_correction": depth_correction})


class MethodRun:
    """A method, the approximate geometry and the ground truth on one GL context, for
    measurements that read the method's state frame by frame (``reproduce sloan1997``'s
    Table 1); timed runs go through :func:`measure` (the harness)."""

    def __init__(self, gl, lf: Lumigraph, size, depth_correction: bool,
                 obj_mesh: ColorMesh | None, method: str, options: dict) -> None:
        from lodsprite.gl.lumigraph import ColorMeshDrawer
        from lodsprite.gl.target import RenderTarget
        from lodsprite.lumigraph.methods import Context, MultiSlabMethod, make_method

        self.gl, self.made = gl, []
        proxy_mesh = lf.proxy() if depth_correction else None
        self.proxy = (ColorMeshDrawer(gl, proxy_mesh.vertices, proxy_mesh.faces,
                                        proxy_mesh.colors, proxy_mesh.normals)
                      if proxy_mesh is not None else None)
        self.made.append(self.proxy)
        self.truth = (ColorMeshDrawer(gl, obj_mesh.vertices, obj_mesh.faces,
                                        obj_mesh.colors, obj_mesh.normals)
                      if obj_mesh is not None else None)
        self.target = RenderTarget(gl, *size) if self.truth is not None else None
        self.made += [self.truth, self.target]
        ctx = Context(gl, lf, 0, size, self.proxy)
        self.method = (make_method(method, ctx, **options) if len(lf.slabs) == 1
                       else MultiSlabMethod(ctx, method, options))
        self.made.append(self.method)

    def release(self) -> None:
        for obj in reversed(self.made):
            if obj is not None:
                obj.release()
