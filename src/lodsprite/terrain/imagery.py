"""Orthophotos draped on a terrain store: sources reprojected onto the store's grid, and
the colour pyramid built beside the heights.

The imagery grid of a store whose level 0 is ``rows x cols`` samples (cell centres,
row 0 north) is ``(rows - 1) 2^m x (cols - 1) 2^m`` texels spanning exactly from the first
sample to the last: texel ``(i, j)``'s centre lies ``(j + 1/2) dx / 2^m`` east of sample
``(0, 0)`` and ``(i + 1/2) dy / 2^m`` south of it, so a texture coordinate ``u = 0`` at
column 0 and ``1`` at the last (as every renderer maps its terrain texture) lands each
texel where it belongs.  ``m`` (:func:`choose_refine`) makes a texel about the finest
source's pixel, from 0 to :data:`MAX_REFINE`.

Each source is warped onto that grid window by window with GDAL's warper (rasterio's
``WarpedVRT``, bilinear, any CRS the DEM's can be reached from); its mask (nodata, an
alpha band, the area it covers) is kept as alpha.  Several sources are painted in the
order given, each over the ones before where it has data.  Bands: red, green and blue by
the file's colour interpretation (else the first three), one band as grey; 8-bit values
are kept, any other type is stretched linearly from its 2nd to its 98th percentile (of a
decimated read of the whole file, through its overviews) to 0-255.  A DEM without a CRS
takes sources without one, stretched over its extent.

Coarser levels are the 2x2 mean in linear light (sRGB decoded, weighted by alpha, encoded
again: a box filter, not a decimation).  Stored as sRGB RGBA ``uint8``, chunked as the
heights, losslessly compressed (Zstandard level 3).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.terrain.store_format import ImagerySourceHeader

MAX_REFINE = 3  # at most 8 x 8 texels a height cell
MAX_TEXELS_SIDE = 1 << 17  # an imagery level 0 of at most this many texels a side
STRETCH_PERCENTILES = (2.0, 98.0)


def imagery_shape(rows: int, cols: int, refine: int) -> tuple[int, int]:
    """Texels ``(rows, cols)`` of the imagery's level 0 over a ``rows x cols`` store."""
    return (rows - 1) << refine, (cols - 1) << refine


def imagery_transform(bounds: tuple[float, float, float, float], rows: int, cols: int,
                      refine: int):
    """The imagery grid's affine transform in the DEM's CRS (north up): ``bounds`` the
    DEM's west, south, east, north cell edges, ``rows x cols`` its samples."""
    from affine import Affine

    w, s, e, n = bounds
    sx, sy = (e - w) / cols, (n - s) / rows
    return Affine(sx / (1 << refine), 0.0, w + 0.5 * sx, 0.0, -sy / (1 << refine),
                  n - 0.5 * sy)


def _srgb_to_linear_lut() -> np.ndarray:
    c = np.arange(256, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


_TO_LINEAR = _srgb_to_linear_lut()


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear light ``[0, 1]`` to sRGB ``uint8`` (the standard transfer function)."""
    x = np.clip(x, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.clip(np.rint(s * 255.0), 0, 255).astype(np.uint8)


def downsample_rgba(a: np.ndarray) -> np.ndarray:
    """``(H, W, 4) uint8`` sRGB with alpha to the next level ``(ceil(H/2), ceil(W/2), 4)``:
    each texel the 2x2 mean in linear light weighted by alpha (an odd last row or column
    averaged with itself), alpha the mean alpha."""
    if a.shape[0] % 2:
        a = np.concatenate([a, a[-1:]], axis=0)
    if a.shape[1] % 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    alpha = a[..., 3].astype(np.float32) / 255.0
    lin = _TO_LINEAR[a[..., :3]] * alpha[..., None]

    def box(x):
        return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])

    wsum = box(alpha)
    rgb = box(lin) / np.maximum(wsum, 1e-6)[..., None]
    out = np.empty((*wsum.shape, 4), np.uint8)
    out[..., :3] = linear_to_srgb(rgb)
    out[..., 3] = np.clip(np.rint(wsum * 255.0), 0, 255)
    return out


def over(dst: np.ndarray, src: np.ndarray) -> None:
    """Paint ``src (H, W, 4) uint8`` over ``dst`` in place where it has data (alpha)."""
    a = src[..., 3:4].astype(np.float32) / 255.0
    if not a.any():
        return
    da = dst[..., 3:4].astype(np.float32) / 255.0
    rgb = src[..., :3] * a + dst[..., :3] * (1 - a)
    dst[..., :3] = np.clip(np.rint(rgb), 0, 255)
    dst[..., 3:4] = np.clip(np.rint(255.0 * (a + da * (1 - a))), 0, 255)


class ImagerySource:
    """One orthophoto read onto the imagery grid window by window (module doc).

    ``dem_crs`` and ``bounds`` (west, south, east, north cell edges in that CRS) place the
    DEM; ``rows x cols`` its samples.  Raises :class:`InputError` for a file that cannot be
    read, an unusable band layout, a CRS that cannot be transformed, or a source that does
    not overlap the DEM."""

    def __init__(self, path: str, dem_crs: str | None,
                 bounds: tuple[float, float, float, float] | None, rows: int, cols: int,
                 dx_m: float) -> None:
        import rasterio

        from lodsprite.terrain.remote import is_url, open_raster

        self.path = str(path)
        try:
            self.ds = (open_raster(self.path) if is_url(self.path)
                       else rasterio.open(_local(self.path)))
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"cannot read imagery {path}: {_line(exc)}") from exc
        try:
            self._check(path, rows, cols, dem_crs, bounds, dx_m)
        except BaseException:
            self.ds.close()
            raise

    def _check(self, path: str, rows: int, cols: int, dem_crs: str | None,
               bounds: tuple[float, float, float, float] | None, dx_m: float) -> None:
        from rasterio.enums import ColorInterp

        ds = self.ds
        if ds.count < 1:
            raise InputError(f"imagery {path} has no bands")
        interp = list(ds.colorinterp)
        rgb = [interp.index(c) + 1 for c in (ColorInterp.red, ColorInterp.green,
                                             ColorInterp.blue) if c in interp]
        self.bands = rgb if len(rgb) == 3 else ([1, 2, 3] if ds.count >= 3 else [1])
        self.dtype = np.dtype(ds.dtypes[self.bands[0] - 1])
        if self.dtype.kind not in "uif":
            raise InputError(f"imagery {path}: bands of type {self.dtype} are not images")
        self.rows, self.cols, self.dem_crs = rows, cols, dem_crs
        self.bounds = bounds
        self.stretch = None if self.dtype == np.uint8 else self._stretch()
        self.pixel_m = self._place(dx_m)

    def _place(self, dx_m: float) -> float:
        """Check the source can be placed over the DEM; the metres of its pixel there."""
        from rasterio.crs import CRS
        from rasterio.warp import calculate_default_transform, transform_bounds

        ds, name = self.ds, self.path
        georef = ds.crs is not None
        if self.dem_crs is None or self.bounds is None:
            if georef and not ds.transform.is_identity:
                raise InputError(f"imagery {name} has a CRS but the DEM has none: it cannot "
                                 "be placed (tile a georeferenced DEM)")
            self.vrt = None
            return dx_m * (self.cols - 1) / max(ds.width, 1)
        if not georef:
            raise InputError(f"imagery {name} has no CRS: it cannot be placed over a "
                             "georeferenced DEM")
        try:
            dst = CRS.from_user_input(self.dem_crs)
            b = transform_bounds(ds.crs, dst, *ds.bounds, densify_pts=21)
            t, _, _ = calculate_default_transform(ds.crs, dst, ds.width, ds.height,
                                                  *ds.bounds)
        except Exception as exc:  # PROJ and GDAL raise several kinds  # noqa: BLE001
            raise InputError(f"imagery {name}: its CRS ({_crs_name(ds.crs)}) cannot be "
                             f"transformed to the DEM's ({self.dem_crs})") from exc
        if not all(math.isfinite(v) for v in b):
            raise InputError(f"imagery {name}: its CRS ({_crs_name(ds.crs)}) cannot be "
                             f"transformed to the DEM's ({self.dem_crs})")
        w, s, e, n = self.bounds
        if b[0] >= e or b[2] <= w or b[1] >= n or b[3] <= s:
            raise InputError(f"imagery {name} does not overlap the DEM (its extent in the "
                             f"DEM's CRS {tuple(round(v, 3) for v in b)}, the DEM's "
                             f"{tuple(round(v, 3) for v in self.bounds)})")
        self.vrt = None  # made for the grid by warp()
        return dx_m * abs(t.a) / ((e - w) / self.cols)

    def warp(self, refine: int) -> None:
        """Prepare reading onto the imagery grid refined ``2^refine`` times."""
        from rasterio.enums import Resampling
        from rasterio.vrt import WarpedVRT

        self.refine = refine
        self.shape = imagery_shape(self.rows, self.cols, refine)
        if self.dem_crs is None or self.bounds is None:
            return
        t = imagery_transform(self.bounds, self.rows, self.cols, refine)
        self.vrt = WarpedVRT(self.ds, crs=self.dem_crs, transform=t, width=self.shape[1],
                             height=self.shape[0], resampling=Resampling.bilinear)

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Texels ``[r0:r1, c0:c1]`` of the grid as ``(h, w, 4) uint8`` RGBA (alpha 0
        where the source has no data)."""
        from rasterio.enums import Resampling
        from rasterio.windows import Window

        h, w = r1 - r0, c1 - c0
        try:
            if self.vrt is not None:
                win = Window(c0, r0, w, h)
                data = self.vrt.read(self.bands, window=win)
                mask = self.vrt.dataset_mask(window=win)
            else:  # no CRS: the source stretched over the grid
                H, W = self.shape
                sh, sw = self.ds.height / H, self.ds.width / W
                win = Window(c0 * sw, r0 * sh, w * sw, h * sh)
                data = self.ds.read(self.bands, window=win, out_shape=(len(self.bands), h, w),
                                    resampling=Resampling.bilinear, boundless=True)
                mask = self.ds.dataset_mask(window=win, out_shape=(h, w),
                                            resampling=Resampling.nearest, boundless=True)
        except Exception as exc:  # noqa: BLE001 - GDAL: RasterioIOError, CPLE_* (truncated)
            raise InputError(f"imagery {self.path}: cannot read texels {r0}:{r1}, {c0}:{c1} "
                             f"({_line(exc)}); the store keeps what was written") from None
        rgb = self._to_uint8(data)
        out = np.empty((h, w, 4), np.uint8)
        out[..., :3] = np.moveaxis(rgb, 0, -1) if rgb.shape[0] == 3 else rgb[0][..., None]
        out[..., 3] = np.where(mask > 0, 255, 0)
        return out

    def _to_uint8(self, data: np.ndarray) -> np.ndarray:
        if self.stretch is None:
            return data.astype(np.uint8, copy=False)
        lo = np.array([s[0] for s in self.stretch], np.float64)[:, None, None]
        hi = np.array([s[1] for s in self.stretch], np.float64)[:, None, None]
        x = (data.astype(np.float64) - lo) * (255.0 / np.maximum(hi - lo, 1e-9))
        return np.clip(np.rint(x), 0, 255).astype(np.uint8)

    def _stretch(self) -> list[list[float]]:
        """Per band the 2nd and 98th percentile of a decimated read (its overviews)."""
        from rasterio.enums import Resampling

        k = max(1, math.ceil(max(self.ds.height, self.ds.width) / 1024))
        shape = (len(self.bands), max(1, self.ds.height // k), max(1, self.ds.width // k))
        a = self.ds.read(self.bands, out_shape=shape, masked=True,
                         resampling=Resampling.nearest)
        out = []
        for b in range(a.shape[0]):
            v = a[b].compressed().astype(np.float64)
            v = v[np.isfinite(v)]
            if not len(v):
                raise InputError(f"imagery {self.path}: band {self.bands[b]} holds no data")
            lo, hi = np.percentile(v, STRETCH_PERCENTILES)
            out.append([float(lo), float(hi if hi > lo else lo + 1)])
        return out

    def info(self) -> ImagerySourceHeader:
        """What the store's header keeps of this source."""
        crs = self.ds.crs.to_string() if self.ds.crs else None
        return ImagerySourceHeader(self.path, crs, list(self.bands), self.stretch,
                                   float(self.pixel_m))

    def attribution(self) -> str:
        """A licence or copyright line from the file's metadata tags, if it has one."""
        tags = {k.upper(): v for k, v in self.ds.tags().items()}
        for key in ("TIFFTAG_COPYRIGHT", "COPYRIGHT", "LICENSE", "LICENCE", "ATTRIBUTION"):
            if tags.get(key):
                return str(tags[key]).strip()[:300]
        return ""

    def close(self) -> None:
        if self.vrt is not None:
            self.vrt.close()
        self.ds.close()


def choose_refine(sources: list[ImagerySource], rows: int, cols: int, dx_m: float,
                  refine: int | None = None) -> int:
    """The refinement ``m``: the finest source's pixel about a texel (``dx_m / 2^m``), from
    0 to :data:`MAX_REFINE`, and no more texels a side than :data:`MAX_TEXELS_SIDE`."""
    if refine is None:
        finest = min(s.pixel_m for s in sources)
        refine = round(math.log2(dx_m / finest)) if finest > 0 else 0
    elif not 0 <= refine <= MAX_REFINE:
        raise InputError(f"--imagery-refine must be 0..{MAX_REFINE}, got {refine}")
    refine = max(0, min(MAX_REFINE, refine))
    while refine and max(imagery_shape(rows, cols, refine)) > MAX_TEXELS_SIDE:
        refine -= 1
    return refine


def mosaic(sources: list[ImagerySource], r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """The sources painted in order over the window: ``(h, w, 4) uint8``."""
    out = np.zeros((r1 - r0, c1 - c0, 4), np.uint8)
    for s in sources:
        over(out, s.read(r0, r1, c0, c1))
    return out


def _local(path: str) -> str:
    """A local imagery file (checked to exist)."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise InputError(f"no such imagery file: {path}")
    return str(p)


def _crs_name(crs) -> str:
    """A CRS in a few words: its authority code, else its name."""
    try:
        auth = crs.to_authority()
        if auth:
            return ":".join(auth)
        return str(crs.to_dict().get("proj") or crs.to_wkt()[:60])
    except Exception:  # noqa: BLE001 - a CRS PROJ cannot describe
        return "unknown"


def _line(exc: BaseException) -> str:
    from lodsprite.terrain.rasters import first_line

    return first_line(exc)[:200]
