"""What a notebook widget shows: a terrain, a scene file or a crowd named as the web
server names one, resolved in the kernel before anything starts.

The user's own Python names it (a file, a store folder or a scene file, or a built-in); the
widget serves that one name from the file's folder, by the web server's rules
(:class:`~lodsprite.distributed.datasets.Datasets`: no path outside the folder, stores
without symlinks, size caps), and a ``load`` from the browser that names anything else is
refused.  Every argument is checked here, as the server will check it
(:class:`~lodsprite.distributed.protocol.LoadArgs`), so a bad one is one
:class:`~lodsprite.errors.InputError` in the cell, not a failure in the browser later.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from pathlib import Path

import msgspec

from lodsprite.distributed.datasets import Datasets
from lodsprite.distributed.protocol import MAX_IMAGE_SIDE, LoadArgs, PathArgs
from lodsprite.distributed.served import OBJECT_KINDS
from lodsprite.errors import InputError, LodspriteError

__all__ = ["MIN_SIDE", "WidgetSource", "check_path", "path_played", "resolve_source"]

MIN_SIDE = 16
"""Smallest canvas side (pixels) a widget draws, as the renderer's."""


@dataclass(frozen=True)
class WidgetSource:
    """A resolved widget terrain: the ``load`` a view sends (names as the server takes
    them) and the folder they are served from (None: built-ins only)."""

    load: LoadArgs
    data_dir: Path | str | None  # a str: an http(s):// folder of terrain stores and COGs


def _name_in(value: str | Path, kind: str, folder: Path | None) -> tuple[str, Path | None]:
    """``value`` as a name the server resolves, and the folder it is in (None: a
    built-in; a URL's folder for a terrain at an ``http(s)://`` URL); a file outside
    ``folder`` (when given) is refused."""
    text = str(value)
    probe = Datasets(None)
    try:  # a built-in name (jacksboro, fractal:N[:S], crowd:N, terrain, checker[:K])
        (probe.scene if kind == "terrain" else probe.texture)(text)
        return text, None
    except InputError as exc:
        builtin_error = exc
    from lodsprite.terrain.remote import is_url

    if is_url(text) and kind == "terrain":  # read in place: the URL's folder served
        if "?" in text or "#" in text:
            raise InputError(f"terrain {text}: a widget's URL takes no query string or "
                             "fragment")
        base, _, name = text.strip().rstrip("/").rpartition("/")
        return name, base  # type: ignore[return-value]
    path = Path(text).expanduser()
    if not path.exists():
        if "/" in text or Path(text).suffix:
            raise InputError(f"{kind} not found: {text}")
        raise builtin_error
    path = path.resolve()
    if folder is not None and path.parent != folder:
        raise InputError(f"{kind} {text}: a widget serves files from one folder, "
                         f"{folder}")
    return path.name, path.parent


def resolve_source(terrain: str | Path, texture: str | Path = "terrain",
                   **load: object) -> WidgetSource:
    """The :class:`WidgetSource` for ``terrain`` and ``texture`` (each a built-in name
    or a file; files in one folder) and the other ``load`` fields (``size``, ``lod``,
    ``epsilon``, ``visibility``, ``grid``, ``fov_y_deg``, ``exaggeration``); raises
    :class:`InputError` with one line naming the bad value."""
    t_name, folder = _name_in(terrain, "terrain", None)
    x_name, x_folder = _name_in(texture, "texture", folder)
    folder = folder or x_folder
    fields = {k: v for k, v in load.items() if v is not None}
    if "size" in fields:
        size = fields["size"] = list(fields["size"])  # type: ignore[call-overload]
        if len(size) != 2 or not all(isinstance(v, int) and MIN_SIDE <= v <= MAX_IMAGE_SIDE
                                     for v in size):
            raise InputError(f"widget: size {tuple(size)}: (width, height), each "
                             f"{MIN_SIDE}..{MAX_IMAGE_SIDE} pixels")
    try:
        args = msgspec.convert({"terrain": t_name, "texture": x_name, **fields}, LoadArgs)
    except (msgspec.ValidationError, ValueError) as exc:
        raise InputError(f"widget: {str(exc).splitlines()[0]}") from None
    datasets = Datasets(folder)
    named = datasets.scene(args.terrain)  # the server's checks, here first
    if named.kind is not None and named.kind not in OBJECT_KINDS:
        raise InputError(f"widget: {terrain} is a {named.kind} scene: the sprite widget "
                         "draws terrains, scene files and crowds (stream=True shows any "
                         "scene)")
    datasets.texture(args.texture)
    return WidgetSource(args, folder)


def check_path(spec: str, frames: int | None) -> PathArgs:
    """``spec`` and ``frames`` as the ``path`` op takes them (a built-in path: chen1999,
    swan2002, flyover[:...], patrol[:...], bank[:...], a crowd's walk); raises
    :class:`InputError`."""
    try:
        return msgspec.convert({"spec": spec, "frames": frames}, PathArgs)
    except msgspec.ValidationError as exc:
        raise InputError(f"path {spec!r}, frames {frames}: {exc}") from None


async def path_played(future: asyncio.Future | None, timeout: float) -> int:
    """The result of a widget's ``played`` ``future`` (frames drawn); raises
    :class:`LodspriteError` without one (no path started) or after ``timeout`` s."""
    if future is None:
        raise LodspriteError("no path is playing: call play() first")
    try:
        return await asyncio.wait_for(asyncio.shield(future), timeout)
    except TimeoutError:
        raise LodspriteError(f"the path did not finish within {timeout:g} s") from None
