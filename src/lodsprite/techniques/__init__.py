"""One technique interface and one registry, for batch runs and the window.

* :class:`Technique`, :class:`Frame`, :class:`Param` — the interface (:mod:`.base`);
* :class:`TechniqueSpec`, :class:`Option`, :func:`register`, :func:`get`, :func:`create`,
  :func:`specs`, :func:`names`, :func:`factories` — the registry (:mod:`.registry`);
* every built-in technique is registered on import (:mod:`.builtin`), by dotted path:
  importing this package imports no technique package (and no moderngl).

A run along a camera path: :func:`lodsprite.harness.run_path`.
"""

from lodsprite.techniques import builtin as _builtin  # noqa: F401  (registers)
from lodsprite.techniques.base import (
    FALLBACK_TINT,
    Frame,
    FrameInfo,
    Param,
    Technique,
    TechniqueFactory,
)
from lodsprite.techniques.registry import (
    LAYERS,
    Option,
    TechniqueSpec,
    create,
    factories,
    get,
    names,
    register,
    specs,
    unregister,
)

__all__ = ["FALLBACK_TINT", "LAYERS", "Frame", "FrameInfo", "Option", "Param", "Technique",
           "TechniqueFactory", "TechniqueSpec", "create", "factories", "get", "names",
           "register", "specs", "unregister"]
