"""lodsprite: time-critical rendering of large datasets with LOD geometry and image reuse."""

from lodsprite.errors import (
    GLUnavailableError,
    InputError,
    LodspriteError,
    PathError,
    TerrainError,
)

__version__ = "0.1.0"

__all__ = [
    "GLUnavailableError",
    "InputError",
    "LodspriteError",
    "PathError",
    "TerrainError",
    "__version__",
]
