"""The techniques' options on the command line, from their declarations: a command that
takes ``options`` (name -> value) gets one ``--OPTION`` per option the registry's
techniques declare (:class:`~lodsprite.techniques.Option`), listed by ``--help`` under
"Technique options", each parsed and checked by its declaration (one error line naming
the option, the value and what is allowed).  A plug-in's options join the same way."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterable
from typing import Annotated, Any

import typer

from lodsprite.techniques import Option, all_options

PANEL = "Technique options"
_PREFIX = "opt_"


def _metavar(o: Option) -> str:
    if o.choices:
        return "[" + "|".join(str(c) for c in o.choices) + "]"
    return {int: "INTEGER", float: "FLOAT"}.get(o.type, "TEXT")


def _flags(parameter: inspect.Parameter) -> set[str]:
    """The command-line names a command's own parameter takes."""
    out = {"--" + parameter.name.replace("_", "-")}
    for meta in getattr(parameter.annotation, "__metadata__", ()):
        for decl in getattr(meta, "param_decls", None) or ():
            out.update(d for d in decl.split("/") if d.startswith("--"))
        default = getattr(meta, "default", None)
        if isinstance(default, str) and default.startswith("--"):
            out.update(d for d in default.split("/") if d.startswith("--"))
    return out


def option_parameter(o: Option) -> inspect.Parameter:
    """The typer parameter of ``o``: ``--flag/--no-flag`` for a bool, else text parsed by
    :meth:`Option.parse`; ``None`` (the default) is "not given"."""
    if o.type is bool:
        info = typer.Option(f"{o.cli}/--no-{o.cli[2:]}", help=o.describe(),
                            rich_help_panel=PANEL, show_default=False)
        annotation: Any = Annotated[bool | None, info]
    else:
        info = typer.Option(o.cli, help=o.describe(), metavar=_metavar(o),
                            rich_help_panel=PANEL, show_default=False)
        annotation = Annotated[str | None, info]
    return inspect.Parameter(_PREFIX + o.name, inspect.Parameter.KEYWORD_ONLY,
                             default=None, annotation=annotation)


def with_technique_options(command: Callable[..., Any],
                           layers: Iterable[str] | None = None) -> Callable[..., Any]:
    """``command`` (which takes ``options: dict``) as a typer command with one parameter
    per technique option of the registry (of the techniques drawing ``layers``; all when
    None) that the command does not take itself; the values given reach it parsed in
    ``options``."""
    sig = inspect.signature(command, eval_str=True)
    own = [p for p in sig.parameters.values() if p.name != "options"]
    taken = set().union(*(_flags(p) for p in own))
    declared = [o for o in all_options(layers).values()
                if o.on_command_line and o.cli not in taken]

    @functools.wraps(command)
    def run(**kwargs: Any) -> Any:
        options = {}
        for o in declared:
            value = kwargs.pop(_PREFIX + o.name, None)
            if value is not None:
                options[o.name] = o.parse(value) if isinstance(value, str) else o.check(value)
        return command(**kwargs, options=options)

    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own]
    run.__signature__ = sig.replace(parameters=[*params, *map(option_parameter, declared)],
                                    return_annotation=None)  # type: ignore[attr-defined]
    return run


__all__ = ["PANEL", "option_parameter", "with_technique_options"]
