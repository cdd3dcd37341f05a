"""Loading height fields: built-in terrains and GeoTIFF / PNG / NumPy files.

Implements :func:`load_heightfield` (spec string -> raw :class:`HeightField`, not
resampled, not exaggerated), :func:`heightfield_from_array` (nodata filling and
validation) and :func:`metres_per_degree` (WGS84 ellipsoid series).

Units: heights are metres as stored in the source (no vertical-unit conversion);
``dx`` / ``dy`` are metres.  Every user-caused failure raises
:class:`~lodsprite.errors.TerrainError` with a one-line message naming the source.

Spec forms:

* ``jacksboro`` -- the USGS 3 arc-second DEM of the Jacksboro fault area
  (Tennessee) shipped with matplotlib's sample data, 344 x 403 samples.
* ``fractal[:SIZE[:SEED]]`` -- :func:`lodsprite.terrain.generators.fractal`
  (SIZE a power of two in 16..8192, default 512; SEED default 0).
* a path ending in ``.tif`` / ``.tiff`` (GeoTIFF, band 1), ``.png`` (8- or 16-bit
  greyscale; pixel values are metres, spacing 30 m) or ``.npy`` (2-D real array of
  metres, spacing 30 m, NaN = nodata).
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from lodsprite.errors import InputError, TerrainError
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import DEFAULT_GRID, HeightField

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
_FILE_TYPES = (".tif", ".tiff", ".png", ".npy")
_JACKSBORO = "jacksboro_fault_dem.npz"


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


def parse_fractal_spec(spec: str) -> tuple[int, int] | None:
    """``(size, seed)`` of a ``fractal[:SIZE[:SEED]]`` spec, or ``None`` for other specs."""
    parts = spec.strip().split(":")
    if parts[0].lower() != "fractal":
        return None
    if len(parts) > 3 or any(not p.strip() for p in parts[1:]):
        raise TerrainError(f"malformed terrain spec {spec!r}: expected fractal:SIZE[:SEED]")
    try:
        values = [int(p) for p in parts[1:]]
    except ValueError:
        raise TerrainError(f"malformed terrain spec {spec!r}: SIZE and SEED must be "
                           "integers") from None
    size = values[0] if values else DEFAULT_GRID
    seed = values[1] if len(values) > 1 else 0
    return size, seed


#: The largest level of a terrain store loaded whole by commands that need the whole
#: field in memory (a store of any size is read at its finest level up to this side).
STORE_MAX_SIDE = 4096


def load_heightfield(spec: str | os.PathLike) -> HeightField:
    """Load the raw height field named by ``spec`` (see the module docstring).

    Returns a :class:`HeightField` with ``heights (rows, cols) float32`` metres,
    row 0 north, and ``dx``, ``dy`` in metres; ``meta`` records the source,
    ``filled_fraction`` (share of nodata samples filled) and any assumptions.
    """
    if isinstance(spec, os.PathLike):
        spec = os.fspath(spec)
    if not isinstance(spec, str) or not spec.strip():
        raise TerrainError(f"terrain spec must be a non-empty string, got {spec!r}")
    spec = spec.strip()
    if spec.lower() == "jacksboro":
        return _load_jacksboro()
    parsed = parse_fractal_spec(spec)
    if parsed is not None:
        return fractal(*parsed)
    path = Path(spec).expanduser()
    suffix = path.suffix.lower()
    from lodsprite.terrain.store import TerrainStore, is_store

    if is_store(path):
        try:
            return TerrainStore(path).heightfield(STORE_MAX_SIDE)
        except InputError as exc:
            raise TerrainError(str(exc)) from exc
    if not path.exists():
        if suffix in _FILE_TYPES:
            raise TerrainError(f"terrain file not found: {spec}")
        raise TerrainError(f"no such terrain file or built-in: {spec}")
    if not path.is_file():
        raise TerrainError(f"terrain path is not a file: {spec}")
    if suffix in (".tif", ".tiff"):
        return _load_geotiff(path)
    if suffix == ".png":
        return _load_png(path)
    if suffix == ".npy":
        return _load_npy(path)
    raise TerrainError(f"unsupported terrain file type {suffix or '(none)'!r}: {spec} "
                       f"(expected one of {', '.join(_FILE_TYPES)})")


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
    nearest = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    h[bad] = h[tuple(idx[bad] for idx in nearest)]
    for _ in range(_HOLE_SMOOTHING_ITERATIONS):   # averages of valid range: no spikes
        h[bad] = ndimage.uniform_filter(h, size=3, mode="nearest")[bad]
    return fraction


def _load_jacksboro() -> HeightField:
    """The matplotlib sample DEM, 344 x 403 int16 metres at 3 arc-seconds.

    Orientation: row 0 is NORTH and column 0 west, so no flip is needed.
    The file's ``ymin`` (36.733) is the latitude of the top edge (row 0) and
    ``ymax`` (36.446) that of the bottom edge -- the names are swapped, not the
    rows: ``ymin - ymax = 344 * dy`` exactly.  matplotlib's own examples agree:
    the hillshading examples ``imshow`` the array with the default
    ``origin='upper'`` under a north-west light (azdeg=315), and the
    custom-shaded 3-D surface example maps rows to ``linspace(ymin, ymax)``,
    i.e. row 0 to the northern latitude.  The terrain itself agrees (checked on
    a hillshade): with row 0 north, the straight ridge fronting the uplifted
    Pine Mountain thrust block runs SW-NE (the Appalachian strike) and the
    Jacksboro tear fault that cuts it off runs NNW-SSE, as mapped; a flipped
    grid would turn both trends the wrong way.  The dendritic reservoir (a flat
    305 m surface, presumably Norris Lake) lies south-east of that front.
    """
    from matplotlib import cbook

    try:
        data = cbook.get_sample_data(_JACKSBORO)
        if not hasattr(data, "files"):          # older matplotlib: a file object
            data = np.load(data)
        with data:
            z = np.asarray(data["elevation"])
            d = {k: float(data[k]) for k in ("dx", "dy", "xmin", "xmax", "ymin", "ymax")}
    except (OSError, KeyError, ValueError) as e:
        raise TerrainError(f"jacksboro: cannot read matplotlib sample data "
                           f"{_JACKSBORO}: {e}") from e
    # Row 0 is north already (see above): the array is used as stored.
    north, south = max(d["ymin"], d["ymax"]), min(d["ymin"], d["ymax"])
    per_lat, per_lon = metres_per_degree((north + south) / 2)
    meta = {"source": "jacksboro", "file": _JACKSBORO, "crs": "EPSG:4326",
            "north": north, "south": south, "west": d["xmin"], "east": d["xmax"],
            "centre_lat": (north + south) / 2}
    return heightfield_from_array(z, d["dx"] * per_lon, d["dy"] * per_lat, "jacksboro", meta)


def _load_geotiff(path: Path) -> HeightField:
    """Band 1 of a single-band GeoTIFF; nodata masked; rows re-ordered to north-up."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                if ds.count != 1:
                    raise TerrainError(f"{path}: expected 1 band, found {ds.count}")
                if not _is_real_dtype(ds.dtypes[0]):
                    raise TerrainError(f"{path}: heights must be real numbers, found "
                                       f"dtype {ds.dtypes[0]}")
                a = ds.read(1, masked=True)
                transform = ds.transform
                dx, dy, meta = _geotiff_spacing(path, transform, ds.crs, ds.height)
    except TerrainError:
        raise
    except Exception as e:                      # GDAL raises RasterioError or CPLE_* errors
        raise TerrainError(f"cannot read GeoTIFF {path}: {_first_line(e)}") from e
    if transform.e > 0 and not transform.is_identity:   # south-up raster: make row 0 north
        a = a[::-1]                             # (identity = plain image, row 0 on top)
    if transform.a < 0:                         # east-to-west columns: make column 0 west
        a = a[:, ::-1]
    return heightfield_from_array(a, dx, dy, path.name, meta)


def _geotiff_spacing(path: Path, transform: Affine, crs: CRS | None,
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
                           f"{_first_line(e)}") from e
    meta["linear_unit"] = unit
    return sx * factor, sy * factor, meta


def _load_png(path: Path) -> HeightField:
    """An 8- or 16-bit greyscale PNG; pixel values are metres, spacing 30 m."""
    from PIL import Image

    try:
        with Image.open(path) as img:
            if img.format != "PNG":
                raise TerrainError(f"{path}: not a PNG file (found {img.format})")
            if img.mode not in ("L", "I", "I;16", "I;16B", "I;16L"):
                raise TerrainError(f"{path}: expected a greyscale PNG (8- or 16-bit), "
                                   f"found mode {img.mode}")
            a = np.array(img)
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        if isinstance(e, TerrainError):
            raise
        raise TerrainError(f"cannot read PNG {path}: {_first_line(e)}") from e
    meta = {"source": str(path), "format": "PNG", "bit_depth": 8 if a.dtype == np.uint8 else 16,
            "spacing_assumed": f"{DEFAULT_SPACING_M} m"}
    return heightfield_from_array(a, DEFAULT_SPACING_M, DEFAULT_SPACING_M, path.name, meta)


def _load_npy(path: Path) -> HeightField:
    """A ``.npy`` 2-D real array of metres (no pickles), spacing 30 m, NaN = nodata."""
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise TerrainError(f"cannot read NumPy file {path}: {_first_line(e)}") from e
    if not isinstance(a, np.ndarray):
        raise TerrainError(f"{path}: expected a single .npy array")
    meta = {"source": str(path), "format": "npy", "spacing_assumed": f"{DEFAULT_SPACING_M} m"}
    return heightfield_from_array(a, DEFAULT_SPACING_M, DEFAULT_SPACING_M, path.name, meta)


def _is_real_dtype(dtype: str | np.dtype) -> bool:
    try:
        dt = np.dtype(dtype)
    except TypeError:
        return False
    return np.issubdtype(dt, np.number) and not np.issubdtype(dt, np.complexfloating)


def _first_line(e: BaseException) -> str:
    """First line of an exception's message, preferring its immediate cause's detail."""
    cause = e.__cause__ or e.__context__
    if "previous exception" in str(e) and cause is not None:
        e = cause                               # GDAL: "Read failed. See previous exception"
        text = e.args[-1] if e.args and isinstance(e.args[-1], str) else str(e)
    else:
        text = str(e)
    text = text.strip()
    return text.splitlines()[0] if text else type(e).__name__
