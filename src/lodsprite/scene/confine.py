"""Files a scene names, confined to a root folder: what a server checks before it opens a
scene a client named (``lodsprite serve --data DIR``, the page, the widget).

Under a root every reference (a scene file's terrain, texture, meshes, points, light
fields, path file; a glTF's buffers and images) must be a relative path that resolves,
symlinks followed, to a place inside the root.  Refused, in one line each: a URL (any
``scheme://``), an absolute path, a ``~`` path, a name that does not exist, one that
resolves outside the root, a folder (a store, a light field) holding any symlink, a glTF
URI that is neither ``data:`` nor a plain relative path (a ``%`` escape or a backslash is
refused rather than decoded: what the check resolves is what the loader opens).
"""

from __future__ import annotations

import json
import os
import re
import struct
from pathlib import Path, PurePosixPath

from lodsprite.errors import InputError

_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*://|data:)")
#: glTF's binary container: magic, version, length; then chunks (length, type).
_GLB_MAGIC, _GLB_JSON = b"glTF", 0x4E4F534A
MAX_GLTF_JSON_BYTES = 16 * 2**20


def is_url(value: str) -> bool:
    """``value`` names a URL (``http://...``, ``file://...``, ``s3://...``, ``data:...``)
    rather than a path or a built-in (``fractal:64``, ``crowd:10``)."""
    return bool(_URL.match(value))


def confined(value: str, folder: Path, root: Path, what: str) -> Path:
    """``value`` (relative to ``folder``) resolved through symlinks, inside ``root`` (both
    resolved folders); else an :class:`InputError` ``"WHAT VALUE: why"``."""
    if not isinstance(value, str) or not value.strip() or "\x00" in value:
        raise InputError(f"{what}: a name must be a non-empty string")
    if is_url(value):
        raise InputError(f"{what} {value!r}: a URL is refused; name a file in the data folder")
    if value.startswith("~") or PurePosixPath(value).is_absolute() or Path(value).is_absolute():
        raise InputError(f"{what} {value!r}: absolute paths are refused; name a file "
                         "relative to the data folder")
    try:
        path = (folder / value).resolve(strict=True)
    except (OSError, RuntimeError, ValueError):
        raise InputError(f"{what} {value!r}: no such file in the data folder") from None
    if not path.is_relative_to(root):
        raise InputError(f"{what} {value!r} leads outside the data folder")
    return path


def check_tree(path: Path, what: str) -> None:
    """Refuse a folder (a store, a light field) holding a symlink: it could lead reads
    outside the data folder."""
    if not path.is_dir():
        return
    for top, dirs, files in os.walk(path):
        for entry in (*dirs, *files):
            if os.path.islink(os.path.join(top, entry)):
                raise InputError(f"{what} {path.name!r}: a folder holding symlinks is refused")


def gltf_uris(path: Path) -> list[str]:
    """The ``uri`` of every buffer and image of the glTF (``.gltf`` JSON or ``.glb``) at
    ``path``; an :class:`InputError` when its JSON cannot be read."""
    try:
        with open(path, "rb") as f:
            if path.suffix.lower() == ".glb":
                magic, _, _ = struct.unpack("<4sII", f.read(12))
                size, kind = struct.unpack("<II", f.read(8))
                if magic != _GLB_MAGIC or kind != _GLB_JSON or size > MAX_GLTF_JSON_BYTES:
                    raise InputError(f"{path.name}: not a glTF binary with a JSON chunk")
                text = f.read(size)
            else:
                text = f.read(MAX_GLTF_JSON_BYTES + 1)
                if len(text) > MAX_GLTF_JSON_BYTES:
                    raise InputError(f"{path.name}: glTF JSON over {MAX_GLTF_JSON_BYTES} bytes")
        doc = json.loads(text)
    except (OSError, struct.error, ValueError, RecursionError) as exc:
        raise InputError(f"{path.name}: unreadable glTF ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path.name}: a glTF's JSON is an object")
    uris = []
    for key in ("buffers", "images"):
        items = doc.get(key, [])
        if not isinstance(items, list):
            raise InputError(f"{path.name}: {key} is not a list")
        for item in items:
            uri = item.get("uri") if isinstance(item, dict) else None
            if uri is not None:
                if not isinstance(uri, str):
                    raise InputError(f"{path.name}: a {key[:-1]}'s uri is not a string")
                uris.append(uri)
    return uris


def check_gltf(path: Path, root: Path, what: str) -> None:
    """Every external file the glTF at ``path`` refers to lies inside ``root``: each URI is
    ``data:...`` or a plain relative path (no ``%`` escape, no backslash) resolving there."""
    for uri in gltf_uris(path):
        if uri.startswith("data:"):
            continue
        if "%" in uri or "\\" in uri:
            raise InputError(f"{what}: {path.name} refers to {uri!r}: escaped or backslashed "
                             "URIs are refused")
        confined(uri, path.parent, root, f"{what}: {path.name} refers to")
