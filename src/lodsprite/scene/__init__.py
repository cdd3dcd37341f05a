"""One scene model: a :class:`Scene` holds typed layers, and techniques draw them.

* :mod:`lodsprite.scene.model`: :class:`Scene`, its layers (:class:`LightField`, the
  object sets' union ``ObjectSet``), :class:`CameraHome` and :func:`load_scene` (a terrain);
* :mod:`lodsprite.scene.kinds`: :func:`open_scene`, one opener for every kind of spec,
  kinds of other packages registered through the ``lodsprite.scenes`` entry points;
* :mod:`lodsprite.scene.spec`: :class:`SceneSpec`, a scene's description on the wire;
* :mod:`lodsprite.scene.file` and :mod:`lodsprite.scene.world`: scene files and their
  object sets over time (:class:`~lodsprite.scene.world.World`).

Nothing of this package imports rendering (``tests/test_layering.py``).
"""

from lodsprite.scene.kinds import ENTRY_POINT_GROUP, SceneKind, open_scene, scene_kinds
from lodsprite.scene.model import LIGHT_SIDE, CameraHome, LightField, Scene, load_scene

__all__ = ["ENTRY_POINT_GROUP", "LIGHT_SIDE", "CameraHome", "LightField", "Scene",
           "SceneKind", "load_scene", "open_scene", "scene_kinds"]
