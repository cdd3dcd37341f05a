"""The terrain pyramid's format: its header, level shapes and tiling, the 2×2 mean
between levels, the geometric error of a coarse level, and the stored encodings.

What :mod:`lodsprite.terrain.store` builds and reads (the layout is described there).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from lodsprite.errors import InputError

FORMAT = "lodsprite-terrain-pyramid"
VERSION = 2  # 2: imagery beside the heights; version 1 stores (no imagery) still open
VERSIONS = (1, 2)
DEFAULT_TILE = 1024
DEFAULT_CHUNK = 256
MIN_LEVEL_SIDE = 256


class ImagerySourceHeader(msgspec.Struct, forbid_unknown_fields=True):
    """One orthophoto the imagery was made from: its name, CRS, bands read (1-based),
    stretch (per band ``[lo, hi]``; None: 8-bit values kept) and the metres of its pixel
    (:meth:`lodsprite.terrain.imagery.ImagerySource.info`)."""

    path: str
    crs: str | None
    bands: list[int]
    stretch: list[list[float]] | None
    pixel_m: float


class ImageryHeader(msgspec.Struct, forbid_unknown_fields=True):
    """The colour pyramid's part of the header: level 0 is ``rows x cols`` texels
    (``(store rows - 1) 2^refine`` by ``(store cols - 1) 2^refine``), ``levels`` levels,
    chunked and sharded as the heights; sRGB RGBA ``uint8`` filtered in linear light,
    compressed by ``codec``."""

    sources: list[ImagerySourceHeader]
    refine: int
    rows: int
    cols: int
    levels: int
    colour_space: Literal["srgb-linear-filtered"] = "srgb-linear-filtered"
    codec: Literal["zstd-3"] = "zstd-3"
    attribution: str = ""
    complete: bool = False
    done: list[list[int]] = []


class StoreHeader(msgspec.Struct, forbid_unknown_fields=True):
    """The store's header (``attrs["lodsprite"]``)."""

    format: str
    version: int
    source: str
    rows: int
    cols: int
    dx: float
    dy: float
    levels: int
    tile: int
    chunk: int
    encoding: Literal["float32", "int16"]
    scale: float = 1.0
    offset: float = 0.0
    crs: str | None = None
    transform: list[float] | None = None
    complete: bool = False
    done: list[list[int]] = []  # per level, the tiles written (row-major tile index)
    level_errors: list[float] = []  # per level, the geometric error bound (metres)
    imagery: ImageryHeader | None = None


def dem_bounds(header: StoreHeader) -> tuple[float, float, float, float] | None:
    """The DEM's west, south, east, north cell edges in its CRS (None: no CRS)."""
    t = header.transform
    if not header.crs or not t:
        return None
    sx, _, x0, _, sy, y0 = t[:6]
    x1, y1 = x0 + sx * header.cols, y0 + sy * header.rows
    return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)


def level_shape(rows: int, cols: int, k: int) -> tuple[int, int]:
    """The shape of level ``k`` of a ``rows x cols`` pyramid: ``ceil(n / 2^k)`` a side."""
    return -(-rows // (1 << k)), -(-cols // (1 << k))


def pyramid_levels(rows: int, cols: int) -> int:
    """Levels down to the first whose longer side is at most ``MIN_LEVEL_SIDE``."""
    n = 1
    while max(level_shape(rows, cols, n - 1)) > MIN_LEVEL_SIDE:
        n += 1
    return n


def downsample(a: np.ndarray) -> np.ndarray:
    """The exact 2×2 mean, an odd last row or column averaged with itself, ``float32``."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape[0] % 2:
        a = np.concatenate([a, a[-1:]], axis=0)
    if a.shape[1] % 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    return (0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])
            ).astype(np.float32)


def tile_windows(shape: tuple[int, int], tile: int) -> list[tuple[int, int, int, int]]:
    """The ``(r0, r1, c0, c1)`` windows of ``tile²`` tiles over ``shape``, row-major."""
    r, c = shape
    return [(r0, min(r, r0 + tile), c0, min(c, c0 + tile))
            for r0 in range(0, r, tile) for c0 in range(0, c, tile)]


def estimate_bytes(rows: int, cols: int, encoding: str) -> int:
    """An upper bound on the store's size (uncompressed, all levels)."""
    item = 4 if encoding == "float32" else 2
    return int(rows * cols * item * 4 / 3) + (1 << 20)


def read_header(group) -> StoreHeader:
    """A Zarr group's validated header; InputError when it has none or a malformed one."""
    raw = group.attrs.get("lodsprite")
    if raw is None:
        raise InputError("not a lodsprite terrain store (no header)")
    try:
        header = msgspec.convert(raw, StoreHeader)
    except msgspec.ValidationError as exc:
        raise InputError(f"malformed terrain store header: {exc}") from exc
    if header.imagery is not None:
        _check_imagery(header)
    t = header.transform
    if t is not None and (len(t) != 6 or not all(math.isfinite(v) for v in t)
                          or t[0] == 0 or t[4] == 0):
        raise InputError("malformed terrain store header: the transform must be 6 finite "
                         "numbers with non-zero cell sizes")
    return header


def _check_imagery(header: StoreHeader) -> None:
    """An imagery header that matches its store's grid (nothing allocated from a bad one)."""
    im = header.imagery
    if not (0 <= im.refine <= 3 and (im.rows, im.cols) == ((header.rows - 1) << im.refine,
                                                           (header.cols - 1) << im.refine)
            and 1 <= im.levels <= 24 and len(im.done) in (0, im.levels)
            and len(im.attribution) <= 1000):
        raise InputError("malformed terrain store header: its imagery does not match its "
                         "grid")


def is_store(path: str | Path) -> bool:
    """Whether ``path`` is a folder holding a Zarr group (a store to open and validate),
    or an ``http(s)://`` URL of one (named ``*.zarr``; validated when opened)."""
    from lodsprite.terrain.remote import is_url

    if is_url(path):
        return str(path).strip().rstrip("/").lower().endswith(".zarr")
    p = Path(path).expanduser()
    return p.is_dir() and (p / "zarr.json").is_file()


def open_read_only(path: str | Path):
    """The Zarr v3 group of a store to read: a local folder, or a URL through the HTTP
    block cache (:mod:`lodsprite.terrain.remote`)."""
    import zarr

    from lodsprite.terrain.remote import is_url, zarr_store

    where = zarr_store(str(path)) if is_url(path) else str(path)
    return zarr.open_group(where, mode="r", zarr_format=3)


def save_header(group, header: StoreHeader) -> None:
    """Write ``header`` as the group's ``attrs["lodsprite"]``."""
    group.attrs["lodsprite"] = json.loads(msgspec.json.encode(header))


def coarse_error(coarse: np.ndarray, fine: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Per coarse sample of the first ``rows x cols``, the largest difference between
    the coarse grid's triangulated surface (square ``(i, j)`` split along ``(i, j)-(i+1,
    j+1)``) and the fine samples ``(2i + a, 2j + b)``, ``a, b`` in {0, 1}.  ``coarse``
    may hold one more row and column (the next tile's); the edge is repeated past it."""
    c = np.asarray(coarse, np.float64)
    c = np.concatenate([c, c[-1:]], 0) if c.shape[0] == rows else c
    c = np.concatenate([c, c[:, -1:]], 1) if c.shape[1] == cols else c
    c = c[: rows + 1, : cols + 1]
    f = np.full((2 * rows, 2 * cols), np.nan)
    fh, fw = min(fine.shape[0], 2 * rows), min(fine.shape[1], 2 * cols)
    f[:fh, :fw] = fine[:fh, :fw]
    h00, h10, h01, h11 = c[:-1, :-1], c[1:, :-1], c[:-1, 1:], c[1:, 1:]
    err = np.zeros((rows, cols))
    for a, b, surf in ((0, 0, h00), (1, 0, (h00 + h10) / 2), (0, 1, (h00 + h01) / 2),
                       (1, 1, (h00 + h11) / 2)):
        d = np.abs(f[a::2, b::2][:rows, :cols] - surf)
        err = np.fmax(err, np.where(np.isfinite(d), d, 0.0))
    return err.astype(np.float32)


def encode(h: np.ndarray, header: StoreHeader) -> np.ndarray:
    """Heights in metres to the stored values (float32, or int16 with -32768 for NaN)."""
    if header.encoding == "float32":
        return h.astype(np.float32)
    q = np.rint((np.asarray(h, np.float64) - header.offset) / header.scale)
    return np.where(np.isfinite(q), np.clip(q, -32767, 32767), -32768).astype(np.int16)


def decode(a: np.ndarray, header: StoreHeader) -> np.ndarray:
    """Stored values to metres (``float32``; NaN where nothing was written)."""
    if header.encoding == "float32":
        return np.asarray(a, dtype=np.float32)
    a = np.asarray(a)
    out = a.astype(np.float32) * np.float32(header.scale) + np.float32(header.offset)
    out[a == -32768] = np.nan
    return out
