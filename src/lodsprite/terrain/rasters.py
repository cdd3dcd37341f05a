"""Height grids to :class:`HeightField`: nodata filling and validation, and the spacing of
georeferenced rasters.

The base of the terrain readers: :mod:`~lodsprite.terrain.loaders` (whole files),
:mod:`~lodsprite.terrain.tiled` (windowed sources) and :mod:`~lodsprite.terrain.store`
(the pyramid store) all build on it, and it imports none of them.

Units: heights in metres as stored; ``dx`` / ``dy`` in metres.  Failures raise
:class:`~lodsprite.errors.TerrainError` with a one-line message naming the source.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lodsprite.errors import TerrainError
from lodsprite.terrain.heightfield import HeightField

if TYPE_CHECKING:
    from affine import Affine
    from rasterio.crs import CRS

DEFAULT_SPACING_M = 30.0
"""Horizontal spacing (metres) assumed for files without georeferencing (PNG, NPY)."""

MAX_NODATA_FRACTION = 0.5
"""Largest fraction of nodata samples that is filled rather than rejected."""

NODATA_SENTINELS = (-32768.0, -32767.0, -9999.0)
"""Heights always treated as nodata (SRTM / ESRI voids), as are ``|h| >= 1e20``."""

_HOLE_SMOOTHING_ITERATIONS = 4


def metres_per_degree(lat_deg: float) -> tuple[float, float]:
    """Metres per degree of latitude and of longitude at geodetic latitude ``lat_deg``.

    WGS84 ellipsoid, the standard cosine series (accurate to about 1 cm).
    """
    phi = math.radians(lat_deg)
    per_lat = (111132.92 - 559.82 * math.cos(2 * phi) + 1.175 * math.cos(4 * phi)
               - 0.0023 * math.cos(6 * phi))
    per_lon = (111412.84 * math.cos(phi) - 93.5 * math.cos(3 * phi)
               + 0.118 * math.cos(5 * phi))
    return per_lat, per_lon


def heightfield_from_array(a: np.ndarray, dx: float, dy: float, name: str,
                           meta: dict | None = None) -> HeightField:
    """Validate ``a (rows, cols)`` (metres; NaN, inf, masked or sentinel = nodata), fill holes.

    Holes are filled from the nearest valid sample and then lightly smoothed
    inside the holes only, so filled heights stay within the valid range (no
    spikes).  ``meta['filled_fraction']`` records the share of filled samples.
    Raises :class:`TerrainError` (naming ``name``) for non-2-D, smaller than
    2x2, non-numeric or complex data, all-nodata data, or more than 50% nodata.
    """
    valid = ~np.ma.getmaskarray(a)
    a = np.asarray(np.ma.getdata(a))
    if a.ndim != 2:
        raise TerrainError(f"{name}: expected a 2-D height grid, got shape {a.shape}")
    if min(a.shape) < 2:
        raise TerrainError(f"{name}: height grid must be at least 2x2 samples, got "
                           f"{a.shape[0]}x{a.shape[1]}")
    if (not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating)):
        raise TerrainError(f"{name}: heights must be real numbers, found dtype {a.dtype}")
    h = a.astype(np.float64)
    valid &= np.isfinite(h) & (np.abs(h) < 1e20) & ~np.isin(h, NODATA_SENTINELS)
    filled = _fill_holes(h, valid, name)
    meta = {**(meta or {}), "filled_fraction": filled}
    return HeightField(h, dx, dy, name, meta)


def _fill_holes(h: np.ndarray, valid: np.ndarray, name: str) -> float:
    """Fill ``h`` (float64, in place) where not ``valid``; return the filled fraction."""
    bad = ~valid
    n_bad = int(bad.sum())
    if n_bad == 0:
        return 0.0
    fraction = n_bad / bad.size
    if n_bad == bad.size:
        raise TerrainError(f"{name}: contains no valid heights (all samples are nodata)")
    if fraction > MAX_NODATA_FRACTION:
        raise TerrainError(f"{name}: {fraction:.0%} of samples are nodata (at most "
                           f"{MAX_NODATA_FRACTION:.0%} can be filled)")
    from scipy import ndimage  # on first use: a slow import, which the CLI skips

    nearest = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    h[bad] = h[tuple(idx[bad] for idx in nearest)]
    for _ in range(_HOLE_SMOOTHING_ITERATIONS):   # averages of valid range: no spikes
        h[bad] = ndimage.uniform_filter(h, size=3, mode="nearest")[bad]
    return fraction


def georef(bounds, metres_per_unit: tuple[float, float]) -> dict:
    """Where a georeferenced dataset lies in its own CRS, for turning its coordinates into
    the world's (metres from the terrain's centre, :func:`lodsprite.paths.core.
    dataset_to_world`): ``bounds`` two opposite corners (x0, y0, x1, y1 in CRS units, the
    outer edges of the cells; a south-up raster's come reversed), kept as west, south,
    east, north, and the metres a CRS unit spans east and north there."""
    x0, y0, x1, y1 = (float(v) for v in bounds)
    w, s, e, n = min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)
    return {"bounds": [w, s, e, n], "metres_per_unit": [float(metres_per_unit[0]),
                                                         float(metres_per_unit[1])]}


def geotiff_spacing(path: Path, transform: Affine, crs: CRS | None,
                     height: int) -> tuple[float, float, dict]:
    """``dx, dy`` in metres and metadata from an affine ``transform`` and ``crs``."""
    if transform.b != 0 or transform.d != 0:
        raise TerrainError(f"{path}: rotated or sheared rasters are not supported")
    sx, sy = abs(transform.a), abs(transform.e)
    meta: dict = {"source": str(path), "format": "GeoTIFF",
                  "crs": crs.to_string() if crs else None}
    if crs is None:
        if transform.is_identity:               # no georeferencing at all
            sx = sy = DEFAULT_SPACING_M
            meta["spacing_assumed"] = f"{DEFAULT_SPACING_M} m (no georeferencing)"
        else:
            meta["spacing_assumed"] = "metres (no CRS)"
        return sx, sy, meta
    if crs.is_geographic:
        _, to_rad = crs.units_factor
        deg = math.degrees(to_rad)              # degrees per angular unit
        lat = (transform.f + transform.e * height / 2) * deg     # unrotated: d == 0
        if not -90 <= lat <= 90:
            raise TerrainError(f"{path}: centre latitude {lat:.3f} is outside -90..90")
        per_lat, per_lon = metres_per_degree(lat)
        meta["centre_lat"] = lat
        return sx * deg * per_lon, sy * deg * per_lat, meta
    try:
        unit, factor = crs.linear_units_factor
    except Exception as e:                      # any CRS without a linear unit
        raise TerrainError(f"{path}: CRS {meta['crs']} has no linear unit: "
                           f"{first_line(e)}") from e
    meta["linear_unit"] = unit
    return sx * factor, sy * factor, meta


def first_line(e: BaseException) -> str:
    """First line of an exception's message, preferring its immediate cause's detail."""
    cause = e.__cause__ or e.__context__
    if "previous exception" in str(e) and cause is not None:
        e = cause                               # GDAL: "Read failed. See previous exception"
        text = e.args[-1] if e.args and isinstance(e.args[-1], str) else str(e)
    else:
        text = str(e)
    text = text.strip()
    return text.splitlines()[0] if text else type(e).__name__
