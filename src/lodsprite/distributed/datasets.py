"""What a LOD server serves: built-in datasets, and files under one data folder.

A client names its terrain and texture; the server never takes a path from it.  A name
is either a built-in:

* terrains ``jacksboro`` and ``fractal[:SIZE[:SEED]]`` with SIZE a power of two in
  ``16 .. MAX_FRACTAL_SIZE``;
* textures ``terrain`` and ``checker[:K]`` (K in 1..1024);

or a file relative to the server's data folder (``lodsprite serve --data DIR``), or for
terrains a terrain store there (a ``lodsprite tile`` folder, read at its finest level of
at most 4096 a side, as every ``--terrain`` is).  A name that is absolute, holds a ``..``
component, or resolves (through symlinks) to a place outside DIR is refused; so is a store
holding any symlink, and every file name when the server has no data folder.
The client loads the same name itself (its coarse model and fallback texture), as in
Swan et al. 2002 where both hosts hold the dataset.

A scene (:meth:`Datasets.scene`) is any of those terrains, ``crowd[:OBJECTS[:TREES]]``
(at most :data:`MAX_SESSION_OBJECTS` in all), or a scene file, a light-field folder or a
plug-in kind's folder under the data folder.  A scene file and every file it names must
lie inside the data folder, symlinks followed (:mod:`lodsprite.scene.confine`); its
instances, light fields and built-in terrain are held to a session's caps.  A kind is
served only when it is among the server's ``kinds`` (the project's own by default:
:data:`SERVED_KINDS`); a plug-in's must be listed.  A URL is never a name.

The data folder may be an ``http(s)://`` URL (``serve --data URL``): names under it are
terrain stores (``*.zarr``) and COGs, relative paths of plain characters, read through
the HTTP block cache (:mod:`lodsprite.terrain.remote`); nothing else is served from it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from lodsprite.errors import InputError, LodspriteError, TerrainError
from lodsprite.terrain.loaders import parse_fractal_spec
from lodsprite.terrain.store import is_store
from lodsprite.terrain.textures import CHECKER_SIZE

MAX_FRACTAL_SIZE = 4096
"""Largest ``fractal:SIZE`` a server generates (quads per side)."""
MAX_SOURCE_SIDE = 16384
"""Largest side (samples or texels) of a terrain or texture file a server reads."""
JACKSBORO_SHAPE = (344, 403)
MAX_SESSION_OBJECTS = 20_000
"""Most objects (a crowd's members and trees, a scene file's instances) a session loads."""
MAX_SESSION_LIGHTFIELDS = 4
"""Most light fields a session's scene holds."""
SERVED_KINDS = ("scene-file", "crowd", "lumigraph")
"""The scene kinds a server serves unless told otherwise: the project's own."""


@dataclass(frozen=True)
class Dataset:
    """A resolved name: ``spec`` for the loaders (a built-in spec or an absolute path
    inside the data folder) and ``shape`` (rows, cols) of the source when known cheaply
    (for the memory estimate; None when the file could not be peeked at)."""

    spec: str
    shape: tuple[int, int] | None
    builtin: bool


@dataclass(frozen=True)
class SceneName:
    """A resolved scene name: ``spec`` for :func:`lodsprite.scene.open_scene` (a built-in
    or an absolute path inside the data folder), its ``kind`` (None: a terrain, whose
    :class:`Dataset` is ``terrain``) and ``root``, the folder every file it names lies in
    (pass it to ``open_scene``)."""

    spec: str
    kind: str | None
    root: Path | None
    terrain: Dataset | None = None


class Datasets:
    """The names a server serves: built-ins, and files under ``data_dir`` (None: none);
    of the scene kinds, those in ``kinds``."""

    def __init__(self, data_dir: Path | str | None = None,
                 kinds: tuple[str, ...] = SERVED_KINDS) -> None:
        from lodsprite.terrain.remote import is_url

        self.kinds = tuple(kinds)
        self.data_dir: Path | None = None
        self.remote: str | None = None  # a data folder at an http(s):// URL
        if data_dir is not None and is_url(str(data_dir)):
            self.remote = str(data_dir).strip().rstrip("/")
        elif data_dir is not None:
            root = Path(data_dir).expanduser()
            if not root.is_dir():
                raise InputError(f"data folder not found: {data_dir}")
            self.data_dir = root.resolve()

    def terrain(self, name: str) -> Dataset:
        """The terrain named ``name``; raises :class:`InputError` with the reason."""
        name = _clean(name, "terrain")
        if name.lower() == "jacksboro":
            return Dataset("jacksboro", JACKSBORO_SHAPE, True)
        parsed = parse_fractal_spec(name)  # raises TerrainError when malformed
        if parsed is not None:
            size, _ = parsed
            if not (16 <= size <= MAX_FRACTAL_SIZE and size & (size - 1) == 0):
                raise InputError(f"fractal size {size} is not a power of two in "
                                 f"16..{MAX_FRACTAL_SIZE}")
            return Dataset(name, (size + 1, size + 1), True)
        if self.remote is not None:
            return self._remote_terrain(name)
        path, shape = self._file(name, "terrain", stores=True)
        return Dataset(str(path), shape, False)

    def local_name(self, name: str) -> str:
        """A resolved spec as the name it was resolved from: a path inside the data
        folder, or a URL under the remote one, relative to it; any other as it is."""
        root = self.data_dir
        if root is not None and os.path.isabs(name) and Path(name).is_relative_to(root):
            return Path(name).relative_to(root).as_posix()
        if self.remote is not None and name.startswith(self.remote + "/"):
            return name[len(self.remote) + 1:]
        return name

    def _remote_terrain(self, name: str) -> Dataset:
        """A terrain store (``*.zarr``) or COG under the remote data folder: its URL, its
        header read through the block cache (:mod:`lodsprite.terrain.remote`)."""
        import re

        from lodsprite.terrain.loaders import STORE_MAX_SIDE
        from lodsprite.terrain.remote import open_raster
        from lodsprite.terrain.store import TerrainStore

        rel = PurePosixPath(name)
        if (rel.is_absolute() or ".." in rel.parts
                or not re.fullmatch(r"[A-Za-z0-9._\-/]{1,200}", name)):
            raise InputError(f"terrain {name!r}: a name under the remote data folder is a "
                             "relative path of letters, digits, '.', '_', '-' and '/'")
        url = f"{self.remote}/{rel.as_posix()}"
        if is_store(url):
            st = TerrainStore(url)
            return Dataset(url, st.shape(st.level_for(STORE_MAX_SIDE)), False)
        if rel.suffix.lower() in (".tif", ".tiff"):
            with open_raster(url) as ds:
                shape = int(ds.height), int(ds.width)
            return Dataset(url, shape, False)
        raise InputError(f"terrain {name!r}: the remote data folder serves terrain stores "
                         "(*.zarr) and COGs (*.tif)")

    def scene(self, name: str) -> SceneName:
        """The scene named ``name``: a terrain (:meth:`terrain`), a crowd, or a scene file,
        light field or plug-in kind's folder under the data folder, checked against the
        session's caps; raises :class:`InputError` with the reason, before anything of it
        is opened beyond its header."""
        from lodsprite.scene.confine import check_tree, is_url
        from lodsprite.scene.kinds import scene_kind

        name = _clean(name, "scene")
        if is_url(name):
            raise InputError(f"scene {name!r}: a URL is refused; name a scene this server "
                             "serves")
        low = name.lower()
        if low == "crowd" or low.startswith("crowd:"):
            self._served("crowd", name)
            from lodsprite.manager.technique import parse_crowd

            objects, trees = parse_crowd(low)
            if not (1 <= objects and 0 <= trees and objects + trees <= MAX_SESSION_OBJECTS):
                raise InputError(f"scene {name!r}: a crowd of 1..{MAX_SESSION_OBJECTS} "
                                 "objects (members and trees) in all")
            return SceneName(low, "crowd", None)
        if low == "jacksboro" or parse_fractal_spec(name) is not None:
            return SceneName(name, None, None, self.terrain(name))
        if self.remote is not None:  # a remote data folder serves terrains only
            terrain = self._remote_terrain(name)
            return SceneName(terrain.spec, None, None, terrain)
        path, shape = self._file(name, "scene", stores=True, folders=True)
        kind = scene_kind(str(path))  # on a path inside the data folder only
        if kind is None:  # a terrain: a store or a file, checked once by _file
            if path.is_dir() and not is_store(path):
                raise InputError(f"terrain {name!r} is not a file")
            return SceneName(str(path), None, self.data_dir, Dataset(str(path), shape, False))
        self._served(kind, name)
        terrain = None
        if kind == "scene-file":
            terrain = self._check_scene_file(path, name)
        else:
            check_tree(path, f"scene {name!r}")
        return SceneName(str(path), kind, self.data_dir, terrain)

    def _served(self, kind: str, name: str) -> None:
        if kind not in self.kinds:
            raise InputError(f"scene {name!r}: this server does not serve {kind} scenes "
                             f"(it serves {', '.join(self.kinds) or 'terrains only'})")

    def _check_scene_file(self, path: Path, name: str) -> Dataset:
        """The scene file read confined to the data folder, and held to the session's
        caps (objects, light fields, its terrain's size); its terrain (a built-in, or a
        file or store under the data folder, checked by :meth:`terrain`'s rule)."""
        from lodsprite.scene.file import read_scene_file
        from lodsprite.techniques.scenes import check_options

        try:
            sf = read_scene_file(path, root=self.data_dir)
            check_options(str(path), sf.terrain.mode, sf.terrain.options)  # as opening will
        except LodspriteError as exc:  # named as the page named it: no server path shown
            raise InputError(self.local_message(str(exc), path, name)) from None
        objects = 0
        for o in sf.objects:  # a points file's lines bound its rows
            if o.count is not None:
                objects += o.count
            elif o.points is not None:
                objects += Path(o.points).read_bytes().count(b"\n") + 1
            if objects > MAX_SESSION_OBJECTS:
                break
        if objects > MAX_SESSION_OBJECTS:
            raise InputError(f"scene {name!r}: {objects} objects, more than a session's "
                             f"{MAX_SESSION_OBJECTS}")
        if len(sf.lightfields) > MAX_SESSION_LIGHTFIELDS:
            raise InputError(f"scene {name!r}: {len(sf.lightfields)} light fields, more "
                             f"than a session's {MAX_SESSION_LIGHTFIELDS}")
        source = sf.terrain.source
        if not Path(source).is_absolute():  # a built-in: the terrain rules apply
            return self.terrain(source)
        try:  # a file under the data folder (read_scene_file resolved it there)
            return self.terrain(Path(source).relative_to(self.data_dir).as_posix())
        except (InputError, ValueError) as exc:
            raise InputError(self.local_message(f"scene {name!r}: {exc}", path, name)
                             ) from None

    def local_message(self, message: str, path: Path | None = None, name: str = "") -> str:
        """``message`` with the server's paths put as a page names them: ``path`` (when
        given) as ``name``, the data folder's other files relative to it, the folder
        itself as "the data folder"."""
        if path is not None:
            message = message.replace(str(path), name)
        if self.data_dir is not None:
            message = message.replace(f"{self.data_dir}{os.sep}", "").replace(
                str(self.data_dir), "the data folder")
        return message

    def texture(self, name: str) -> Dataset:
        """The texture named ``name``; raises :class:`InputError` with the reason."""
        name = _clean(name, "texture")
        low = name.lower()
        if low in ("terrain", "imagery", "imagery+hillshade"):  # a store's own imagery, too
            return Dataset(low, None, True)  # the working grid's size (or the imagery's)
        if low == "checker" or low.startswith("checker:"):
            _, _, k = low.partition(":")
            if k and not (k.isdigit() and 1 <= int(k) <= CHECKER_SIZE):
                raise InputError(f"checker squares must be an integer in 1..{CHECKER_SIZE}, "
                                 f"got {k!r}")
            return Dataset(name, (CHECKER_SIZE, CHECKER_SIZE), True)
        path, shape = self._file(name, "texture")
        return Dataset(str(path), shape, False)

    def _file(self, name: str, what: str, stores: bool = False,
              folders: bool = False) -> tuple[Path, tuple[int, int] | None]:
        """The file (or store, or with ``folders`` any folder) ``name`` names inside the
        data folder, checked, and its shape (:func:`_peek_shape`; None for a folder)."""
        if self.data_dir is None:
            how = (" from its remote data folder but terrains" if self.remote else
                   " (start it with --data DIR)")
            raise InputError(f"{what} {name!r} is not a built-in, and this server serves no "
                             f"files{how}")
        rel = PurePosixPath(name)
        if rel.is_absolute() or name.startswith("~"):
            raise InputError(f"{what} {name!r}: absolute paths are refused; name a file "
                             "relative to the data folder")
        if ".." in rel.parts:
            raise InputError(f"{what} {name!r}: '..' is refused")
        try:
            path = (self.data_dir / rel).resolve(strict=True)
        except (OSError, RuntimeError, ValueError):
            raise InputError(f"{what} {name!r}: no such file in the data folder") from None
        if not path.is_relative_to(self.data_dir):
            raise InputError(f"{what} {name!r} leads outside the data folder")
        if stores and is_store(path):
            _check_store(path, name)
        elif folders and path.is_dir():
            return path, None
        elif not path.is_file():
            raise InputError(f"{what} {name!r} is not a file")
        shape = _peek_shape(path)
        if shape is not None and max(shape) > MAX_SOURCE_SIDE:
            raise InputError(f"{what} {name!r} is {shape[1]}x{shape[0]}: more than "
                             f"{MAX_SOURCE_SIDE} a side")
        return path, shape


def _clean(name: str, what: str) -> str:
    if not isinstance(name, str) or not name.strip() or "\x00" in name:
        raise InputError(f"{what} name must be a non-empty string")
    return name.strip()


def _check_store(path: Path, name: str) -> None:
    """Refuse a store holding a symlink (it could lead reads outside the data folder) or
    one that does not open as a complete terrain store."""
    import os

    from lodsprite.terrain.store import TerrainStore

    for root, dirs, files in os.walk(path):
        for entry in (*dirs, *files):
            if os.path.islink(os.path.join(root, entry)):
                raise InputError(f"terrain {name!r}: a store holding symlinks is refused")
    TerrainStore(path)  # raises InputError naming what is wrong


def _peek_shape(path: Path) -> tuple[int, int] | None:
    """(rows, cols) of an image, GeoTIFF or .npy file without reading its data, or of the
    level a terrain store is loaded at; None when the file cannot be read this way (the
    loader then reports what is wrong)."""
    suffix = path.suffix.lower()
    try:
        if path.is_dir():
            from lodsprite.terrain.loaders import STORE_MAX_SIDE
            from lodsprite.terrain.store import TerrainStore

            st = TerrainStore(path)
            return st.shape(st.level_for(STORE_MAX_SIDE))
        if suffix == ".npy":
            a = np.load(path, mmap_mode="r", allow_pickle=False)
            return (int(a.shape[0]), int(a.shape[1])) if a.ndim == 2 else None
        if suffix in (".tif", ".tiff"):
            import rasterio

            with rasterio.open(path) as ds:
                return int(ds.height), int(ds.width)
        from PIL import Image

        with Image.open(path) as img:
            return int(img.size[1]), int(img.size[0])
    except (TerrainError, InputError):
        raise
    except Exception:  # any reader's error: the loader names it properly later
        return None
