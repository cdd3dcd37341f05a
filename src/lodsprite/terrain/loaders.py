"""Loading height fields: built-in terrains and GeoTIFF / PNG / NumPy files.

Implements :func:`load_heightfield` (spec string -> raw :class:`HeightField`, not
resampled, not exaggerated); :func:`heightfield_from_array` (nodata filling and
validation) and :func:`metres_per_degree` (WGS84 ellipsoid series) live in
:mod:`~lodsprite.terrain.rasters` and are re-exported here.

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

import os
import warnings
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError, TerrainError
from lodsprite.terrain.generators import fractal
from lodsprite.terrain.heightfield import DEFAULT_GRID, HeightField
from lodsprite.terrain.rasters import (
    DEFAULT_SPACING_M,
    first_line,
    georef,
    geotiff_spacing,
    heightfield_from_array,
    metres_per_degree,
)

_FILE_TYPES = (".tif", ".tiff", ".png", ".npy")
_JACKSBORO = "jacksboro_fault_dem.npz"


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


def load_level0(spec: str | os.PathLike, exaggeration: float = 1.0,
                max_side: int | None = None) -> HeightField:
    """A terrain store's level 0 whole, its own samples (no resampling), heights times
    ``exaggeration``, placed as the adaptive renderer places it (centred on the origin).
    Raises :class:`InputError` when its longer side exceeds ``max_side`` samples (what full
    resolution draws whole; default :data:`STORE_MAX_SIDE` + 1) or ``spec`` is no store."""
    max_side = STORE_MAX_SIDE + 1 if max_side is None else max_side
    from lodsprite.terrain.remote import location
    from lodsprite.terrain.store import TerrainStore, is_store

    if not is_store(spec):
        raise InputError(f"{spec}: not a terrain store")
    store = TerrainStore(location(spec), exaggeration)
    rows, cols = store.shape(0)
    if max(rows, cols) > max_side:
        raise InputError(f"{spec}: level 0 is {cols}x{rows} samples, more than full resolution "
                         f"draws whole ({max_side} a side); use --mode adaptive (level 0 "
                         "streamed by tiles) or render a coarser copy with --mode lod")
    meta = {"source": str(store.path), "format": "lodsprite terrain store", "level": 0,
            "store_rows": rows, "store_cols": cols, "exaggeration": float(exaggeration)}
    return heightfield_from_array(store.read(0, 0, rows, 0, cols), store.dx, store.dy,
                                  store.path.name, meta)


def load_heightfield(spec: str | os.PathLike,
                     store_side: int = STORE_MAX_SIDE) -> HeightField:
    """Load the raw height field named by ``spec`` (see the module docstring).

    Returns a :class:`HeightField` with ``heights (rows, cols) float32`` metres,
    row 0 north, and ``dx``, ``dy`` in metres; ``meta`` records the source,
    ``filled_fraction`` (share of nodata samples filled) and any assumptions.  A terrain
    store gives its finest level of at most ``store_side`` samples a side, whole.
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
    from lodsprite.terrain.remote import is_url, location
    from lodsprite.terrain.store import TerrainStore, is_store

    path = location(spec)
    suffix = Path(path.name).suffix.lower()
    if is_store(path):
        try:
            return TerrainStore(path).heightfield(store_side)
        except InputError as exc:
            raise TerrainError(str(exc)) from exc
    if is_url(spec):
        if suffix not in (".tif", ".tiff"):
            raise TerrainError(f"{spec}: a URL names a (Cloud Optimized) GeoTIFF or a "
                               "terrain store (*.zarr)")
        return _load_geotiff(path, store_side)
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
            "centre_lat": (north + south) / 2,
            "georef": georef((d["xmin"], south, d["xmax"], north), (per_lon, per_lat))}
    return heightfield_from_array(z, d["dx"] * per_lon, d["dy"] * per_lat, "jacksboro", meta)


def _load_geotiff(path, max_side: int | None = None) -> HeightField:
    """Band 1 of a single-band GeoTIFF; nodata masked; rows re-ordered to north-up.
    ``max_side``: read at most this many samples a side (a remote COG: through its
    overviews, only what that needs; its spacing widened to match)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.errors import NotGeoreferencedWarning

    from lodsprite.terrain.remote import Url, open_raster

    try:
        with warnings.catch_warnings(), rasterio.Env():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with (open_raster(path) if isinstance(path, Url) else rasterio.open(path)) as ds:
                if ds.count != 1:
                    raise TerrainError(f"{path}: expected 1 band, found {ds.count}")
                if not _is_real_dtype(ds.dtypes[0]):
                    raise TerrainError(f"{path}: heights must be real numbers, found "
                                       f"dtype {ds.dtypes[0]}")
                k = 1 if max_side is None else max(1, -(-max(ds.shape) // max_side))
                a = ds.read(1, masked=True, out_shape=(-(-ds.height // k), -(-ds.width // k)),
                            resampling=Resampling.average) if k > 1 else ds.read(1, masked=True)
                transform = ds.transform * ds.transform.scale(ds.width / a.shape[1],
                                                              ds.height / a.shape[0])
                dx, dy, meta = geotiff_spacing(path, transform, ds.crs, a.shape[0])
                if ds.crs is not None:  # where the dataset's own coordinates lie
                    meta["georef"] = georef(ds.bounds, (dx / abs(transform.a),
                                                        dy / abs(transform.e)))
    except TerrainError:
        raise
    except InputError as e:  # a URL refused (no answer, no ranges): its own line
        raise TerrainError(str(e)) from e
    except Exception as e:                      # GDAL raises RasterioError or CPLE_* errors
        raise TerrainError(f"cannot read GeoTIFF {path}: {first_line(e)}") from e
    if transform.e > 0 and not transform.is_identity:   # south-up raster: make row 0 north
        a = a[::-1]                             # (identity = plain image, row 0 on top)
    if transform.a < 0:                         # east-to-west columns: make column 0 west
        a = a[:, ::-1]
    return heightfield_from_array(a, dx, dy, path.name, meta)


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
        raise TerrainError(f"cannot read PNG {path}: {first_line(e)}") from e
    meta = {"source": str(path), "format": "PNG", "bit_depth": 8 if a.dtype == np.uint8 else 16,
            "spacing_assumed": f"{DEFAULT_SPACING_M} m"}
    return heightfield_from_array(a, DEFAULT_SPACING_M, DEFAULT_SPACING_M, path.name, meta)


def _load_npy(path: Path) -> HeightField:
    """A ``.npy`` 2-D real array of metres (no pickles), spacing 30 m, NaN = nodata."""
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise TerrainError(f"cannot read NumPy file {path}: {first_line(e)}") from e
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
