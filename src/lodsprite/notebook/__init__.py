"""lodsprite in a notebook: :func:`widget` (anywidget; the ``notebook`` extra installs
what it needs).  :class:`~lodsprite.notebook.sprite.SpriteWidget` flies a terrain, a
scene file or a crowd with spriteframes drawn in the browser and keyframes from the
kernel's renderer processes;
:class:`~lodsprite.notebook.stream.StreamWidget` streams every frame rendered in the
kernel (jupyter_rfb), for scenes the browser does not draw and for comparison."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["widget"]


def widget(source: str | Path = "jacksboro", *, stream: bool = False, **kwargs: Any):
    """A widget for ``source``, displayed as a cell's value.

    A terrain (a DEM file, a terrain store folder, a built-in such as ``jacksboro`` or
    ``fractal:N``), a scene file or a crowd (``crowd:N``) gives a
    :class:`~lodsprite.notebook.sprite.SpriteWidget`: spriteframes drawn in the browser,
    keyframes from the kernel's renderer processes (a scene file's standing layers and
    light fields, a crowd's ground and trees; its walkers and a crowd's members drawn in
    the browser each frame; see it for the keyword arguments).  A scene the browser does
    not draw (a light field alone, a plug-in's kind), or any scene with ``stream=True``,
    gives a
    :class:`~lodsprite.notebook.stream.StreamWidget`: every frame rendered in the kernel
    (the fallback, and the comparison).
    Raises :class:`~lodsprite.errors.InputError` (one line) for a bad argument, and
    :class:`~lodsprite.errors.LodspriteError` naming the ``notebook`` extra when its
    packages are not installed."""
    from lodsprite.errors import LodspriteError

    try:
        from lodsprite.notebook.sprite import SpriteWidget
        from lodsprite.notebook.stream import StreamWidget
    except ModuleNotFoundError as exc:
        if exc.name not in ("anywidget", "traitlets", "ipywidgets", "jupyter_rfb"):
            raise
        raise LodspriteError("lodsprite.widget needs the notebook extra: "
                             "pip install 'lodsprite[notebook]'") from None
    one_line_errors()
    if stream or _scene_kind(str(source)):
        return StreamWidget(source, **kwargs)
    return SpriteWidget(source, **kwargs)


def _scene_kind(spec: str) -> bool:
    """Whether a scene kind the browser does not draw (a light field, a plug-in's)
    claims ``spec`` (a terrain, a scene file or a crowd: False)."""
    from lodsprite.distributed.served import OBJECT_KINDS
    from lodsprite.scene.kinds import scene_kind

    kind = scene_kind(spec)
    return kind is not None and kind not in OBJECT_KINDS


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
        stb = [f"{etype.__name__}: {value}"]
        self._showtraceback(etype, value, stb)  # the kernel's error message, one line
        return stb

    shell.set_custom_exc((LodspriteError,), handler)
