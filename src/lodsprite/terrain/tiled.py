"""Height sources read window by window, for building pyramids larger than memory.

* :class:`FractalSource` - ``fractal:SIZE[:SEED]`` or ``fractal:ROWSxCOLS[:SEED]``: fBm of
  2D gradient noise (Perlin 1985/2002) evaluated at each sample's absolute grid position,
  so any window gives the same samples whatever the tiling (seamless borders), at any
  size (tested to 65536²).  Its detail is the same in metres whatever the size: an octave
  of period ``P`` samples has amplitude ``FRACTAL_RELIEF_M * (P / FRACTAL_REF_PERIOD)^H``
  with ``H = FRACTAL_HURST`` (rough like real DEMs, Hurst 0.8) up to ``FRACTAL_REF_PERIOD``
  (about 10 km) and grows only as ``P^FRACTAL_BROAD_H`` beyond, so a 16k² field is a
  larger land with the same hills as a 1k² one (relief about 1.5 km at 1k², 2.5 km at
  16k²), not a 1k² field stretched.  It is a different generator from the in-memory
  ``fractal:SIZE`` of :mod:`lodsprite.terrain.generators` (FFT synthesis with erosion,
  powers of two only), which needs the whole field at once.
* :class:`GeoTiffSource` - a GeoTIFF or Cloud Optimized GeoTIFF read with rasterio one
  window at a time (decimated reads use the file's overviews); nodata holes inside a
  window are filled from the nearest valid sample.

Both give ``read(r0, r1, c0, c1) -> float32 (r1 - r0, c1 - c0)`` metres and the grid's
``rows``, ``cols``, spacings ``dx``, ``dy`` (metres) and georeferencing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError

FRACTAL_MAX_SIDE = 1 << 20
FRACTAL_SPACING_M = 30.0
FRACTAL_RELIEF_M = 700.0        # amplitude of the octave of FRACTAL_REF_PERIOD samples
FRACTAL_REF_PERIOD = 341.0      # samples (about 10 km at 30 m)
FRACTAL_HURST = 0.8             # amplitude ratio 2^-H per octave below the reference
FRACTAL_BROAD_H = 0.25          # and 2^-H' above it


def _hash(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """A 32-bit integer hash of lattice points (uint64 arithmetic, wrapped)."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.uint64) * np.uint64(0x27D4EB2F165667C5)
             ^ iy.astype(np.uint64) * np.uint64(0x165667B19E3779F9)
             ^ np.uint64((seed * 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF))
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
    return h


def gradient_noise(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """2D gradient noise in about [-0.7, 0.7] on the grid ``x (W,)`` by ``y (H,)``
    (lattice units), ``(H, W) float32``.  The lattice gradients are hashed once per
    lattice point of the window, then gathered per sample."""
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
    ix, iy = x0.astype(np.int64), y0.astype(np.int64)
    lx = np.arange(ix.min(), ix.max() + 2)
    ly = np.arange(iy.min(), iy.max() + 2)
    ang = _hash(lx[None, :], ly[:, None], seed).astype(np.float64) * (2 * math.pi / 2.0 ** 64)
    gx, gy = np.cos(ang).astype(np.float32), np.sin(ang).astype(np.float32)
    cx, cy = (ix - lx[0])[None, :], (iy - ly[0])[:, None]
    fxr, fyc = fx[None, :], fy[:, None]

    def corner(dx, dy):
        return (gx[cy + dy, cx + dx] * (fxr - dx) + gy[cy + dy, cx + dx] * (fyc - dy))

    u = (fx * fx * fx * (fx * (fx * 6 - 15) + 10))[None, :]
    v = (fy * fy * fy * (fy * (fy * 6 - 15) + 10))[:, None]
    c00, c10 = corner(0, 0), corner(1, 0)
    bottom = c00 + u * (c10 - c00)
    c01, c11 = corner(0, 1), corner(1, 1)
    top = c01 + u * (c11 - c01)
    return bottom + v * (top - bottom)


@dataclass
class FractalSource:
    """Seamless fBm terrain of ``rows x cols`` samples, ``FRACTAL_SPACING_M`` apart."""

    rows: int
    cols: int
    seed: int = 0
    dx: float = FRACTAL_SPACING_M
    dy: float = FRACTAL_SPACING_M
    name: str = "fractal"
    crs: str | None = None
    transform: list[float] | None = None

    def __post_init__(self) -> None:
        if not (2 <= self.rows <= FRACTAL_MAX_SIDE and 2 <= self.cols <= FRACTAL_MAX_SIDE):
            raise InputError(f"fractal sides must be 2..{FRACTAL_MAX_SIDE}, got "
                             f"{self.rows}x{self.cols}")
        side = max(self.rows, self.cols)
        self.base_period = max(8.0, side / 3.0)           # samples, largest features
        self.octaves = max(1, int(math.log2(self.base_period / 2.0)) + 1)

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        rr = np.arange(r0, r1, dtype=np.float64)
        cc = np.arange(c0, c1, dtype=np.float64)
        h = np.zeros((r1 - r0, c1 - c0), np.float32)
        period = self.base_period
        for o in range(self.octaves):
            n = gradient_noise(cc / period, rr / period, self.seed * 131 + o)
            rel = period / FRACTAL_REF_PERIOD
            amp = FRACTAL_RELIEF_M * rel ** (FRACTAL_HURST if rel <= 1 else FRACTAL_BROAD_H)
            h += np.float32(amp) * (n if o else np.abs(n) * 2)  # a broad ridged base, fBm
            period /= 2.0
        return h


def parse_fractal(spec: str) -> FractalSource | None:
    """``fractal:SIZE[:SEED]`` or ``fractal:ROWSxCOLS[:SEED]``, else None."""
    parts = spec.split(":")
    if parts[0] != "fractal":
        return None
    if not 2 <= len(parts) <= 3:
        raise InputError(f"a fractal is fractal:SIZE[:SEED] or fractal:ROWSxCOLS[:SEED], "
                         f"got {spec!r}")
    try:
        dims = [int(v) for v in parts[1].lower().split("x")]
        seed = int(parts[2]) if len(parts) == 3 else 0
    except ValueError as exc:
        raise InputError(f"a fractal's size and seed are whole numbers, got {spec!r}") from exc
    rows, cols = (dims[0], dims[0]) if len(dims) == 1 else dims[:2]
    if len(dims) > 2:
        raise InputError(f"a fractal is fractal:SIZE or fractal:ROWSxCOLS, got {spec!r}")
    return FractalSource(rows, cols, seed, name=spec)


@dataclass
class GeoTiffSource:
    """A GeoTIFF/COG read window by window (kept open)."""

    path: Path  # or a Url (lodsprite.terrain.remote): read through the block cache
    rows: int = field(init=False)
    cols: int = field(init=False)

    def __post_init__(self) -> None:
        import rasterio

        from lodsprite.errors import TerrainError
        from lodsprite.terrain.rasters import geotiff_spacing
        from lodsprite.terrain.remote import Url, open_raster

        try:
            self.ds = (open_raster(self.path) if isinstance(self.path, Url)
                       else rasterio.open(self.path))
        except (rasterio.errors.RasterioIOError, OSError) as exc:
            raise InputError(f"cannot read {self.path}: {exc}") from exc
        self.rows, self.cols = self.ds.height, self.ds.width
        t = self.ds.transform
        try:
            self.dx, self.dy, _ = geotiff_spacing(self.path, t, self.ds.crs, self.rows)
        except TerrainError as exc:
            raise InputError(str(exc)) from exc
        # as the in-memory loader: row 0 north, column 0 west
        self.flip_rows, self.flip_cols = (t.e > 0 and not t.is_identity), t.a < 0
        self.name = Path(self.path.name).stem
        self.crs = self.ds.crs.to_string() if self.ds.crs else None
        self.transform = list(self.ds.transform)[:6]
        self.nodata = self.ds.nodata

    def coarse(self, max_side: int = 512) -> np.ndarray:
        """A decimated read of the whole file (through its overviews if it has them),
        masked where nodata, ``float64`` with NaN holes."""
        from rasterio.enums import Resampling

        k = max(1, math.ceil(max(self.rows, self.cols) / max_side))
        shape = (max(1, self.rows // k), max(1, self.cols // k))
        try:
            a = self.ds.read(1, out_shape=shape, masked=True, resampling=Resampling.nearest)
        except Exception as exc:  # noqa: BLE001 - GDAL: RasterioIOError, CPLE_* (truncated)
            raise InputError(f"{self.path}: cannot read it decimated ({_first(exc)})") from None
        return np.ma.filled(a.astype(np.float64), np.nan)

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        from rasterio.windows import Window

        fr0, fr1 = (self.rows - r1, self.rows - r0) if self.flip_rows else (r0, r1)
        fc0, fc1 = (self.cols - c1, self.cols - c0) if self.flip_cols else (c0, c1)
        try:
            a = self.ds.read(1, window=Window(fc0, fr0, fc1 - fc0, fr1 - fr0), masked=True)
        except Exception as exc:  # noqa: BLE001 - GDAL: RasterioIOError, CPLE_* (truncated)
            raise InputError(f"{self.path}: cannot read rows {r0}:{r1}, columns {c0}:{c1} "
                             f"({_first(exc)}); the store keeps what was written") from None
        h = np.ma.filled(a.astype(np.float64), np.nan)
        if self.flip_rows:
            h = h[::-1]
        if self.flip_cols:
            h = h[:, ::-1]
        bad = ~np.isfinite(h)
        if bad.all():  # a window of nodata only: the nearest valid sample of the whole file
            return np.full(h.shape, self._nearest_valid(r0, r1, c0, c1), np.float32)
        if bad.any():
            from scipy.ndimage import distance_transform_edt

            _, (ri, ci) = distance_transform_edt(bad, return_indices=True)
            h = h[ri, ci]
        return h.astype(np.float32)

    def _nearest_valid(self, r0: int, r1: int, c0: int, c1: int) -> float:
        """The valid sample of the decimated file nearest the window's centre."""
        if not hasattr(self, "_coarse"):
            self._coarse = self.coarse()
        c = self._coarse
        ok = np.argwhere(np.isfinite(c))
        if not len(ok):
            return 0.0
        fr = ((r0 + r1) / 2) * c.shape[0] / self.rows
        fc = ((c0 + c1) / 2) * c.shape[1] / self.cols
        i, j = ok[np.argmin((ok[:, 0] - fr) ** 2 + (ok[:, 1] - fc) ** 2)]
        return float(c[i, j])

    def close(self) -> None:
        self.ds.close()


def _first(exc: BaseException) -> str:
    from lodsprite.terrain.rasters import first_line

    return first_line(exc)[:200]


def open_source(spec: str):
    """The source of ``lodsprite tile SRC``: a fractal spec or a GeoTIFF file."""
    from lodsprite.terrain.remote import is_url, location

    src = parse_fractal(spec)
    if src is not None:
        return src
    if is_url(spec):
        if not spec.lower().split("?")[0].endswith((".tif", ".tiff")):
            raise InputError(f"{spec}: the tiler reads GeoTIFF/COG (.tif/.tiff) URLs")
        return GeoTiffSource(location(spec))
    p = Path(spec)
    if not p.is_file():
        raise InputError(f"no such source: {spec} (a GeoTIFF/COG file or fractal:SIZE[:SEED])")
    if p.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"{spec}: the tiler reads GeoTIFF/COG (.tif/.tiff) files or "
                         "fractal:SIZE[:SEED]")
    return GeoTiffSource(p)
