"""A technique option, declared once (:class:`Option`): name, type, default, range or
choices, unit and help.  Every front end reads it: ``render`` and ``view`` make their
``--OPTION`` parameters from it, a scene file's ``[terrain]`` options, the web page's query
and :func:`lodsprite.techniques.create` parse and check values through it, so the error
line a user sees names the option, the value and what is allowed, the same everywhere.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from lodsprite.errors import InputError

_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


@dataclass(frozen=True)
class Option:
    """One option of a technique.

    ``name``: a Python identifier (the factory's keyword); ``type``: ``int``, ``float``,
    ``str``, ``bool`` or ``object`` (an object option is for the Python API only, never on
    a command line); ``default``: the value when none is given (``None``: off, or the
    terrain's default where :mod:`lodsprite.techniques.defaults` gives one: ``none`` says
    which, for the help); ``min``/``max``: the range (``above``: ``min`` itself excluded);
    ``choices``: the values allowed; ``unit``: e.g. ``"px"``, ``"ms"``, ``"MB"``;
    ``flag``: the command-line name without ``--`` (default: ``name`` with ``-`` for
    ``_``); ``command_line``: False keeps it off ``render``/``view`` (the Python API and
    scene files only); ``help``: one line.
    """

    name: str
    type: type
    default: Any = None
    help: str = ""
    min: float | None = None
    max: float | None = None
    above: bool = False
    choices: tuple[Any, ...] = ()
    unit: str = ""
    flag: str = ""
    none: str = ""
    command_line: bool = True

    @property
    def cli(self) -> str:
        """The command-line name, ``--flag``."""
        return "--" + (self.flag or self.name.replace("_", "-"))

    @property
    def on_command_line(self) -> bool:
        return self.command_line and self.type is not object

    def allowed(self) -> str:
        """What values are allowed, in words (``"> 0 px"``, ``"1..4"``, ``"lru | benefit"``)."""
        if self.choices:
            return " | ".join(str(c) for c in self.choices)
        unit = f" {self.unit}" if self.unit else ""
        if self.min is not None and self.max is not None and not self.above:
            return f"{self.min:g}..{self.max:g}{unit}"
        parts = []
        if self.min is not None:
            parts.append(f"{'>' if self.above else '>='} {self.min:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        text = " and ".join(parts) or {int: "a whole number", float: "a number",
                                       bool: "true | false"}.get(self.type, "text")
        return text + (unit if parts else "")

    def describe(self) -> str:
        """The help line with the default and what is allowed (``--help``, ``info``)."""
        default = self.none or ("none" if self.default is None else
                                f"{self.default:g}" if isinstance(self.default, float)
                                else str(self.default))
        return f"{self.help} [{self.allowed()}; default: {default}]"

    def declaration(self, default: Any = None) -> dict[str, Any]:
        """The declaration as JSON (the web page parses its query by it): name, type
        (``int``, ``float``, ``str``, ``bool``), default (``default`` where the option's
        is None), min, max, above, choices, unit, flag, allowed (in words), help."""
        return {"name": self.name, "type": self.type.__name__,
                "default": self.default if self.default is not None else default,
                "min": self.min, "max": self.max, "above": self.above,
                "choices": list(self.choices), "unit": self.unit, "flag": self.cli,
                "allowed": self.allowed(), "help": self.help}

    def _fail(self, value: Any) -> InputError:
        return InputError(f"option {self.cli}: got {value!r}, allowed: {self.allowed()}")

    def parse(self, text: str) -> Any:
        """A value from its text (a command line, a query string, a scene file); raises
        :class:`InputError` naming the option, the text and what is allowed."""
        if not isinstance(text, str):
            return self.check(text)
        raw = text.strip()
        if self.default is None and raw.lower() in ("", "none"):
            return None
        try:
            if self.type is bool:
                if raw.lower() not in (*_TRUE, *_FALSE):
                    raise ValueError(raw)
                value: Any = raw.lower() in _TRUE
            elif self.type is int:
                value = int(raw)
            elif self.type is float:
                value = float(raw)
            elif self.type is str:
                value = raw
            else:
                raise ValueError(raw)
        except ValueError:
            raise self._fail(text) from None
        return self.check(value)

    def check(self, value: Any) -> Any:
        """``value`` checked against the option's type, range and choices (an ``int``
        where a ``float`` is wanted is taken as one); returns it; raises
        :class:`InputError` otherwise.  ``None`` passes where the default is ``None``."""
        if value is None:
            if self.default is None:
                return None
            raise self._fail(value)
        if self.type is object:
            return value
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if self.type is int and isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, self.type) or (self.type is not bool
                                                and isinstance(value, bool)):
            raise self._fail(value)
        if self.choices and value not in self.choices:
            raise self._fail(value)
        if self.type in (int, float):
            if value != value:  # NaN
                raise self._fail(value)
            low = self.min is not None and (value <= self.min if self.above
                                            else value < self.min)
            if low or (self.max is not None and value > self.max):
                raise self._fail(value)
        return value


def merge(groups: Iterable[Iterable[Option]]) -> dict[str, Option]:
    """Options by name across ``groups`` (the first declaration of a name wins: a command
    line has one ``--OPTION`` for every technique that declares it)."""
    out: dict[str, Option] = {}
    for options in groups:
        for o in options:
            out.setdefault(o.name, o)
    return out


__all__ = ["Option", "merge"]
