"""A griffe extension for the API pages: the docstrings' reStructuredText roles
(``:func:`x```, ``:class:`~a.B```) and literal-block markers (``::``) read as Markdown."""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|attr|data|exc|obj|const|ref):`~?([^`]+)`")
LITERAL = re.compile(r"(?<=\S)::$", flags=re.MULTILINE)  # "A session::" -> "A session:"


def markdown(text: str) -> str:
    """``text`` with RST roles as code spans and ``::`` block markers as colons."""
    return LITERAL.sub(":", ROLE.sub(r"`\1`", text))


class RstRoles(griffe.Extension):
    """Rewrites every object's docstring once it is loaded."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = markdown(obj.docstring.value)
