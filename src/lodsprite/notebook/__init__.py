"""lodsprite in a notebook: :func:`widget` (anywidget; the ``notebook`` extra installs
what it needs).  :class:`~lodsprite.notebook.sprite.SpriteWidget` flies a terrain with
spriteframes drawn in the browser and keyframes from the kernel's renderer processes;
:class:`~lodsprite.notebook.stream.StreamWidget` streams every frame rendered in the
kernel (jupyter_rfb), for scenes the browser does not draw and for comparison."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["widget"]


def widget(source: str | Path = "jacksboro", **kwargs: Any):
    """A widget for ``source`` (a DEM file, a terrain store folder, a built-in terrain;
    see :class:`~lodsprite.notebook.sprite.SpriteWidget` for the keyword arguments),
    displayed as a cell's value.  Raises :class:`~lodsprite.errors.InputError` (one
    line) for a bad argument, and :class:`~lodsprite.errors.LodspriteError` naming the
    ``notebook`` extra when anywidget is not installed."""
    from lodsprite.errors import LodspriteError

    try:
        from lodsprite.notebook.sprite import SpriteWidget
    except ModuleNotFoundError as exc:
        if exc.name not in ("anywidget", "traitlets", "ipywidgets"):
            raise
        raise LodspriteError("lodsprite.widget needs the notebook extra: "
                             "pip install 'lodsprite[notebook]'") from None
    one_line_errors()
    return SpriteWidget(source, **kwargs)


def one_line_errors() -> None:
    """In IPython, show lodsprite's own errors (:class:`~lodsprite.errors.LodspriteError`)
    as one line, ``InputError: the reason``, not a traceback through the library."""
    try:
        from IPython import get_ipython
    except ModuleNotFoundError:
        return
    shell = get_ipython()
    if shell is None:
        return
    from lodsprite.errors import LodspriteError

    def handler(self, etype, value, tb, tb_offset=None):  # IPython's CustomTB signature
        return [f"{etype.__name__}: {value}"]

    shell.set_custom_exc((LodspriteError,), handler)
