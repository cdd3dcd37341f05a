"""One technique interface and one registry, for batch runs and the window.

* :class:`Technique`, :class:`Frame`, :class:`Param` — the interface (:mod:`.base`);
* :class:`TechniqueSpec`, :class:`Option`, :func:`register`, :func:`get`, :func:`create`,
  :func:`specs`, :func:`names`, :func:`factories` — the registry (:mod:`.registry`);
* :class:`Option` — an option, declared once (:mod:`.options`);
* techniques are plug-ins: every spec, the built-in ones (:mod:`.builtin` and the
  packages' ``spec`` modules) too, is named by an entry point of the group
  ``lodsprite.techniques`` and loaded the first time the registry is asked; importing
  this package imports no technique package (and no moderngl).

A run along a camera path: :func:`lodsprite.harness.run_path`.
"""

from lodsprite.techniques.base import (
    FALLBACK_TINT,
    Frame,
    FrameInfo,
    Param,
    Technique,
    TechniqueFactory,
)
from lodsprite.techniques.options import Option
from lodsprite.techniques.registry import (
    GROUP,
    LAYERS,
    TechniqueSpec,
    all_options,
    create,
    discover,
    factories,
    for_scene,
    get,
    names,
    register,
    specs,
    unregister,
)

__all__ = ["FALLBACK_TINT", "GROUP", "LAYERS", "Frame", "FrameInfo", "Option", "Param",
           "Technique", "TechniqueFactory", "TechniqueSpec", "all_options", "create",
           "discover", "factories", "for_scene", "get", "names", "register", "specs", "unregister"]
