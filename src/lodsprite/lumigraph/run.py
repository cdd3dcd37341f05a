"""Capturing a lumigraph and rendering it along a camera path: the engine behind
``lodsprite lumigraph capture`` and ``lodsprite lumigraph render``.

Capture renders every st node's uv image of an object (built-in ``still-life``, or a
mesh file) and stores it (:mod:`lodsprite.lumigraph.store`) with the approximate
geometry: the mesh simplified with fast-simplification (``proxy_faces`` triangles).  The
object itself is kept too (``object.npz``), so that renders can be compared with the
ground truth: the mesh drawn directly from the same eye.

Rendering reconstructs every frame from all nodes (the ``full`` method, §2.3), with depth
correction from the approximate geometry unless switched off, timed up to ``finish()``.
"""

from __future__ import annotations

import io
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint, look_at, perspective
from lodsprite.errors import InputError
from lodsprite.lumigraph.capture import ColorMesh, capture, still_life
from lodsprite.lumigraph.geometry import Slab, slab_facing
from lodsprite.lumigraph.store import Lumigraph, save
from lodsprite.paths import CameraPath
from lodsprite.report.io import atomic_write_bytes, write_csv, write_json

OBJECT_FILE = "object.npz"
BUILTIN_OBJECTS = ("still-life",)
DEFAULT_PROXY_FACES = 2000
FOV_Y_DEG = 30.0
Progress = Callable[[int, int], None]


def load_object(spec: str) -> ColorMesh:
    """``still-life`` or a mesh file (OBJ, PLY, OFF, STL, GLB, GLTF), drawn in one colour
    under the light (its own colours are not read yet)."""
    if spec in BUILTIN_OBJECTS:
        return still_life()
    import trimesh

    from lodsprite.profiles.meshes import MeshError, load_mesh

    try:
        mesh = load_mesh(spec)
    except MeshError as exc:
        raise InputError(str(exc)) from exc
    normals = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals
    colors = np.tile([0.8, 0.72, 0.6], (len(mesh.vertices), 1))
    return ColorMesh(mesh.vertices, mesh.faces.astype(np.int32), colors, np.asarray(normals))


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
                      proxy_faces: int = DEFAULT_PROXY_FACES,
                      progress: Progress | None = None) -> dict:
    """Capture ``model`` into the lumigraph folder ``out_dir``; returns a summary."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.lumigraph import ColorMeshRenderer
    from lodsprite.gl.target import RenderTarget

    mesh = load_object(model)
    slab = slab_facing(mesh.centre, mesh.radius, np.array([0.0, 0.0, 1.0]), n_st, n_uv)
    near, far = 0.05 * slab.st_distance, slab.st_distance + 2 * mesh.radius
    t0 = time.perf_counter()
    with GLContext() as gl:
        obj = ColorMeshRenderer(gl, mesh.vertices, mesh.faces, mesh.colors, mesh.normals)
        target = RenderTarget(gl, n_uv, n_uv)
        try:
            images = capture(obj, slab, target, near, far, progress)
            gl.finish()
        finally:
            target.release()
            obj.release()
    capture_s = time.perf_counter() - t0
    save(out_dir, [slab], [images], simplified(mesh, proxy_faces), model, near, far, codec,
         quality, capture_s)
    buf = io.BytesIO()
    np.savez_compressed(buf, vertices=mesh.vertices.astype(np.float32), faces=mesh.faces,
                        colors=mesh.colors.astype(np.float32),
                        normals=mesh.normals.astype(np.float32))
    atomic_write_bytes(Path(out_dir) / OBJECT_FILE, buf.getvalue())
    return {"object": model, "nodes": n_st * n_st, "uv": n_uv, "codec": codec,
            "capture_s": capture_s, "faces": int(len(mesh.faces))}


def object_path(slab: Slab, frames: int, arc_deg: float = 50.0) -> CameraPath:
    """An arc of ``frames`` viewpoints in front of the slab, looking at the uv plane's
    centre, that stays within the st plane's coverage: eyes at 1.6 times the st plane's
    distance, swinging ``arc_deg`` degrees about the slab's up axis, a little above."""
    if frames < 2:
        raise InputError(f"a path needs at least 2 frames, got {frames}")
    d = 1.6 * slab.st_distance
    a = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, frames))
    local = np.stack([d * np.sin(a), np.full_like(a, 0.12 * d), d * np.cos(a),
                      np.ones_like(a)], axis=1)
    eyes = local @ slab.frame.T
    centre = slab.frame[:3, 3]
    up = slab.frame[:3, 1]
    return CameraPath("lumigraph-arc", tuple(look_at(e[:3], centre, up) for e in eyes),
                      FOV_Y_DEG)


def _read_object(folder: Path) -> ColorMesh | None:
    path = folder / OBJECT_FILE
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        return ColorMesh(z["vertices"].astype(np.float64), z["faces"].astype(np.int32),
                         z["colors"].astype(np.float64), z["normals"].astype(np.float64))


def render_lumigraph(folder: Path, out_dir: Path, frames: int = 120,
                     size: tuple[int, int] = (512, 512), path: CameraPath | None = None,
                     ground_truth: bool = False, depth_correction: bool = True,
                     progress: Progress | None = None) -> dict:
    """Reconstruct every frame of ``path`` (default: :func:`object_path`) from all nodes;
    write ``frames.csv`` and ``summary.json`` to ``out_dir`` and return the summary."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.lumigraph import ColorMeshRenderer, LumigraphRenderer
    from lodsprite.gl.target import RenderTarget

    lf = Lumigraph(folder)
    slab = lf.slabs[0]
    path = path or object_path(slab, frames)
    obj_mesh = _read_object(Path(folder)) if ground_truth else None
    if ground_truth and obj_mesh is None:
        raise InputError(f"{folder} holds no {OBJECT_FILE}: no ground truth to compare with")
    w, h = size
    proj = perspective(path.fov_y_deg, w / h, lf.header.near, 4 * lf.header.far)
    t0 = time.perf_counter()
    images = lf.nodes(0)
    load_s = time.perf_counter() - t0
    rows = []
    with GLContext() as gl:
        proxy_mesh = lf.proxy() if depth_correction else None
        proxy = (ColorMeshRenderer(gl, proxy_mesh.vertices, proxy_mesh.faces,
                                   proxy_mesh.colors, proxy_mesh.normals)
                 if proxy_mesh is not None else None)
        rec = LumigraphRenderer(gl, slab, images, w, h)
        truth = (ColorMeshRenderer(gl, obj_mesh.vertices, obj_mesh.faces, obj_mesh.colors,
                                   obj_mesh.normals) if obj_mesh is not None else None)
        target = RenderTarget(gl, w, h) if truth is not None else None
        try:
            rec.render(path.viewpoints[0].view_matrix(), proj, proxy)  # warm-up, untimed
            gl.finish()
            for i, vp in enumerate(path.viewpoints):
                rows.append(_frame(gl, rec, proxy, truth, target, vp, proj, i))
                if progress:
                    progress(i + 1, len(path))
        finally:
            for obj in (rec, proxy, truth, target):
                if obj is not None:
                    obj.release()
        renderer = gl.info.renderer
    ms = np.array([r["ms"] for r in rows])
    summary = {"frames": len(rows), "method": "full", "lumigraph": str(folder),
               "object": lf.header.object, "nodes": len(images),
               "bad_nodes": len(lf.bad_nodes), "size": [w, h],
               "depth_correction": depth_correction, "load_s": load_s,
               "median_ms": float(np.median(ms)), "mean_ms": float(ms.mean()),
               "p99_ms": float(np.percentile(ms, 99)),
               "images_per_frame_mean": float(len(images)),
               "gl_renderer": renderer, "machine": platform.machine()}
    if ground_truth:
        summary["psnr_mean"] = float(np.mean([r["psnr"] for r in rows]))
        summary["ssim_mean"] = float(np.mean([r["ssim"] for r in rows]))
    columns = ["frame", "ms", "images"] + (["psnr", "ssim"] if ground_truth else [])
    write_csv(Path(out_dir) / "frames.csv", rows, columns)
    write_json(Path(out_dir) / "summary.json", summary)
    return summary


def _frame(gl, rec, proxy, truth, target, vp: Viewpoint, proj, i: int) -> dict:
    """One timed reconstruction (and, untimed, its PSNR/SSIM against ``truth``)."""
    view = vp.view_matrix()
    t0 = time.perf_counter()
    rec.render(view, proj, proxy)
    gl.finish()
    row = {"frame": i, "ms": (time.perf_counter() - t0) * 1e3, "images": rec.images}
    if truth is not None:  # untimed
        from lodsprite.metrics import psnr, ssim

        got = rec.read_rgb8()
        truth.render(proj @ view, target.fbo)
        want = target.read_color()
        row.update(psnr=psnr(got, want), ssim=ssim(got, want))
    return row
