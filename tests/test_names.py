"""Names that explain themselves: "renderer" is :class:`lodsprite.api.Renderer` alone, the
surface a technique draws on; the GL classes that draw one kind of thing are drawers."""

import ast
from pathlib import Path

import lodsprite

SRC = Path(lodsprite.__file__).resolve().parent


def _classes() -> dict[str, list[str]]:
    """Every class the package defines: name -> the modules (relative paths) defining it."""
    out: dict[str, list[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                out.setdefault(node.name, []).append(str(path.relative_to(SRC)))
    return out


def test_the_only_renderer_class_is_the_api_renderer():
    classes = _classes()
    renderers = {n: where for n, where in classes.items() if n.endswith("Renderer")}
    assert renderers == {"Renderer": ["api.py"]}

