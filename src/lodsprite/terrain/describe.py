"""What a dataset is, as a GIS user asks (``lodsprite info DATASET``): a GeoTIFF's or a
terrain store's CRS, extent, resolution, nodata, levels and size, read from its header
only (a GeoTIFF's metadata through rasterio, a store's ``attrs``), never its samples.

:func:`describe` returns an ordered ``{field: text}``; GL-free, imports nothing of the
renderers.
"""

from __future__ import annotations

from pathlib import Path

from lodsprite.errors import InputError, TerrainError
from lodsprite.terrain.rasters import first_line

__all__ = ["describe"]


def describe(spec: str | Path) -> dict[str, str]:
    """The fields of dataset ``spec`` (a GeoTIFF, a terrain store, ``fractal:N``,
    ``jacksboro``), as text, in the order a reader wants them; raises
    :class:`~lodsprite.errors.TerrainError` for what is none of these or cannot be read."""
    from lodsprite.terrain.loaders import parse_fractal_spec
    from lodsprite.terrain.store import is_store

    text = str(spec).strip()
    parsed = parse_fractal_spec(text)
    if parsed is not None:
        n, seed = parsed
        return {"dataset": text, "kind": "generated fractal (in memory)",
                "samples": f"{n + 1} x {n + 1}", "seed": str(seed),
                "CRS": "none (metres from the centre)",
                "resolution": "30 x 30 m"}
    from lodsprite.terrain.remote import Url, location

    path = location(text)
    if is_store(path):
        return _store(path)
    if Path(path.name).suffix.lower() in (".tif", ".tiff") and (
            isinstance(path, Url) or path.is_file()):
        return _geotiff(path)
    if text.lower() == "jacksboro":
        from lodsprite.terrain.loaders import load_heightfield

        hf = load_heightfield("jacksboro")  # 344 x 403: the header is the array's
        m = hf.meta
        return {"dataset": "jacksboro", "kind": "matplotlib's sample DEM (int16 metres)",
                "samples": f"{hf.rows} x {hf.cols}", "CRS": m["crs"],
                "extent": _extent(m["west"], m["south"], m["east"], m["north"]),
                "resolution": f"{_metres(hf.dx)} x {_metres(hf.dy)} m (3 arc-seconds)"}
    if not isinstance(path, Url) and not path.exists():
        raise TerrainError(f"no such dataset: {text}")
    raise TerrainError(f"{text}: info describes a GeoTIFF, a terrain store or fractal:N")


def _extent(x0: float, y0: float, x1: float, y1: float) -> str:
    """West, south, east, north of two corners in any order (a south-up or east-to-west
    raster's bounds come reversed), to a millimetre of a UTM northing."""
    w, e, s, n = min(x0, x1), max(x0, x1), min(y0, y1), max(y0, y1)
    return f"west {w:.10g}, south {s:.10g}, east {e:.10g}, north {n:.10g}"


def _metres(v: float) -> str:
    return f"{v:,.3f}".rstrip("0").rstrip(".")


def _geotiff(path: Path) -> dict[str, str]:
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from lodsprite.terrain.remote import Url, open_raster

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.Env(), (open_raster(path) if isinstance(path, Url)
                                  else rasterio.open(path)) as ds:
                b = ds.bounds
                out = {"dataset": str(path), "kind": f"raster ({ds.driver})",
                       "samples": f"{ds.height} x {ds.width}, {ds.count} band(s), "
                                  f"{ds.dtypes[0]}",
                       "CRS": _crs(ds.crs),
                       "extent": _extent(b.left, b.bottom, b.right, b.top),
                       "resolution": f"{abs(ds.res[0]):.6g} x {abs(ds.res[1]):.6g} "
                                     f"{_units(ds.crs)}",
                       "nodata": "none" if ds.nodata is None else f"{ds.nodata:g}",
                       "overviews": ", ".join(str(f) for f in ds.overviews(1)) or "none",
                       "tiling": ("tiled " + "x".join(str(s) for s in ds.block_shapes[0])
                                  if ds.profile.get("tiled") else "striped"),
                       "compression": str(ds.compression.value if ds.compression
                                          else "none").lower()}
    except InputError as exc:  # a URL refused (no answer, no ranges): its own line
        raise TerrainError(str(exc)) from None
    except Exception as exc:  # GDAL raises RasterioError or CPLE_* errors
        raise TerrainError(f"cannot read {path}: {first_line(exc)}") from None
    return out


def _crs(crs) -> str:
    if crs is None:
        return "none (metres assumed)"
    epsg = crs.to_epsg()
    return f"EPSG:{epsg}" if epsg is not None else crs.to_string()[:80]


def _units(crs) -> str:
    if crs is None:
        return "(no CRS)"
    if crs.is_geographic:
        return "degrees"
    try:
        return crs.linear_units_factor[0]
    except Exception:  # noqa: BLE001 - a CRS without a linear unit
        return "units"


def _store(path: Path) -> dict[str, str]:
    """A store's header, read as it is (an unfinished build too, which
    :class:`~lodsprite.terrain.store.TerrainStore` refuses to open)."""

    from lodsprite.errors import InputError
    from lodsprite.terrain.store_format import level_shape, open_read_only, read_header

    try:
        h = read_header(open_read_only(path))
    except InputError as exc:
        raise TerrainError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - zarr raises many kinds on a damaged store
        raise TerrainError(f"{path}: unreadable terrain store ({type(exc).__name__})") from None
    levels = ", ".join("x".join(str(s) for s in level_shape(h.rows, h.cols, k))
                       for k in range(h.levels))
    out = {"dataset": str(path), "kind": f"lodsprite terrain store (format {h.version})",
           "source": h.source,
           "samples": f"{h.rows} x {h.cols}, {h.encoding}" + (
               f" (value x {h.scale:g} + {h.offset:g} m)" if h.encoding == "int16" else ""),
           "CRS": (h.crs or "none (metres from the centre)")[:80]}
    if h.transform:
        a, _, c, _, e, f = h.transform
        out["extent"] = _extent(c, f + e * h.rows, c + a * h.cols, f)
    else:
        out["extent"] = (f"{_metres(h.dx * (h.cols - 1))} x {_metres(h.dy * (h.rows - 1))} m, "
                         "centred on the origin")
    out["resolution"] = f"{_metres(h.dx)} x {_metres(h.dy)} m"
    out["levels"] = f"{h.levels}: {levels}"
    if h.level_errors:
        out["level errors"] = ", ".join(f"{e:.3g}" for e in h.level_errors) + " m"
    out["tiles"] = f"{h.tile} a side, chunks of {h.chunk}"
    out["complete"] = "yes" if h.complete else "no (resumable: tile it again)"
    out["imagery"] = _imagery(h)
    if h.imagery is not None and h.imagery.attribution:
        out["attribution"] = h.imagery.attribution[:200]
    return out


def _imagery(h) -> str:
    """A store's imagery in a line: texels, refinement, levels, sources, state."""
    im = h.imagery
    if im is None:
        return "none (tile it with --imagery ORTHO.tif to drape one)"
    names = ", ".join(Path(s.path).name for s in im.sources[:4])
    more = f" and {len(im.sources) - 4} more" if len(im.sources) > 4 else ""
    state = "" if im.complete else ", unfinished"
    return (f"{im.rows} x {im.cols} RGBA texels ({1 << im.refine} a height cell side), "
            f"{im.levels} levels, sRGB filtered in linear light, lossless zstd, from "
            f"{names}{more}{state}")
