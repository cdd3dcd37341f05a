"""Configs that carry technique options (:class:`TechniqueOptions`, :func:`takes_options`):
:class:`~lodsprite.run.RenderConfig` and :class:`~lodsprite.viewer.app.ViewOptions` hold
the options a user gave in one mapping, each declared once by its technique's
:class:`~lodsprite.techniques.Option`, never as fields of their own."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from lodsprite.techniques.registry import all_options


class TechniqueOptions:
    """A config that carries the technique options it was given in ``options`` (name ->
    value; a name not there was not given) and reads each as an attribute: ``c.epsilon``
    is ``c.options["epsilon"]``, else the option's declared default (the registry's
    first declaration of the name).  Use with :func:`takes_options`."""

    options: Mapping[str, Any]

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name == "options":
            raise AttributeError(name)
        known = all_options()
        if name not in known:
            raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")
        return self.options.get(name, known[name].default)

    def flat(self) -> dict[str, Any]:
        """The fields and the options given in one dict (a summary's ``config``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)  # type: ignore[arg-type]
               if f.name != "options"}
        return {**out, **self.options}


def takes_options(cls: type) -> type:
    """Class decorator, after ``@dataclass``: the constructor also takes technique options
    as keywords (``RenderConfig(mode="sprite", epsilon=2.0)``), merged into ``options``;
    a name no registered technique declares raises ``TypeError`` as any unknown keyword,
    and ``None`` (not given) is left out."""
    init = cls.__init__
    own = {f.name for f in fields(cls)}

    @functools.wraps(init)
    def __init__(self, *args: Any, options: Mapping[str, Any] | None = None,
                 **kw: Any) -> None:
        extra = {k: v for k, v in kw.items() if k not in own}
        unknown = set(extra) - set(all_options())
        if unknown:
            raise TypeError(f"{cls.__name__} got unexpected keyword(s) "
                            f"{', '.join(sorted(unknown))}")
        merged = {k: v for k, v in {**(options or {}), **extra}.items() if v is not None}
        init(self, *args, options=merged, **{k: v for k, v in kw.items() if k in own})

    cls.__init__ = __init__  # type: ignore[misc]
    return cls


__all__ = ["TechniqueOptions", "takes_options"]
