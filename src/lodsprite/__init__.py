"""lodsprite: time-critical rendering of large datasets with LOD geometry and image reuse.

The public API (see the README's "Python API" section):

* scenes: :func:`load_scene` (terrain and texture specs) and :func:`open_scene` (any
  scene: a terrain, a lumigraph folder, a crowd) -> :class:`Scene`, which holds layers;
* rendering: :class:`RenderActor` (standalone headless context, or an application's
  moderngl context for embedding), :meth:`Renderer.sprite` -> :class:`LodSprite`, the
  LOD-sprite engine frame by frame (keyframes inline, or from a worker process);
* cameras and paths: :class:`Viewpoint`, :func:`look_at`, :class:`CameraPath`,
  :func:`get_path` (built-in paths and JSON files), :func:`load_path_json`;
* images: :func:`read_image`, :func:`write_image`;
* batch runs: :class:`RenderConfig` and :func:`render_path` (what ``lodsprite render``
  does);
* techniques, for batch runs and the window alike: :class:`Technique` (frames as
  :class:`Frame`), the registry (:class:`TechniqueSpec`, :class:`Option`, :func:`register`,
  module :mod:`lodsprite.techniques`), :func:`run_path`, the one harness, and
  :func:`view_scene`, the viewer window with your own techniques;
* notebooks: :func:`widget`, a Jupyter widget flying a terrain (the ``notebook`` extra);
* errors: :class:`LodspriteError` and its subclasses.
"""

from typing import TYPE_CHECKING

from lodsprite.errors import (
    GLUnavailableError,
    InputError,
    LodspriteError,
    PathError,
    TerrainError,
)

# Where each public name lives.  They load on first use (PEP 562), so that importing one
# GL-free module (``lodsprite.sprite.policy``, say) does not load OpenGL.
_LAZY = {
    "LodSprite": "lodsprite.api", "Renderer": "lodsprite.api", "read_image": "lodsprite.api",
    "write_image": "lodsprite.api", "Projection": "lodsprite.camera",
    "Viewpoint": "lodsprite.camera", "look_at": "lodsprite.camera",
    "CameraPath": "lodsprite.paths", "get_path": "lodsprite.paths",
    "load_path_json": "lodsprite.paths", "RenderConfig": "lodsprite.runconfig",
    "render_path": "lodsprite.run", "Scene": "lodsprite.scene",
    "load_scene": "lodsprite.scene", "SpriteFrame": "lodsprite.sprite.engine",
    "FrameInfo": "lodsprite.techniques", "Param": "lodsprite.techniques",
    "Technique": "lodsprite.techniques", "terrain_techniques": "lodsprite.technique",
    "Frame": "lodsprite.techniques", "TechniqueSpec": "lodsprite.techniques",
    "Option": "lodsprite.techniques", "register": "lodsprite.techniques",
    "run_path": "lodsprite.harness", "open_scene": "lodsprite.techniques.scenes",
    "view_scene": "lodsprite.viewer.app", "widget": "lodsprite.notebook",
}

if TYPE_CHECKING:
    from lodsprite.api import LodSprite, Renderer, read_image, write_image
    from lodsprite.camera import Projection, Viewpoint, look_at
    from lodsprite.harness import run_path
    from lodsprite.notebook import widget
    from lodsprite.paths import CameraPath, get_path, load_path_json
    from lodsprite.run import render_path
    from lodsprite.runconfig import RenderConfig
    from lodsprite.scene import Scene, load_scene
    from lodsprite.sprite.engine import SpriteFrame
    from lodsprite.technique import terrain_techniques
    from lodsprite.techniques import (
        Frame,
        FrameInfo,
        Option,
        Param,
        Technique,
        TechniqueSpec,
        register,
    )
    from lodsprite.techniques.scenes import open_scene
    from lodsprite.viewer.app import view_scene


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lodsprite' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)


__version__ = "0.1.0"

__all__ = [
    "CameraPath",
    "Frame",
    "FrameInfo",
    "GLUnavailableError",
    "InputError",
    "LodSprite",
    "LodspriteError",
    "Option",
    "Param",
    "PathError",
    "Projection",
    "RenderConfig",
    "Renderer",
    "Scene",
    "SpriteFrame",
    "Technique",
    "TechniqueSpec",
    "TerrainError",
    "Viewpoint",
    "__version__",
    "get_path",
    "load_path_json",
    "load_scene",
    "look_at",
    "open_scene",
    "read_image",
    "register",
    "render_path",
    "run_path",
    "terrain_techniques",
    "view_scene",
    "widget",
    "write_image",
]
