"""The one technique registry: name -> :class:`TechniqueSpec` (factory, options, the scene
layers it draws, description).  ``render``, ``view``, ``lumigraph render``, ``crowd``,
``client`` and the viewer read it; adding a technique is one class and one
:func:`register` call (see ``examples/custom_technique.py``).

Factories are named by dotted path (``"package.module:callable"``) and imported only when
a technique is made, so this module imports no technique package.  A factory is called as
``factory(renderer, **options)`` where ``options`` are the spec's :class:`Option` values
(defaults filled in) and its ``fixed`` keywords.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from lodsprite.errors import InputError

if TYPE_CHECKING:
    from lodsprite.api import Renderer
    from lodsprite.techniques.base import Technique, TechniqueFactory

#: The scene layers techniques draw (:mod:`lodsprite.scene`).
LAYERS = ("terrain", "objects", "lightfield")


@dataclass(frozen=True)
class Option:
    """One option of a technique: name (a Python identifier, ``--name`` on the command
    line with ``_`` as ``-``), type, default and one line of help."""

    name: str
    type: type
    default: Any
    help: str = ""


@dataclass(frozen=True)
class TechniqueSpec:
    """A registered technique.

    ``name``: the registry key (unique); ``factory``: ``"module:callable"`` or a callable
    ``(renderer, **options) -> Technique``; ``options``: what it takes; ``layers``: the scene
    layers it draws (a scene offers the techniques whose layers it has); ``description``:
    one line; ``mode``: the short name the viewer and the commands show (default: ``name``);
    ``fixed``: keywords always passed to the factory (e.g. a lumigraph method's name).
    """

    name: str
    factory: str | Callable[..., Technique]
    options: tuple[Option, ...] = ()
    layers: tuple[str, ...] = ("terrain",)
    description: str = ""
    mode: str = ""
    fixed: dict[str, Any] = field(default_factory=dict)

    @property
    def short(self) -> str:
        """The mode name shown to users."""
        return self.mode or self.name

    def defaults(self) -> dict[str, Any]:
        return {o.name: o.default for o in self.options}

    def load(self) -> Callable[..., Technique]:
        """The factory itself (its module imported now)."""
        if callable(self.factory):
            return self.factory
        module, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module), attr)

    def bind(self, options: dict[str, Any]) -> dict[str, Any]:
        """The spec's options out of ``options`` (others ignored), defaults filled in."""
        return {**self.defaults(), **{k: v for k, v in options.items()
                                      if k in self.defaults() and v is not None}}

    def create(self, renderer: Renderer, **options: Any) -> Technique:
        """Make the technique on ``renderer``; unknown options raise ``InputError``."""
        unknown = set(options) - set(self.defaults())
        if unknown:
            raise InputError(f"{self.name} takes no option {', '.join(sorted(unknown))}; "
                             f"its options: {', '.join(self.defaults()) or 'none'}")
        return self.load()(renderer, **self.bind(options), **self.fixed)

    def factory_for(self, **options: Any) -> TechniqueFactory:
        """A ``(renderer) -> Technique`` factory with the spec's options out of
        ``options`` (the viewer's form)."""
        bound = self.bind(options)
        return lambda renderer: self.load()(renderer, **bound, **self.fixed)


_REGISTRY: dict[str, TechniqueSpec] = {}


def register(spec: TechniqueSpec, replace: bool = False) -> TechniqueSpec:
    """Add ``spec`` to the registry (``replace``: over one of the same name)."""
    if spec.name in _REGISTRY and not replace:
        raise InputError(f"a technique named {spec.name!r} is registered already")
    unknown = set(spec.layers) - set(LAYERS)
    if unknown:
        raise InputError(f"unknown layer {', '.join(sorted(unknown))}: use {', '.join(LAYERS)}")
    _REGISTRY[spec.name] = spec
    return spec


def unregister(name: str) -> None:
    """Remove a technique (tests, plug-ins)."""
    _REGISTRY.pop(name, None)


def get(name: str) -> TechniqueSpec:
    """The spec registered as ``name`` (raises ``InputError`` naming the choices)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(f"unknown technique {name!r}: use one of "
                         f"{', '.join(_REGISTRY)}") from None


def specs(layers: Iterable[str] | None = None) -> list[TechniqueSpec]:
    """Every registered spec in registration order; with ``layers``, those that draw
    only layers among them (what a scene with those layers can show)."""
    if layers is None:
        return list(_REGISTRY.values())
    have = set(layers)
    return [s for s in _REGISTRY.values() if set(s.layers) <= have]


def names(layers: Iterable[str] | None = None) -> tuple[str, ...]:
    """The registered names (of :func:`specs` ``(layers)``)."""
    return tuple(s.name for s in specs(layers))


def create(name: str, renderer: Renderer, **options: Any) -> Technique:
    """Make technique ``name`` on ``renderer`` with ``options``."""
    return get(name).create(renderer, **options)


def factories(layers: Iterable[str], exclude: Iterable[str] = (),
              **options: Any) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a scene with ``layers``: short name -> factory, each with
    the options of ``options`` it declares; ``exclude``: names left out."""
    skip = set(exclude)
    return {s.short: s.factory_for(**options) for s in specs(layers) if s.name not in skip}
