"""The colour pyramid of a terrain store: built tile by tile beside the heights, resumable,
and read back by level and window.

Layout inside ``STORE.zarr`` (the grid and filtering are :mod:`lodsprite.terrain.imagery`'s)::

    imagery/0, 1, ...   level j: ``ceil(R / 2^j) x ceil(C / 2^j) x 4`` sRGB RGBA uint8
                        (``R x C`` the header's imagery texels), inner chunks of
                        ``chunk² x 4`` in shards of ``tile² x 4``, Zstandard level 3

Level 0 is warped from the sources one tile at a time; level ``j + 1`` is
:func:`~lodsprite.terrain.imagery.downsample_rgba` of level ``j`` read back from the store,
so memory holds a few tiles whatever the size.  The header's ``imagery.done`` records the
tiles written: an interrupted build resumes where it stopped.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lodsprite.errors import InputError
from lodsprite.terrain.imagery import (
    ImagerySource,
    choose_refine,
    downsample_rgba,
    imagery_shape,
    mosaic,
)
from lodsprite.terrain.store_format import (
    ImageryHeader,
    StoreHeader,
    dem_bounds,
    level_shape,
    pyramid_levels,
    save_header,
    tile_windows,
)

Progress = Callable[[int, int], None]
CODEC_LEVEL = 3


def gdal_env():
    """A rasterio environment: GDAL's and PROJ's messages go to logging, not stderr."""
    import rasterio

    return rasterio.Env()


def estimate_bytes(header: StoreHeader) -> int:
    """An upper bound on the imagery's size (uncompressed RGBA, every level); 0 without."""
    im = header.imagery
    return 0 if im is None else int(im.rows * im.cols * 4 * 4 / 3) + (1 << 20)


def open_sources(paths: list[str], header: StoreHeader) -> list[ImagerySource]:
    """The orthophotos ``paths`` placed over the store ``header`` describes (each checked:
    readable, transformable, overlapping); closed again if one fails."""
    bounds = dem_bounds(header)
    sources: list[ImagerySource] = []
    try:
        for p in paths:
            sources.append(ImagerySource(p, header.crs if bounds else None, bounds,
                                         header.rows, header.cols, header.dx))
    except BaseException:
        for s in sources:
            s.close()
        raise
    return sources


def plan(sources: list[ImagerySource], header: StoreHeader, refine: int | None,
         attribution: str | None) -> ImageryHeader:
    """The imagery header for ``sources`` over ``header``'s grid (refinement chosen by
    :func:`~lodsprite.terrain.imagery.choose_refine` unless given; the attribution given,
    else the first one a source's metadata holds)."""
    m = choose_refine(sources, header.rows, header.cols, header.dx, refine)
    rows, cols = imagery_shape(header.rows, header.cols, m)
    if attribution is None:
        attribution = next((a for a in (s.attribution() for s in sources) if a), "")
    if len(attribution) > 1000:
        raise InputError("--attribution is longer than 1000 characters")
    levels = pyramid_levels(rows, cols)  # as the heights: down to 256 a side
    infos = [s.info() for s in sources]
    return ImageryHeader(infos, m, rows, cols, levels, attribution=attribution,
                         done=[[] for _ in range(levels)])


def create_arrays(group, header: StoreHeader) -> None:
    """Make the empty imagery levels (zero: no data) in ``group``."""
    from zarr.codecs import ZstdCodec

    im = header.imagery
    for j in range(im.levels):
        shape = level_shape(im.rows, im.cols, j)
        shard = tuple(min(header.tile, -(-s // header.chunk) * header.chunk) for s in shape)
        group.create_array(f"imagery/{j}", shape=(*shape, 4),
                           chunks=(header.chunk, header.chunk, 4), shards=(*shard, 4),
                           dtype="uint8", fill_value=0, overwrite=True,
                           compressors=ZstdCodec(level=CODEC_LEVEL))


def tiles(header: StoreHeader, j: int) -> list[tuple[int, int, int, int]]:
    im = header.imagery
    return tile_windows(level_shape(im.rows, im.cols, j), header.tile)


def total_tiles(header: StoreHeader) -> int:
    return sum(len(tiles(header, j)) for j in range(header.imagery.levels))


def build(group, header: StoreHeader, sources: list[ImagerySource],
          progress: Progress | None = None, done_before: int = 0, total: int = 0,
          stop_after: int | None = None) -> tuple[int, bool]:
    """Write the imagery tiles not yet done; ``(tiles written, finished)``.  ``stop_after``
    stops after that many tiles (to test resuming)."""
    im = header.imagery
    for s in sources:
        s.warp(im.refine)
    written = 0
    for j in range(im.levels):
        done = set(im.done[j])
        for n, (r0, r1, c0, c1) in enumerate(tiles(header, j)):
            if n in done:
                continue
            if stop_after is not None and written >= stop_after:
                return written, False
            if j == 0:
                rgba = mosaic(sources, r0, r1, c0, c1)
            else:
                below = level_shape(im.rows, im.cols, j - 1)
                rgba = downsample_rgba(np.asarray(group[f"imagery/{j - 1}"][
                    2 * r0: min(below[0], 2 * r1), 2 * c0: min(below[1], 2 * c1)]))
            group[f"imagery/{j}"][r0:r1, c0:c1] = rgba[: r1 - r0, : c1 - c0]
            im.done[j].append(n)
            save_header(group, header)
            written += 1
            if progress:
                progress(done_before + written, total)
    im.complete = True
    return written, True


def read(group, header: StoreHeader, j: int, r0: int, r1: int, c0: int, c1: int
         ) -> np.ndarray:
    """Level ``j``'s texels over a window, ``(h, w, 4) uint8`` sRGB RGBA.  A damaged chunk
    raises :class:`InputError`."""
    try:
        return np.asarray(group[f"imagery/{j}"][r0:r1, c0:c1])
    except InputError:
        raise
    except Exception as exc:  # zarr, its codecs and HTTP raise many kinds
        raise InputError(f"the store's imagery level {j} cannot be read, damaged or "
                         f"unreachable ({type(exc).__name__}: {str(exc)[:200]})") from exc


def check_arrays(group, header: StoreHeader) -> None:
    """Every imagery level present with the shape the header gives (InputError)."""
    im = header.imagery
    for j in range(im.levels):
        want = (*level_shape(im.rows, im.cols, j), 4)
        try:
            arr = group[f"imagery/{j}"]
        except KeyError as exc:
            raise InputError(f"imagery level {j} is missing") from exc
        if tuple(arr.shape) != want or arr.dtype != np.uint8:
            raise InputError(f"imagery level {j} is {tuple(arr.shape)} {arr.dtype}, the "
                             f"header says {want} uint8")


def level_for(header: StoreHeader, max_side: int) -> int:
    """The finest imagery level whose longer side is at most ``max_side``."""
    im = header.imagery
    for j in range(im.levels):
        if max(level_shape(im.rows, im.cols, j)) <= max_side:
            return j
    return im.levels - 1


def texture(group, header: StoreHeader, max_side: int) -> np.ndarray:
    """The whole imagery as one ``(H, W, 4) uint8`` texture of at most ``max_side`` a side,
    spanning the store's extent exactly (``u = 0`` at sample column 0, ``1`` at the last):
    the finest level that fits, its texels beyond the extent (a level's last texel may
    reach past it) resampled away."""
    from PIL import Image

    im = header.imagery
    j = level_for(header, max_side)
    r, c = level_shape(im.rows, im.cols, j)
    a = read(group, header, j, 0, r, 0, c)
    exact_r, exact_c = im.rows / (1 << j), im.cols / (1 << j)
    if (exact_r, exact_c) == (r, c):
        return a
    out_r, out_c = max(2, round(exact_r)), max(2, round(exact_c))
    img = Image.fromarray(a, "RGBA").resize((out_c, out_r), Image.Resampling.BILINEAR,
                                            box=(0.0, 0.0, exact_c, exact_r))
    return np.asarray(img)


def window_texture(group, header: StoreHeader, r0: int, r1: int, c0: int, c1: int,
                   max_side: int) -> np.ndarray:
    """The imagery over level 0's samples ``[r0, r1) x [c0, c1)`` as ``(H, W, 4) uint8``
    spanning exactly from sample ``(r0, c0)`` to sample ``(r1 - 1, c1 - 1)``: level 0's
    texels when they fit ``max_side`` a side, else the finest level that does (its
    fractional edges resampled, as :func:`texture`)."""
    from PIL import Image

    im = header.imagery
    t0r, t1r = r0 << im.refine, (r1 - 1) << im.refine  # texel span of the samples
    t0c, t1c = c0 << im.refine, (c1 - 1) << im.refine
    j = 0
    while max(t1r - t0r, t1c - t0c) / (1 << j) > max_side and j < im.levels - 1:
        j += 1
    f = 1 << j
    a0r, a0c = t0r // f, t0c // f
    a1r, a1c = min(-(-t1r // f), level_shape(im.rows, im.cols, j)[0]), \
        min(-(-t1c // f), level_shape(im.rows, im.cols, j)[1])
    a = read(group, header, j, a0r, a1r, a0c, a1c)
    box = (t0c / f - a0c, t0r / f - a0r, t1c / f - a0c, t1r / f - a0r)
    if box == (0.0, 0.0, float(a.shape[1]), float(a.shape[0])):
        return a
    size = (max(2, round(box[2] - box[0])), max(2, round(box[3] - box[1])))
    return np.asarray(Image.fromarray(a, "RGBA").resize(size, Image.Resampling.BILINEAR,
                                                        box=box))
