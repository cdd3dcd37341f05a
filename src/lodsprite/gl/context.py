"""Headless OpenGL context (the only place a moderngl context is created).

lodsprite renders offscreen through a standalone EGL context: Mesa's llvmpipe
software rasteriser on machines without a GPU, the vendor's driver where there
is one.  OpenGL 3.3 core is required.
"""

from __future__ import annotations

import os
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
        # The framebuffer bound at creation (id 0); re-bound before a bound target is released.
        self.default_fbo = self.mgl.detect_framebuffer(0)

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

    def check_error(self, where: str = "") -> None:
        """Raise :class:`GLError` if the GL error flag is set."""
        err = self.mgl.error
        if err != "GL_NO_ERROR":
            raise GLError(f"OpenGL error {err}{' in ' + where if where else ''}")

    def release(self) -> None:
        if self.mgl is not None:
            self.mgl.release()
            self.mgl = None

    def __enter__(self) -> GLContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
