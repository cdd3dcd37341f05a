"""The notebook widget's front end: the web page's own ES modules
(``lodsprite/distributed/web/static``: wire, decode, gl, camera, cursor, predictor,
depth_estimate, walkers, hud, app),
linked in the browser, not copied.

anywidget loads one ES module (``_esm``) from a string, where relative imports have no
base to resolve against.  :func:`widget_esm` therefore ships the static modules' sources
with the widget's loader (``loader.js``), which turns each into a ``blob:`` URL in
dependency order, its ``from './x.js'`` specifiers rewritten to the URLs of the modules
already made, then imports ``app.js`` and starts the client over the widget's messages.
The decode worker (``decode.js``) is started from its ``blob:`` URL.  The sources are read
once a process; a module of the page that imports one not in the folder, or a cycle of
imports, raises :class:`~lodsprite.errors.LodspriteError` (a packaging bug, not input).
"""

from __future__ import annotations

import functools
import json
import re
from pathlib import Path

from lodsprite.errors import LodspriteError

__all__ = ["MODULES", "import_order", "widget_css", "widget_esm"]

STATIC = Path(__file__).resolve().parents[1] / "distributed" / "web" / "static"
MODULES = ("app.js", "camera.js", "cursor.js", "decode.js", "depth_estimate.js", "gl.js", "hud.js",
           "predictor.js", "walkers.js", "wire.js")
"""The page's modules the widget runs (main.js, the page's WebSocket transport, is not)."""
_IMPORT = re.compile(r"""\bfrom\s+['"]\./([\w.-]+\.js)['"]""")


def imports(source: str) -> list[str]:
    """The sibling modules ``source`` imports (``from './x.js'``), in order."""
    return _IMPORT.findall(source)


def import_order(sources: dict[str, str]) -> list[str]:
    """The module names of ``sources`` with every module after those it imports;
    raises :class:`LodspriteError` for an import outside ``sources`` or a cycle."""
    order: list[str] = []
    state: dict[str, int] = {}  # 1: being visited, 2: placed

    def visit(name: str, trail: tuple[str, ...]) -> None:
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            raise LodspriteError(f"widget modules import in a cycle: {' -> '.join(trail)}")
        if name not in sources:
            raise LodspriteError(f"widget module {trail[-2]} imports {name}, not shipped")
        state[name] = 1
        for dep in imports(sources[name]):
            visit(dep, (*trail, dep))
        state[name] = 2
        order.append(name)

    for name in sorted(sources):
        visit(name, (name,))
    return order


@functools.cache
def widget_esm() -> str:
    """The anywidget ES module: ``loader.js`` with the page's module sources and their
    import order."""
    sources = {name: (STATIC / name).read_text(encoding="utf-8") for name in MODULES}
    loader = (Path(__file__).parent / "loader.js").read_text(encoding="utf-8")
    payload = json.dumps({"sources": sources, "order": import_order(sources)})
    return loader.replace("/*__MODULES__*/null", payload, 1)


@functools.cache
def widget_css() -> str:
    """The widget's style sheet (``widget.css``)."""
    return (Path(__file__).parent / "widget.css").read_text(encoding="utf-8")
