"""The one technique registry: name -> :class:`TechniqueSpec` (factory, options, the scene
layers it draws, description).  ``render``, ``view``, ``lumigraph render``, ``crowd``,
``client``, scene files, ``info`` and the viewer read it.

Techniques are plug-ins: every spec, the built-in ones too, is named by an entry point of
the group ``lodsprite.techniques`` (``pyproject.toml``), and the registry loads them from
the installed distributions' metadata the first time it is asked (:func:`discover`); a
plug-in that fails to load is left out with one warning line.  :func:`register` adds a
spec in the running process (``examples/custom_technique.py``).  A factory is called as
``factory(renderer, **options)`` with the spec's :class:`Option` values (defaults filled
in, checked) and its ``fixed`` keywords.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any

from lodsprite.errors import InputError
from lodsprite.techniques.options import Option, merge

if TYPE_CHECKING:
    from lodsprite.scene import Scene
    from lodsprite.techniques.base import RendererLike, Technique, TechniqueFactory

#: The scene layers techniques draw (:mod:`lodsprite.scene`).
LAYERS = ("terrain", "objects", "lightfield")
#: The entry-point group techniques register through.
GROUP = "lodsprite.techniques"
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TechniqueSpec:
    """A registered technique.

    ``name``: the registry key (unique); ``factory``: a callable ``(renderer, **options)
    -> Technique`` (the class itself, or a function that imports it when called, so that
    reading the registry imports no GL); ``options``: what it takes, each declared once
    (:class:`Option`); ``layers``: the scene layers it draws (a scene offers the
    techniques whose layers it has); ``description``: one line; ``mode``: the short name
    the viewer and the commands show (default: ``name``); ``fixed``: keywords always
    passed to the factory (e.g. a lumigraph method's name); ``order``: where it sorts in
    lists and the viewer's keys 1-9 (plug-ins after the built-ins by default);
    ``light``: over a terrain store it draws the store itself, never the scene's
    in-memory grid (the batch driver loads a light scene); ``batch``: ``render --mode``
    runs it (False: the window and scenes only); ``knob``: the live parameter a scene's
    frame budget turns (``epsilon``, ``sse``, ``lod``; empty: none); ``summary``: lines
    ``render`` prints after its table, ``str.format`` templates over the run's summary.
    """

    name: str
    factory: Callable[..., Technique]
    options: tuple[Option, ...] = ()
    layers: tuple[str, ...] = ("terrain",)
    description: str = ""
    mode: str = ""
    fixed: dict[str, Any] = field(default_factory=dict)
    order: int = 1000
    light: bool = False
    batch: bool = True
    knob: str = ""
    summary: tuple[str, ...] = ()

    @property
    def short(self) -> str:
        """The mode name shown to users."""
        return self.mode or self.name

    def option(self, name: str) -> Option:
        for o in self.options:
            if o.name == name:
                return o
        raise InputError(f"{self.name} takes no option {name}; its options: "
                         f"{', '.join(o.name for o in self.options) or 'none'}")

    def defaults(self) -> dict[str, Any]:
        return {o.name: o.default for o in self.options}

    def bind(self, options: dict[str, Any]) -> dict[str, Any]:
        """The spec's options out of ``options`` (others ignored, ``None``: not given),
        checked (:meth:`Option.check`), defaults filled in."""
        given = {o.name: o.check(options[o.name]) for o in self.options
                 if options.get(o.name) is not None}
        return {**self.defaults(), **given}

    def create(self, renderer: RendererLike, **options: Any) -> Technique:
        """Make the technique on ``renderer``; an unknown option or a bad value raises
        :class:`InputError` (one line naming the option)."""
        for name in options:
            self.option(name)
        return self.factory(renderer, **self.bind(options), **self.fixed)

    def factory_for(self, **options: Any) -> TechniqueFactory:
        """A ``(renderer) -> Technique`` factory with the spec's options out of
        ``options`` (the viewer's form)."""
        bound = self.bind(options)
        return lambda renderer: self.factory(renderer, **bound, **self.fixed)


_REGISTRY: dict[str, TechniqueSpec] = {}
_DISCOVERED = False


def _add(spec: TechniqueSpec, replace: bool) -> TechniqueSpec:
    if not isinstance(spec, TechniqueSpec):
        raise InputError(f"not a TechniqueSpec: {spec!r}")
    if spec.name in _REGISTRY and not replace:
        raise InputError(f"a technique named {spec.name!r} is registered already")
    unknown = set(spec.layers) - set(LAYERS)
    if unknown:
        raise InputError(f"unknown layer {', '.join(sorted(unknown))}: use {', '.join(LAYERS)}")
    _REGISTRY[spec.name] = spec
    return spec


def discover() -> None:
    """Load every spec the installed distributions name under :data:`GROUP`, once (a
    spec registered already by :func:`register` is kept); a plug-in that fails to load is
    left out with one warning line."""
    global _DISCOVERED
    if _DISCOVERED:
        return
    _DISCOVERED = True
    seen: set[str] = set()
    for ep in entry_points(group=GROUP):
        if ep.name in seen:
            continue
        seen.add(ep.name)
        try:
            spec = ep.load()
            if spec.name not in _REGISTRY:
                _add(spec, False)
        except Exception as exc:  # a broken plug-in must not stop the others
            log.warning("technique plug-in %s (%s) left out: %s: %s", ep.name, ep.value,
                        type(exc).__name__, exc)
    if not _REGISTRY:
        log.warning("no technique registered: the %s entry points are missing (reinstall "
                    "lodsprite: pip install -e .)", GROUP)


def register(spec: TechniqueSpec, replace: bool = False) -> TechniqueSpec:
    """Add ``spec`` to the registry in this process (``replace``: over one of the same
    name)."""
    discover()
    return _add(spec, replace)


def unregister(name: str) -> None:
    """Remove a technique (tests, plug-ins)."""
    discover()
    _REGISTRY.pop(name, None)


def get(name: str) -> TechniqueSpec:
    """The spec registered as ``name`` (raises ``InputError`` naming the choices)."""
    discover()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(f"unknown technique {name!r}: use one of "
                         f"{', '.join(names())}") from None


def specs(layers: Iterable[str] | None = None) -> list[TechniqueSpec]:
    """Every registered spec by ``order`` (then registration); with ``layers``, those
    that draw only layers among them (what a scene with those layers can show)."""
    discover()
    ordered = sorted(_REGISTRY.values(), key=lambda s: s.order)
    if layers is None:
        return ordered
    have = set(layers)
    return [s for s in ordered if set(s.layers) <= have]


def for_scene(scene: Scene, mode: str | None = None) -> TechniqueSpec:
    """The spec that ``mode`` names (its name or short name; default: the scene's own
    ``mode``) among the batch techniques that draw ``scene``'s layers: the one ``render``,
    the window and the served surfaces draw ``scene`` with; else an
    :class:`~lodsprite.errors.InputError` naming the choices."""
    mode = mode or scene.mode
    usable = [s for s in specs(scene.layers) if s.batch]
    for spec in usable:
        if mode in (spec.name, spec.short):
            return spec
    raise InputError(f"unknown mode '{mode}' for {scene.name} ({', '.join(scene.layers)}): "
                     f"use one of {', '.join(s.short for s in usable) or 'none'}")


def names(layers: Iterable[str] | None = None) -> tuple[str, ...]:
    """The registered names (of :func:`specs` ``(layers)``)."""
    return tuple(s.name for s in specs(layers))


def create(name: str, renderer: RendererLike, **options: Any) -> Technique:
    """Make technique ``name`` on ``renderer`` with ``options`` (checked by the spec's
    :class:`Option` declarations)."""
    return get(name).create(renderer, **options)


def factories(layers: Iterable[str], exclude: Iterable[str] = (),
              **options: Any) -> dict[str, TechniqueFactory]:
    """The viewer's modes for a scene with ``layers``: short name -> factory, each with
    the options of ``options`` it declares; ``exclude``: names left out."""
    skip = set(exclude)
    return {s.short: s.factory_for(**options) for s in specs(layers) if s.name not in skip}


def all_options(layers: Iterable[str] | None = None) -> dict[str, Option]:
    """Every registered technique's options by name (the first declaration of a name):
    what a command line offers as ``--OPTION``."""
    return merge(s.options for s in specs(layers))
