"""A lumigraph on disk: a JSON header, one compressed image file per node, and the
approximate geometry; nodes load lazily and independently.

Layout of a lumigraph folder::

    lumigraph.json          the header (:class:`Header`): format, version, codec, slabs
    proxy.npz               the approximate geometry: vertices, faces, colors, normals
    slab0/s000_t000.jpg     node (i=0, j=0) of slab 0: its uv image, row 0 at v max
    ...

The header is validated as a typed schema (msgspec) with size caps before anything is
allocated, and node files are read only from inside the folder.  A node file that is
missing or cannot be decoded makes that node one without data (a fictitious node in the
paper's terms): it is reported in :attr:`Lumigraph.bad_nodes`, never an exception.
"""

from __future__ import annotations

import io
import json
import logging
import os
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np
from PIL import Image

from lodsprite.errors import InputError
from lodsprite.files import atomic_write_bytes
from lodsprite.lumigraph.capture import ColorMesh
from lodsprite.lumigraph.geometry import Slab

log = logging.getLogger(__name__)

FORMAT = "lodsprite-lumigraph"
VERSION = 1
HEADER_FILE = "lumigraph.json"
PROXY_FILE = "proxy.npz"
MAX_HEADER_BYTES = 1 << 20
MAX_NODE_BYTES = 64 << 20
MAX_PROXY_BYTES = 512 << 20
CODECS = {"jpeg": "jpg", "png": "png"}


class SlabHeader(msgspec.Struct, forbid_unknown_fields=True):
    """One slab: ``frame`` local-to-world (4 rows of 4), sizes and distance (metres), node
    grid and uv image size."""

    frame: list[list[float]]
    st_size: float
    uv_size: float
    st_distance: float
    n_st: int
    n_uv: int

    def slab(self) -> Slab:
        return Slab(np.asarray(self.frame, dtype=np.float64), self.st_size, self.uv_size,
                    self.st_distance, self.n_st, self.n_uv)


class Header(msgspec.Struct, forbid_unknown_fields=True):
    """The lumigraph's header (``lumigraph.json``)."""

    format: str
    version: int
    codec: Literal["jpeg", "png"]
    quality: int
    object: str
    near: float
    far: float
    slabs: list[SlabHeader]
    capture_s: float = 0.0


def slab_header(slab: Slab) -> SlabHeader:
    return SlabHeader([[float(v) for v in row] for row in slab.frame], float(slab.st_size),
                      float(slab.uv_size), float(slab.st_distance), int(slab.n_st),
                      int(slab.n_uv))


def node_name(slab_index: int, i: int, j: int, codec: str) -> str:
    return f"slab{slab_index}/s{i:03d}_t{j:03d}.{CODECS[codec]}"


def encode_node(image: np.ndarray, codec: str, quality: int) -> bytes:
    """One uv image, ``(n, n, 3) uint8`` row 0 at the top, as JPEG or PNG bytes."""
    buf = io.BytesIO()
    im = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB")
    if codec == "jpeg":
        im.save(buf, "JPEG", quality=int(quality), subsampling=0)
    else:
        im.save(buf, "PNG", compress_level=6)
    return buf.getvalue()


def save(out_dir: str | os.PathLike, slabs: list[Slab],
         images: list[dict[tuple[int, int], np.ndarray]], proxy: ColorMesh, object_name: str,
         near: float, far: float, codec: str = "jpeg", quality: int = 90,
         capture_s: float = 0.0) -> Path:
    """Write a lumigraph folder (nodes first, header last: a folder with a header is
    complete).  ``images[k]`` are slab ``k``'s node images by ``(i, j)``."""
    if codec not in CODECS:
        raise InputError(f"unknown codec {codec!r}: use {' or '.join(CODECS)}")
    if not 1 <= int(quality) <= 100:
        raise InputError(f"JPEG quality must be 1..100, got {quality}")
    out = Path(out_dir)
    for k, nodes in enumerate(images):
        for (i, j), image in nodes.items():
            atomic_write_bytes(out / node_name(k, i, j, codec), encode_node(image, codec,
                                                                           quality))
    buf = io.BytesIO()
    np.savez_compressed(buf, vertices=proxy.vertices.astype(np.float32),
                        faces=proxy.faces.astype(np.int32),
                        colors=proxy.colors.astype(np.float32),
                        normals=proxy.normals.astype(np.float32))
    atomic_write_bytes(out / PROXY_FILE, buf.getvalue())
    header = Header(FORMAT, VERSION, codec, int(quality), object_name, float(near), float(far),
                    [slab_header(s) for s in slabs], float(capture_s))
    atomic_write_bytes(out / HEADER_FILE, json.dumps(msgspec.to_builtins(header),
                                                     indent=2).encode())
    return out


class Lumigraph:
    """A lumigraph folder opened for reading: header validated, nodes loaded on demand."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.header = read_header(self.folder)
        self.slabs = [s.slab() for s in self.header.slabs]
        self.bad_nodes: dict[tuple[int, int, int], str] = {}

    def node(self, slab: int, i: int, j: int, level: int = 0) -> np.ndarray | None:
        """Node ``(i, j)`` of ``slab``'s uv image, ``(m, m, 3) uint8`` with ``m = n_uv >>
        level`` (level ``k`` of the uv mipmap), or None when its file is missing or corrupt
        (recorded in :attr:`bad_nodes`)."""
        data = self.node_bytes(slab, i, j)
        return None if data is None else self.decode(data, slab, i, j, level)

    def node_path(self, slab: int, i: int, j: int) -> Path:
        s = self.slabs[slab]
        if not (0 <= i < s.n_st and 0 <= j < s.n_st):
            raise InputError(f"node ({i}, {j}) is outside slab {slab}'s {s.n_st}² grid")
        return self.folder / node_name(slab, i, j, self.header.codec)

    def node_bytes(self, slab: int, i: int, j: int) -> bytes | None:
        """The compressed file of a node (the fetch of §4.2), or None (see :meth:`node`)."""
        path = self.node_path(slab, i, j)
        try:
            if path.is_symlink() or path.stat().st_size > MAX_NODE_BYTES:
                raise OSError("not a plain node file of a sane size")
            return path.read_bytes()
        except OSError as exc:
            self.mark_bad(slab, i, j, exc)
            return None

    def decode(self, data: bytes, slab: int, i: int, j: int, level: int = 0
               ) -> np.ndarray | None:
        """Decode a node file (the decompression of §4.2) at uv level ``level``: JPEG
        decodes straight at 1/2, 1/4 or 1/8 scale (DCT scaling), PNG is box-reduced."""
        s = self.slabs[slab]
        m = max(1, s.n_uv >> int(level))
        try:
            with Image.open(io.BytesIO(data)) as im:
                if im.size != (s.n_uv, s.n_uv):
                    raise OSError(f"{im.size[0]}x{im.size[1]}, not {s.n_uv}²")
                if level and im.format == "JPEG":
                    im.draft("RGB", (m, m))
                im = im.convert("RGB")
                if im.size != (m, m):
                    im = im.reduce(max(1, im.size[0] // m)).resize((m, m))
                return np.asarray(im)
        except (OSError, ValueError, Image.DecompressionBombError) as exc:
            self.mark_bad(slab, i, j, exc)
            return None

    def mark_bad(self, slab: int, i: int, j: int, exc: BaseException | str) -> None:
        """Record node (slab, i, j) as unusable (said once, kept in :attr:`bad_nodes`)."""
        reason = " ".join(str(exc).split()) or type(exc).__name__
        if (slab, i, j) not in self.bad_nodes:
            log.warning("lumigraph node %s is unusable (%s): drawn without data",
                        node_name(slab, i, j, self.header.codec), reason)
        self.bad_nodes[(slab, i, j)] = reason

    def nodes(self, slab: int = 0, which=None) -> dict[tuple[int, int], np.ndarray]:
        """The usable node images of ``slab`` (all, or the ``(i, j)`` in ``which``)."""
        s = self.slabs[slab]
        keys = which if which is not None else [(i, j) for i in range(s.n_st)
                                                for j in range(s.n_st)]
        out = {}
        for i, j in keys:
            img = self.node(slab, i, j)
            if img is not None:
                out[(i, j)] = img
        return out

    def proxy(self) -> ColorMesh:
        """The approximate geometry."""
        path = self.folder / PROXY_FILE
        try:
            if path.stat().st_size > MAX_PROXY_BYTES:
                raise InputError(f"{path}: larger than {MAX_PROXY_BYTES >> 20} MB")
            with np.load(path, allow_pickle=False) as z:
                mesh = ColorMesh(z["vertices"].astype(np.float64), z["faces"].astype(np.int32),
                                 z["colors"].astype(np.float64),
                                 z["normals"].astype(np.float64))
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"cannot read the lumigraph's geometry {path}: {exc}") from exc
        nv = len(mesh.vertices)
        if (mesh.faces.ndim != 2 or mesh.faces.shape[1] != 3 or mesh.vertices.shape != (nv, 3)
                or mesh.colors.shape != (nv, 3) or mesh.normals.shape != (nv, 3)
                or (len(mesh.faces) and (mesh.faces.min() < 0 or mesh.faces.max() >= nv))):
            raise InputError(f"{path}: malformed geometry arrays")
        return mesh


def read_header(folder: Path) -> Header:
    """The validated header of a lumigraph folder (raises :class:`InputError`)."""
    path = folder / HEADER_FILE
    try:
        if not folder.is_dir():
            raise InputError(f"{folder} is not a lumigraph folder (no such directory)")
        if path.stat().st_size > MAX_HEADER_BYTES:
            raise InputError(f"{path}: header larger than {MAX_HEADER_BYTES >> 10} KB")
        header = msgspec.json.decode(path.read_bytes(), type=Header)
    except FileNotFoundError as exc:
        raise InputError(f"{folder} is not a lumigraph folder (no {HEADER_FILE})") from exc
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
    except msgspec.ValidationError as exc:
        raise InputError(f"{path}: malformed lumigraph header: {exc}") from exc
    except msgspec.DecodeError as exc:
        raise InputError(f"{path}: not JSON: {exc}") from exc
    if header.format != FORMAT or header.version != VERSION:
        raise InputError(f"{path}: not a {FORMAT} version {VERSION} header "
                         f"(format {header.format!r}, version {header.version})")
    if not 1 <= len(header.slabs) <= 6:
        raise InputError(f"{path}: a lumigraph has 1 to 6 slabs, got {len(header.slabs)}")
    if not (0 < header.near < header.far):
        raise InputError(f"{path}: near/far must satisfy 0 < near < far")
    for s in header.slabs:
        if len(s.frame) != 4 or any(len(r) != 4 for r in s.frame):
            raise InputError(f"{path}: a slab frame must be 4 rows of 4 numbers")
        s.slab()  # checks sizes and resolutions (InputError)
    return header
