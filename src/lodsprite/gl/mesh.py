"""Flat-shaded triangle meshes under a directional light, instanced, multisampled, offscreen.

Used by LOD-matching profiles (Scoggins et al. 2000 §4.1: each LOD and the full model
rendered with directional light and flat shading) and by the scenes that put many LOD
objects on screen at once (the sphereflake spiral, the mountain sweep).

A :class:`MeshSet` keeps every level of an LOD chain on the GPU; a frame draws any
number of objects, each an ``(level, model matrix, albedo)`` triple, grouped per level
into one instanced draw.  GPU objects live across frames; only the per-instance buffer
is rewritten.
"""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from lodsprite.errors import InputError
from lodsprite.gl.context import GLContext
from lodsprite.gl.shaders import MESH_FS, MESH_VS
from lodsprite.gl.terrain import mat_bytes

DEFAULT_AMBIENT = 0.15
INSTANCE_FLOATS = 16 + 3  # mat4 model (column-major) + vec3 albedo


class MeshSet:
    """GPU copies of meshes ``levels[k] = (vertices (N,3) float32, faces (F,3) int32)``."""

    def __init__(self, ctx: GLContext, levels: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        if not levels:
            raise InputError("a mesh set needs at least one mesh")
        mgl = ctx.mgl
        self.buffers: list[tuple[moderngl.Buffer, moderngl.Buffer, int]] = []
        for vertices, faces in levels:
            v = np.ascontiguousarray(vertices, dtype=np.float32)
            f = np.ascontiguousarray(faces, dtype=np.int32)
            self.buffers.append((mgl.buffer(v.tobytes()), mgl.buffer(f.tobytes()), f.size))
        self.faces = np.array([n // 3 for *_, n in self.buffers], dtype=np.int64)

    def __len__(self) -> int:
        return len(self.buffers)

    def release(self) -> None:
        for vbo, ibo, _ in self.buffers:
            vbo.release()
            ibo.release()
        self.buffers.clear()


class MeshDrawer:
    """Renders :class:`MeshSet` objects into a ``width x height`` multisampled framebuffer.

    ``samples`` is the MSAA sample count (1 = none; reduced to what the driver allows).
    Colour is kept as 32-bit float, so images read back carry no 8-bit quantisation
    (power spectra of nearly identical images are compared).  ``channels=1`` keeps only
    the red channel (grey objects: profiles), which is cheaper on llvmpipe.
    """

    def __init__(self, ctx: GLContext, width: int, height: int, samples: int = 4,
                 channels: int = 4) -> None:
        if channels not in (1, 4):
            raise InputError("channels must be 1 or 4")
        mgl = ctx.mgl
        self.ctx = ctx
        self.size = (int(width), int(height))
        self.samples = max(1, min(int(samples), int(mgl.max_samples)))
        ms = self.samples if self.samples > 1 else 0
        self.channels = channels
        self._ms_color = mgl.renderbuffer(self.size, channels, samples=ms, dtype="f4")
        self._ms_depth = mgl.depth_renderbuffer(self.size, samples=ms)
        self._ms_fbo = mgl.framebuffer([self._ms_color], self._ms_depth)
        self._color = mgl.texture(self.size, channels, dtype="f4")
        self._fbo = mgl.framebuffer([self._color])
        self.program = mgl.program(vertex_shader=MESH_VS, fragment_shader=MESH_FS)
        # One instance buffer per (mesh set, level), grown on demand; GL 3.3 has no base instance.
        self._instances: dict[tuple[int, int], tuple[moderngl.Buffer, int]] = {}
        self._vaos: dict[tuple[int, int], moderngl.VertexArray] = {}

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    def _vao(self, meshes: MeshSet, level: int, count: int) -> moderngl.VertexArray:
        """The vertex array of ``meshes[level]`` with room for ``count`` instances."""
        key = (id(meshes), level)
        buf, capacity = self._instances.get(key, (None, 0))
        if count > capacity:
            if key in self._vaos:
                self._vaos.pop(key).release()
            if buf is not None:
                buf.release()
            capacity = max(count, 2 * capacity, 16)
            buf = self.ctx.mgl.buffer(reserve=capacity * INSTANCE_FLOATS * 4)
            self._instances[key] = (buf, capacity)
        if key not in self._vaos:
            vbo, ibo, _ = meshes.buffers[level]
            self._vaos[key] = self.ctx.mgl.vertex_array(
                self.program,
                [(vbo, "3f", "in_pos"), (buf, "16f 3f/i", "in_model", "in_albedo")],
                index_buffer=ibo, index_element_size=4)
        return self._vaos[key]

    def render(self, meshes: MeshSet, levels: np.ndarray, models: np.ndarray,
               view_proj: np.ndarray, light: Sequence[float],
               albedo: np.ndarray | None = None, ambient: float = DEFAULT_AMBIENT,
               background: Sequence[float] = (0.0, 0.0, 0.0)) -> int:
        """Draw objects ``k`` = mesh ``levels[k]`` placed by ``models[k]`` and return the
        number of triangles submitted.

        ``levels (K,) int``; ``models (K, 4, 4)`` object-to-world; ``view_proj (4, 4)``
        world-to-clip; ``light (3,)`` direction towards the light in world space;
        ``albedo (K, 3)`` linear RGB in [0, 1] (default white).  Issues GL work and returns
        at once: ``ctx.finish()`` before stopping a clock.
        """
        levels = np.asarray(levels, dtype=np.int64).reshape(-1)
        models = np.asarray(models, dtype=np.float64).reshape(-1, 4, 4)
        if len(levels) != len(models):
            raise InputError("levels and models must have the same length")
        if len(levels) and (levels.min() < 0 or levels.max() >= len(meshes)):
            raise InputError(f"mesh level out of range 0..{len(meshes) - 1}")
        albedo = (np.ones((len(levels), 3)) if albedo is None
                  else np.broadcast_to(np.asarray(albedo, dtype=np.float64), (len(levels), 3)))
        light = np.asarray(light, dtype=np.float64)
        light = light / np.linalg.norm(light)
        mgl = self.ctx.mgl
        self._ms_fbo.use()
        self._ms_fbo.clear(*background[:3], 1.0, depth=1.0)
        mgl.enable(moderngl.DEPTH_TEST)
        self.program["u_view_proj"].write(mat_bytes(view_proj))
        self.program["u_light"].value = tuple(light)
        self.program["u_ambient"].value = float(ambient)
        data = np.zeros((len(levels), INSTANCE_FLOATS), dtype=np.float32)
        data[:, :16] = models.transpose(0, 2, 1).reshape(-1, 16)  # column-major mat4
        data[:, 16:] = albedo
        order = np.argsort(levels, kind="stable")
        data, sorted_levels = data[order], levels[order]
        triangles = 0
        starts = np.flatnonzero(np.r_[True, sorted_levels[1:] != sorted_levels[:-1]])
        for start, stop in zip(starts, np.r_[starts[1:], len(sorted_levels)], strict=True):
            if start >= len(sorted_levels):
                break
            level, count = int(sorted_levels[start]), int(stop - start)
            vao = self._vao(meshes, level, count)
            self._instances[(id(meshes), level)][0].write(data[start:stop].tobytes())
            vao.render(moderngl.TRIANGLES, instances=count)
            triangles += int(meshes.faces[level]) * count
        mgl.copy_framebuffer(self._fbo, self._ms_fbo)
        return triangles

    def read_rgb_float(self) -> np.ndarray:
        """Linear colour ``(height, width, 3) float32``, row 0 at the top of the image
        (grey, from the red channel, when ``channels=1``)."""
        if self.channels == 1:
            return np.repeat(self.read_luminance()[:, :, None], 3, axis=2)
        data = self._fbo.read(components=4, dtype="f4")
        img = np.frombuffer(data, np.float32).reshape(self.height, self.width, 4)
        return img[::-1, :, :3].copy()

    def read_luminance(self) -> np.ndarray:
        """Luminance ``(height, width) float32`` (Rec. 709 weights; the red channel when
        ``channels=1``), row 0 at the top."""
        if self.channels == 1:
            data = self._fbo.read(components=1, dtype="f4")
            return np.frombuffer(data, np.float32).reshape(self.height, self.width)[::-1].copy()
        rgb = self.read_rgb_float()
        return (rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)).astype(np.float32)

    def read_rgb8(self) -> np.ndarray:
        """Colour ``(height, width, 3) uint8`` (clamped, rounded), row 0 at the top."""
        return np.clip(np.rint(self.read_rgb_float() * 255.0), 0, 255).astype(np.uint8)

    def forget(self, meshes: MeshSet) -> None:
        """Release the vertex arrays and instance buffers built for ``meshes`` (call before
        releasing the mesh set)."""
        for key in [k for k in self._instances if k[0] == id(meshes)]:
            if key in self._vaos:
                self._vaos.pop(key).release()
            self._instances.pop(key)[0].release()

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for buf, _ in self._instances.values():
            buf.release()
        self._instances.clear()
        if self.ctx.mgl.fbo in (self._ms_fbo, self._fbo):
            self.ctx.default_fbo.use()
        for obj in (self._ms_fbo, self._fbo, self._ms_color, self._ms_depth, self._color,
                    self.program):
            obj.release()
