"""Typed exceptions of the lodsprite API.

Every error a user can cause (a missing file, a malformed spec, an impossible
parameter) is raised as a subclass of :class:`LodspriteError`; the CLI turns
these into one line on stderr and exit code 2.
"""

from __future__ import annotations


class LodspriteError(Exception):
    """Base class of every error lodsprite raises on purpose."""


class InputError(LodspriteError, ValueError):
    """A user-supplied value (argument, option, spec) is invalid."""


class TerrainError(InputError):
    """A height field or texture could not be loaded or is unusable."""


class PathError(InputError):
    """A camera path could not be built or loaded."""


class GLUnavailableError(LodspriteError, RuntimeError):
    """No OpenGL 3.3+ context could be created (missing EGL/Mesa libraries)."""


class MeshError(InputError):
    """A mesh file or model spec could not be loaded or is unusable."""


class SceneFileError(InputError):
    """A scene file (TOML, :mod:`lodsprite.scene.file`) is malformed or names something
    unusable; the message is one line naming the file and the field."""
