"""Headless OpenGL context (the only place a moderngl context is created), or an
application's own context wrapped for embedding (:meth:`GLContext.wrap`).

lodsprite renders offscreen through a standalone EGL context: Mesa's llvmpipe
software rasteriser on machines without a GPU, the vendor's driver where there
is one.  OpenGL 3.3 core is required.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import moderngl

from lodsprite.errors import GLUnavailableError, LodspriteError

REQUIRED_GL = 330

MISSING_GL_HELP = (
    "lodsprite could not create a headless OpenGL 3.3 context through EGL ({reason}). "
    "It needs the EGL loader and an OpenGL driver: on Debian/Ubuntu install the packages "
    "libegl1 and libgl1-mesa-dri (Mesa's llvmpipe renders on the CPU when there is no GPU); "
    "with an NVIDIA GPU the vendor driver provides libEGL_nvidia. Set LODSPRITE_GL_BACKEND "
    "to another moderngl/glcontext backend name to try a different one."
)


@functools.cache
def _gl_library() -> ctypes.CDLL | None:
    """The GL dispatch library (glvnd's libOpenGL, else libGL), or None."""
    names = ["libOpenGL.so.0", "libGL.so.1", ctypes.util.find_library("OpenGL"),
             ctypes.util.find_library("GL")]
    for name in filter(None, names):
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None


def _gl_finish():
    """``glFinish`` through ctypes (which releases the GIL while it runs), or None."""
    lib = _gl_library()
    return getattr(lib, "glFinish", None) if lib is not None else None


@functools.cache
def gl_draw_elements_instanced():
    """``glDrawElementsInstanced(mode, count, type, offset, instances)`` through ctypes
    (the GIL released while it runs: on llvmpipe a draw call shades the vertices on the
    calling thread), or None where the GL library cannot be found."""
    lib = _gl_library()
    fn = getattr(lib, "glDrawElementsInstanced", None) if lib is not None else None
    if fn is not None:
        fn.argtypes = [ctypes.c_uint, ctypes.c_int, ctypes.c_uint, ctypes.c_void_p,
                       ctypes.c_int]
        fn.restype = None
    return fn


@functools.cache
def _egl():
    """libEGL with the four calls :func:`keep_current` needs typed, or None."""
    for name in filter(None, ["libEGL.so.1", ctypes.util.find_library("EGL")]):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        for fn in ("eglGetCurrentContext", "eglGetCurrentDisplay"):
            getattr(lib, fn).restype = ctypes.c_void_p
        lib.eglGetCurrentSurface.restype = ctypes.c_void_p
        lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
        lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        lib.eglMakeCurrent.restype = ctypes.c_uint
        return lib
    return None


@contextmanager
def keep_current() -> Iterator[None]:
    """Run a block that creates, enters or releases other contexts (in-process LOD
    profile generation) and make the EGL context current before it current again after
    it (creating a standalone context makes the new one current; the caller's GL objects
    would otherwise be drawn on the wrong context).  Without EGL: a plain block."""
    egl = _egl()
    saved = None
    if egl is not None and egl.eglGetCurrentContext():
        saved = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(0x3059),  # EGL_DRAW
                 egl.eglGetCurrentSurface(0x305A), egl.eglGetCurrentContext())  # EGL_READ
    try:
        yield
    finally:
        if saved is not None:
            egl.eglMakeCurrent(*saved)


class GLError(LodspriteError, RuntimeError):
    """OpenGL reported an error (a bug in lodsprite, or an unsupported driver)."""


@dataclass(frozen=True)
class GLInfo:
    """What the driver reports: renderer and version strings, max texture size (texels)."""

    renderer: str
    version: str
    vendor: str
    max_texture_size: int
    version_code: int


class GLContext:
    """A standalone OpenGL context; owns the moderngl context and releases it."""

    def __init__(self, backend: str | None = None) -> None:
        backend = backend or os.environ.get("LODSPRITE_GL_BACKEND", "egl")
        try:
            self.mgl = moderngl.create_standalone_context(require=REQUIRED_GL, backend=backend)
        except Exception as exc:  # glcontext raises plain Exceptions of several kinds
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise GLUnavailableError(MISSING_GL_HELP.format(reason=reason)) from exc
        self.backend = backend
        self.owned = True
        # The framebuffer bound at creation (id 0); re-bound before a bound target is released.
        self.default_fbo = self.mgl.detect_framebuffer(0)

    @classmethod
    def wrap(cls, mgl: moderngl.Context) -> GLContext:
        """An existing moderngl context (an application's or a window's) for lodsprite to
        draw with (embedding).  It must be current on the calling thread and offer OpenGL
        3.3; lodsprite never releases it (:meth:`release` only forgets it)."""
        if not isinstance(mgl, moderngl.Context):
            raise LodspriteError(f"expected a moderngl.Context, got {type(mgl).__name__}")
        if mgl.version_code < REQUIRED_GL:
            raise GLUnavailableError(f"lodsprite needs OpenGL 3.3; this context offers "
                                     f"{mgl.version_code // 100}.{mgl.version_code % 100 // 10}")
        self = cls.__new__(cls)
        self.mgl = mgl
        self.backend = "external"
        self.owned = False
        self.default_fbo = mgl.screen if mgl.screen is not None else mgl.detect_framebuffer(0)
        return self

    @property
    def info(self) -> GLInfo:
        i = self.mgl.info
        return GLInfo(
            renderer=str(i["GL_RENDERER"]),
            version=str(i["GL_VERSION"]),
            vendor=str(i["GL_VENDOR"]),
            max_texture_size=int(i["GL_MAX_TEXTURE_SIZE"]),
            version_code=int(self.mgl.version_code),
        )

    def finish(self) -> None:
        """Block until all issued GL work is done (call before stopping a clock)."""
        self.mgl.finish()

    def finish_unlocked(self) -> None:
        """:meth:`finish` without holding Python's GIL, for worker threads: moderngl holds
        the GIL in ``glFinish`` (moderngl PR #723), which would stop every other Python
        thread while this context's frame renders.  ``glFinish`` is called through ctypes,
        which releases the GIL, on the context current on the calling thread (this one,
        in the thread that made it)."""
        fn = _gl_finish()
        if fn is None:
            self.mgl.finish()
        else:
            fn()

    def check_error(self, where: str = "") -> None:
        """Raise :class:`GLError` if the GL error flag is set."""
        err = self.mgl.error
        if err != "GL_NO_ERROR":
            raise GLError(f"OpenGL error {err}{' in ' + where if where else ''}")

    def release(self) -> None:
        if self.mgl is not None and self.owned:
            self.mgl.release()
        self.mgl = None

    def __enter__(self) -> GLContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
