"""Terrain pyramids on disk: Zarr v3 multiscale stores built by streaming, for height
fields larger than memory (any size and aspect).

Layout of ``STORE.zarr`` (a Zarr v3 group)::

    attrs["lodsprite"]   the header (:class:`StoreHeader`): format, version, grid, spacing
                         (metres), georeferencing, encoding, levels, build state
    0, 1, 2, ...         level k: ``ceil(rows / 2^k) x ceil(cols / 2^k)`` heights, inner
                         chunks of ``chunk²`` inside shards of ``tile²``; float32 metres,
                         or int16 with ``height = stored * scale + offset``
    minmax/0, ...        per chunk of level k: min, max and geometric error (metres),
                         ``(chunk rows, chunk cols, 3)``

The geometric error of a chunk of level ``k`` is the largest height difference between
the triangulated grid of level ``k`` (samples placed at every ``2^k``-th level-0 position,
each square split along its main diagonal, as the adaptive renderer draws it) and the
samples of level ``k - 1`` beneath it; the header's ``level_errors`` sums them up the
levels (a bound on the error against level 0).

Level 0 is written tile by tile from the source (:mod:`lodsprite.terrain.tiled`); level
``k + 1`` is the exact 2×2 mean of level ``k`` (an odd last row or column is averaged with
itself), read back from the store tile by tile, so memory never holds more than a few
tiles.  The header records which tiles are done: an interrupted build resumes where it
stopped; a store whose build has not finished is refused when opened, with the command
that finishes it.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np

from lodsprite.errors import InputError
from lodsprite.terrain.store_format import (
    DEFAULT_CHUNK,
    DEFAULT_TILE,
    FORMAT,
    MIN_LEVEL_SIDE,
    VERSION,
    VERSIONS,
    StoreHeader,
    coarse_error,
    decode,
    dem_bounds,
    downsample,
    encode,
    estimate_bytes,
    is_store,
    level_shape,
    open_read_only,
    pyramid_levels,
    read_header,
    save_header,
    tile_windows,
)

Progress = Callable[[int, int], None]
log = logging.getLogger(__name__)
_WARNED: set[str] = set()  # stores opened without their unfinished imagery, said once


def build_store(source_spec: str, out: str | Path, tile: int = DEFAULT_TILE,
                chunk: int = DEFAULT_CHUNK, encoding: str = "float32", scale: float = 0.25,
                overwrite: bool = False, progress: Progress | None = None,
                stop_after: int | None = None, scheduler: str | None = None,
                imagery: list[str] | tuple[str, ...] = (), attribution: str | None = None,
                imagery_refine: int | None = None) -> dict:
    """Build (or resume building) the pyramid of ``source_spec`` in ``out``; returns a
    summary.  ``scheduler``: a Dask scheduler address to spread each level's height tiles
    over (the store and the source must be on storage the workers share; imagery is built
    here).  ``imagery``: orthophotos to drape (:mod:`lodsprite.terrain.store_imagery`),
    painted in order; ``attribution`` their licence line (default: from their metadata);
    ``imagery_refine`` texels a height cell side as a power of two (default: from the
    finest source).  A complete store without imagery gains it.  ``stop_after`` stops
    after that many tiles (to test resuming)."""

    from lodsprite.terrain import store_imagery
    from lodsprite.terrain.tiled import open_source

    if encoding not in ("float32", "int16"):
        raise InputError(f"--encoding must be float32 or int16, got {encoding!r}")
    if not (chunk >= 16 and tile >= chunk and tile % chunk == 0):
        raise InputError(f"the tile ({tile}) must be a multiple of the chunk ({chunk}), "
                         "chunk at least 16")
    if encoding == "int16" and not scale > 0:
        raise InputError(f"--scale must be > 0 m, got {scale}")
    src = open_source(source_spec)
    out = Path(out)
    offset = _check_source(src, encoding, scale)
    levels = pyramid_levels(src.rows, src.cols)
    header = StoreHeader(FORMAT, VERSION, source_spec, src.rows, src.cols, float(src.dx),
                         float(src.dy), levels, tile, chunk, encoding,
                         float(scale) if encoding == "int16" else 1.0, float(offset),
                         src.crs, src.transform, False, [[] for _ in range(levels)])
    if imagery and imagery_refine is None:  # the refinement the store's imagery has
        old = _existing_header(out) if out.exists() and not overwrite else None
        if old is not None and old.imagery is not None:
            imagery_refine = old.imagery.refine
    # GDAL's and PROJ's messages to logging, not the terminal (a failure is our one line)
    with store_imagery.gdal_env():
        sources = store_imagery.open_sources(list(imagery), header) if imagery else []
        try:
            if sources:
                header.imagery = store_imagery.plan(sources, header, imagery_refine,
                                                    attribution)
            group = _open_for_build(out, header, overwrite)
            header = read_header(group)
            if header.complete:
                return {"store": str(out), "rows": src.rows, "cols": src.cols,
                        "levels": levels, "tiles_written": 0, "seconds": 0.0,
                        "resumed": False, "already": True}
            return _build(out, src, group, header, sources, progress, stop_after, scheduler)
        finally:
            for s in sources:
                s.close()


def _build(out: Path, src, group, header: StoreHeader, sources: list, progress, stop_after,
           scheduler) -> dict:
    import time

    from lodsprite.terrain import store_imagery

    levels, tile = header.levels, header.tile
    total = sum(len(tile_windows(level_shape(src.rows, src.cols, k), tile)) for k in range(levels))
    done_before = sum(len(d) for d in header.done)
    if header.imagery is not None:
        total += store_imagery.total_tiles(header)
        done_before += sum(len(d) for d in header.imagery.done)
    written, t0, samples0 = 0, time.perf_counter(), 0
    client = _client(scheduler) if scheduler else None
    try:
        for k in range(levels):
            done_k = set(header.done[k])
            pending = [n for n in range(len(tile_windows(level_shape(src.rows, src.cols, k), tile)))
                       if n not in done_k]
            if k == 0:
                tiles0 = tile_windows(level_shape(src.rows, src.cols, 0), tile)
                samples0 = sum((tiles0[n][1] - tiles0[n][0]) * (tiles0[n][3] - tiles0[n][2])
                               for n in pending)
            if stop_after is not None:
                pending = pending[: max(0, stop_after - written)]
            for n in _run_tiles(client, out, k, pending, src, group, header):
                header.done[k].append(n)
                save_header(group, header)
                written += 1
                if progress:
                    progress(done_before + written, total)
            if stop_after is not None and written >= stop_after and len(header.done[k]) < len(
                    tile_windows(level_shape(src.rows, src.cols, k), tile)):
                return {"store": str(out), "interrupted": True, "tiles_written": written}
    finally:
        if client is not None:
            client.close()
    if not header.level_errors:
        header.level_errors = level_errors(group, header)
        save_header(group, header)
    if header.imagery is not None and not header.imagery.complete:
        more = None if stop_after is None else max(0, stop_after - written)
        n, finished = store_imagery.build(group, header, sources, progress,
                                          done_before + written, total, more)
        written += n
        if not finished:
            return {"store": str(out), "interrupted": True, "tiles_written": written}
    header.complete = True
    save_header(group, header)
    seconds = time.perf_counter() - t0
    return {"store": str(out), "rows": src.rows, "cols": src.cols, "levels": levels,
            "tiles_written": written, "seconds": seconds, "resumed": done_before > 0,
            "mb_per_s": samples0 * 4 / 2 ** 20 / max(seconds, 1e-9)}


def level_errors(group, header: StoreHeader) -> list[float]:
    """Per level, the sum of the largest chunk errors of it and every finer level."""
    total, out = 0.0, []
    for k in range(header.levels):
        e = np.asarray(group[f"minmax/{k}"][...])[..., 2]
        total += float(np.nanmax(e)) if k and np.isfinite(e).any() else 0.0
        out.append(total)
    return out


def _client(address: str):
    from lodsprite.cluster import connect

    return connect(address)


def _run_tiles(client, out: Path, k: int, tiles: list[int], src, group, header):
    """Write level ``k``'s ``tiles`` here or on the cluster; yields each tile index once
    it is written."""
    if client is None:
        for n in tiles:
            build_tile(out, k, n, src, group, header)
            yield n
        return
    from dask.distributed import as_completed

    futures = {client.submit(build_tile, str(out), k, n, pure=False): n for n in tiles}
    for fut in as_completed(futures):
        fut.result()
        yield futures[fut]


def _open_group(out: Path):
    import zarr

    return zarr.open_group(str(out), mode="r+")


def build_tile(out, k: int, n: int, src=None, group=None, header=None) -> None:
    """Write tile ``n`` of level ``k`` (level 0 from the source, others from the level
    below) with its chunks' min and max; opens what it is not given (a cluster worker)."""
    from lodsprite.terrain.tiled import open_source

    group = group if group is not None else _open_group(Path(out))
    header = header if header is not None else read_header(group)
    r0, r1, c0, c1 = tile_windows(level_shape(header.rows, header.cols, k), header.tile)[n]
    if k == 0:
        src = src if src is not None else open_source(header.source)
        h, err = src.read(r0, r1, c0, c1), None
    else:
        h, err = _parent_window(group, header, k, r0, r1, c0, c1)
    _write_tile(group[str(k)], group[f"minmax/{k}"], header, h, r0, c0, err)


def _check_source(src, encoding: str, scale: float) -> float:
    """Refuse an all-nodata source; the int16 offset (the coarse minimum)."""
    coarse = src.coarse() if hasattr(src, "coarse") else src.read(0, min(src.rows, 64), 0,
                                                                  min(src.cols, 64))
    finite = np.asarray(coarse, np.float64)
    finite = finite[np.isfinite(finite)]
    if not len(finite):
        raise InputError(f"{src.name}: every sample is nodata")
    if encoding == "int16":
        lo = float(finite.min()) - 0.1 * (float(np.ptp(finite)) + 1.0)
        if (float(finite.max()) - lo) / scale > 32767:
            raise InputError(f"heights span more than int16 holds at --scale {scale} m: "
                             "use a larger scale or float32")
        return lo
    return 0.0


def _open_for_build(out: Path, header: StoreHeader, overwrite: bool):
    import zarr

    from lodsprite.terrain.store_imagery import estimate_bytes as imagery_bytes

    free = shutil.disk_usage(out.parent if out.parent.exists() else Path.cwd()).free
    need = estimate_bytes(header.rows, header.cols, header.encoding) + imagery_bytes(header)
    if out.exists():
        old = _existing_header(out)
        if overwrite:
            if old is None and not (out.is_dir() and not any(out.iterdir())):
                raise InputError(f"{out} exists and is not a terrain store: not replacing it")
            if need > free + _size(out):
                raise InputError(f"the store needs up to {need / 2 ** 30:.1f} GB and the disk "
                                 f"has {(free + _size(out)) / 2 ** 30:.1f} GB")
            shutil.rmtree(out)
        else:
            if old is None:
                raise InputError(f"{out} exists and is not a terrain store being built: "
                                 "choose another --out")
            same = (old.source, old.rows, old.cols, old.tile, old.chunk, old.encoding,
                    old.scale) == (header.source, header.rows, header.cols, header.tile,
                                   header.chunk, header.encoding, header.scale)
            if not same:
                raise InputError(f"{out} holds a store built with other parameters: pass "
                                 "--overwrite to rebuild it")
            group = zarr.open_group(str(out), mode="r+")
            _match_imagery(out, group, old, header)
            return group
    elif need > free:
        raise InputError(f"the store needs up to {need / 2 ** 30:.1f} GB and the disk has "
                         f"{free / 2 ** 30:.1f} GB free")
    group = zarr.open_group(str(out), mode="w")
    dtype = "float32" if header.encoding == "float32" else "int16"
    fill = np.nan if header.encoding == "float32" else -32768
    for k in range(header.levels):
        shape = level_shape(header.rows, header.cols, k)
        shard = (min(header.tile, _ceil_to(shape[0], header.chunk)),
                 min(header.tile, _ceil_to(shape[1], header.chunk)))
        group.create_array(str(k), shape=shape, chunks=(header.chunk, header.chunk),
                           shards=shard, dtype=dtype, fill_value=fill)
        cr, cc = (-(-s // header.chunk) for s in shape)
        per = header.tile // header.chunk  # one minmax chunk a tile: tiles write apart
        group.create_array(f"minmax/{k}", shape=(cr, cc, 3),
                           chunks=(min(per, cr), min(per, cc), 3), dtype="float32",
                           fill_value=np.nan)
    if header.imagery is not None:
        from lodsprite.terrain.store_imagery import create_arrays

        create_arrays(group, header)
    save_header(group, header)
    return group


def _match_imagery(out: Path, group, old: StoreHeader, new: StoreHeader) -> None:
    """Resume ``old``'s build with ``new``'s imagery: the same sources, or imagery added
    to a store without any (its arrays made, the store incomplete until they are full)."""
    from lodsprite.terrain.store_imagery import create_arrays

    if new.imagery is None:
        if old.imagery is not None and not old.complete:
            raise InputError(f"{out} is being built with imagery: resume it with the same "
                             "--imagery")
        return
    if old.imagery is None:
        _check_space(out, new)
        old.imagery, old.complete, old.version = new.imagery, False, VERSION
        create_arrays(group, old)
        save_header(group, old)
        return
    if [s.path for s in old.imagery.sources] != [s.path for s in new.imagery.sources]:
        raise InputError(f"{out} holds imagery from other sources "
                         f"({', '.join(s.path for s in old.imagery.sources)}): pass "
                         "--overwrite to rebuild it")
    if old.imagery.refine != new.imagery.refine:
        raise InputError(f"{out} holds imagery refined {old.imagery.refine}, not "
                         f"{new.imagery.refine} (--imagery-refine): pass --overwrite to "
                         "rebuild it")


def _check_space(out: Path, header: StoreHeader) -> None:
    """Refuse imagery the disk cannot hold (uncompressed, every level: an upper bound)."""
    from lodsprite.terrain.store_imagery import estimate_bytes as imagery_bytes

    free = shutil.disk_usage(out if out.exists() else out.parent).free
    need = imagery_bytes(header)
    if need > free:
        raise InputError(f"the imagery needs up to {need / 2 ** 30:.1f} GB and the disk "
                         f"has {free / 2 ** 30:.1f} GB free")


def _existing_header(out: Path) -> StoreHeader | None:
    """The header of a lodsprite store at ``out``, or None for anything else."""
    import zarr

    if not is_store(out):
        return None
    try:
        return read_header(zarr.open_group(str(out), mode="r"))
    except Exception:  # not a group, not ours, damaged: not a store to resume
        return None


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def _ceil_to(n: int, m: int) -> int:
    return -(-n // m) * m


def _parent_window(group, header: StoreHeader, k: int, r0: int, r1: int, c0: int, c1: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Level ``k``'s window as the 2×2 mean of level ``k - 1`` (read from the store), and
    the geometric error of that window's samples against level ``k - 1``."""
    pr, pc = level_shape(header.rows, header.cols, k - 1)
    kr, kc = level_shape(header.rows, header.cols, k)
    er, ec = min(kr, r1 + 1), min(kc, c1 + 1)        # one more row and column, if any
    below = decode(group[str(k - 1)][2 * r0: min(pr, 2 * er), 2 * c0: min(pc, 2 * ec)],
                   header)
    ext = downsample(below)[: er - r0, : ec - c0]
    h = ext[: r1 - r0, : c1 - c0]
    return h, coarse_error(ext, below, r1 - r0, c1 - c0)


def _write_tile(arr, mm, header: StoreHeader, h: np.ndarray, r0: int, c0: int,
                err: np.ndarray | None = None) -> None:
    arr[r0: r0 + h.shape[0], c0: c0 + h.shape[1]] = encode(h, header)
    stored = decode(encode(h, header), header)
    c = header.chunk
    out = np.full((-(-h.shape[0] // c), -(-h.shape[1] // c), 3), np.nan, np.float32)
    for i in range(0, h.shape[0], c):
        for j in range(0, h.shape[1], c):
            block = stored[i: i + c, j: j + c]
            ok = block[np.isfinite(block)]
            e = 0.0 if err is None else float(np.max(err[i: i + c, j: j + c]))
            if len(ok):
                out[i // c, j // c] = (ok.min(), ok.max(), e)
    mm[r0 // c: r0 // c + out.shape[0], c0 // c: c0 // c + out.shape[1]] = out


class TerrainStore:
    """A pyramid store opened for reading: header and arrays validated when opened.

    ``exaggeration`` (> 0) multiplies every height read, the chunk bounds and the level
    errors, as ``--exaggeration`` does for in-memory terrains."""

    def __init__(self, path: str | Path, exaggeration: float = 1.0) -> None:

        if not (exaggeration > 0 and np.isfinite(exaggeration)):
            raise InputError(f"vertical exaggeration must be positive, got {exaggeration}")
        from lodsprite.terrain.remote import Url, is_url, location

        self.exaggeration = float(exaggeration)
        self.path = location(path) if is_url(path) else Path(path)
        if not isinstance(self.path, Url) and not (self.path / "zarr.json").is_file():
            raise InputError(f"{self.path} is not a terrain store (no zarr.json)")
        try:
            self.group = open_read_only(self.path)
            self.header = read_header(self.group)
        except InputError as exc:
            raise InputError(f"{self.path}: {exc}") from exc
        except Exception as exc:  # zarr raises many kinds on a damaged store
            raise InputError(f"{self.path}: unreadable terrain store "
                             f"({type(exc).__name__}: {exc})") from exc
        h = self.header
        if h.format != FORMAT or h.version not in VERSIONS:
            raise InputError(f"{self.path}: not a {FORMAT} store of version "
                             f"{' or '.join(map(str, VERSIONS))}")
        if not h.complete and h.level_errors and h.imagery is not None:
            # the heights finished, the imagery not: the terrain without its imagery
            if str(self.path) not in _WARNED:
                _WARNED.add(str(self.path))
                log.warning("%s: its imagery is unfinished (resume it with lodsprite tile "
                            "--imagery); drawn without", self.path)
            h = self.header = msgspec.structs.replace(h, imagery=None)
        elif not h.complete:
            if isinstance(self.path, Url):
                raise InputError(f"{self.path}: the build did not finish; finish it where "
                                 "it was built")
            more = "".join(f" --imagery {s.path}" for s in h.imagery.sources) + (
                f" --imagery-refine {h.imagery.refine}") if h.imagery else ""
            raise InputError(f"{self.path}: the build did not finish; run `lodsprite tile "
                             f"{h.source} --out {self.path}{more}` again to resume it")
        for k in range(h.levels):
            try:
                shape = tuple(self.group[str(k)].shape)
            except KeyError as exc:
                raise InputError(f"{self.path}: level {k} is missing") from exc
            if shape != level_shape(h.rows, h.cols, k):
                raise InputError(f"{self.path}: level {k} is {shape}, the header says "
                                 f"{level_shape(h.rows, h.cols, k)}")
        if h.imagery is not None:
            from lodsprite.terrain.store_imagery import check_arrays

            try:
                check_arrays(self.group, h)
            except InputError as exc:
                raise InputError(f"{self.path}: {exc}") from exc

    @property
    def imagery(self):
        """The imagery's header (:class:`~lodsprite.terrain.store_format.ImageryHeader`),
        or None for a store without imagery."""
        return self.header.imagery

    def read_imagery(self, j: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Imagery level ``j`` over a window of its texels, ``(h, w, 4) uint8`` sRGB RGBA
        (alpha 0: no source covers it)."""
        from lodsprite.terrain import store_imagery

        return store_imagery.read(self.group, self.header, j, r0, r1, c0, c1)

    def imagery_window(self, r0: int, r1: int, c0: int, c1: int, max_side: int
                       ) -> np.ndarray:
        """The imagery over level 0's samples ``[r0, r1) x [c0, c1)``, ``(H, W, 4) uint8``
        (:func:`lodsprite.terrain.store_imagery.window_texture`)."""
        from lodsprite.terrain import store_imagery

        return store_imagery.window_texture(self.group, self.header, r0, r1, c0, c1,
                                            max_side)

    def imagery_texture(self, max_side: int) -> np.ndarray:
        """The whole imagery at most ``max_side`` texels a side, ``(H, W, 4) uint8``
        (:func:`lodsprite.terrain.store_imagery.texture`)."""
        from lodsprite.terrain import store_imagery

        return store_imagery.texture(self.group, self.header, max_side)

    @property
    def levels(self) -> int:
        return self.header.levels

    @property
    def dx(self) -> float:
        return self.header.dx

    @property
    def dy(self) -> float:
        return self.header.dy

    @property
    def chunk(self) -> int:
        return self.header.chunk

    @property
    def level_errors(self) -> list[float]:
        return [e * self.exaggeration for e in self.header.level_errors]

    def shape(self, k: int) -> tuple[int, int]:
        return level_shape(self.header.rows, self.header.cols, k)

    def read(self, k: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Level ``k``'s heights in metres over a window, ``float32`` (NaN: unwritten)."""
        h = decode(self.group[str(k)][r0:r1, c0:c1], self.header)
        return h if self.exaggeration == 1.0 else h * np.float32(self.exaggeration)

    def minmax(self, k: int) -> np.ndarray:
        """Level ``k``'s per-chunk min, max and geometric error, ``(chunk rows, chunk
        cols, 3)``."""
        return np.asarray(self.group[f"minmax/{k}"][...]) * self.exaggeration

    def level_for(self, max_side: int) -> int:
        """The finest level whose longer side is at most ``max_side``."""
        for k in range(self.levels):
            if max(self.shape(k)) <= max_side:
                return k
        return self.levels - 1

    def heightfield(self, max_side: int = 4096):
        """The finest level that fits ``max_side`` as an in-memory :class:`HeightField`
        (its spacing stretched so that it spans level 0's extent, as the adaptive renderer
        draws it), for commands that need the whole field."""
        from lodsprite.terrain.rasters import heightfield_from_array

        k = self.level_for(max_side)
        r, c = self.shape(k)
        a = self.read(k, 0, r, 0, c)
        h = self.header
        meta = {"source": str(self.path), "format": "lodsprite terrain store",
                "level": k, "store_rows": self.header.rows, "store_cols": self.header.cols,
                "crs": self.header.crs}
        bounds = dem_bounds(h)
        if bounds is not None:  # where the dataset's own coordinates lie
            from lodsprite.terrain.rasters import georef

            sx, sy = h.transform[0], h.transform[4]
            meta["georef"] = georef(bounds, (h.dx / abs(sx), h.dy / abs(sy)))
        dx = h.dx * (h.cols - 1) / max(c - 1, 1)
        dy = h.dy * (h.rows - 1) / max(r - 1, 1)
        return heightfield_from_array(a, dx, dy, self.path.name, meta)


__all__ = ["DEFAULT_CHUNK", "DEFAULT_TILE", "FORMAT", "MIN_LEVEL_SIDE", "VERSION", "StoreHeader",
           "TerrainStore", "build_store", "build_tile", "coarse_error", "decode", "downsample",
           "encode", "estimate_bytes", "is_store", "level_errors", "level_shape",
           "pyramid_levels"]
