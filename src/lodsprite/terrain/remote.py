"""DEMs, orthophotos and terrain stores read where they lie: ``http(s)://`` URLs of a
Cloud Optimized GeoTIFF or of a terrain store (Zarr v3), through a read-through cache of
blocks on disk.

Every read goes through fsspec's HTTP filesystem wrapped in its block cache
(``blockcache``: the blocks of each remote file kept in a sparse file on disk, a
file's blocks fetched with HTTP range requests only when first read): rasterio opens a
COG through it (its ``opener``), so GDAL reads only the header, tiles and overviews a
window needs; zarr reads a store's metadata, shard indexes and chunks through it (zarr's
``FsspecStore`` over fsspec's async wrapper).  GDAL's own ``/vsicurl/`` cache lives in
memory only; this one survives the process, so a second run fetches nothing again.

Before a URL is opened the server is asked for one byte (``Range: bytes=0-0``): an answer
other than ``206 Partial Content`` (a server that ignores ranges would send the whole
file for every block) is refused in one line.

``LODSPRITE_HTTP_TRACE=FILE`` appends each store read's URL and byte range to FILE (what
the reads used, to set against what the server sent).

The cache folder is ``LODSPRITE_HTTP_CACHE`` (default ``~/.cache/lodsprite/http``, under
``XDG_CACHE_HOME`` when set), capped at ``LODSPRITE_HTTP_CACHE_MB`` megabytes (default
2048): when a process tree first opens a URL, the files cached longest ago are dropped
until the folder is under its cap.  The commands' ``--http-cache DIR`` sets the folder.
"""

from __future__ import annotations

import math
import os
import threading
import urllib.error
import urllib.request
from functools import lru_cache
from pathlib import Path

from lodsprite.errors import InputError

BLOCK = 1 << 15  # 32 KiB blocks: a read fetches at most two blocks past what it needs
DEFAULT_CAP_MB = 2048
PROBE_TIMEOUT_S = 15.0
SCHEMES = ("http://", "https://")


def is_url(spec: object) -> bool:
    """Whether ``spec`` is an ``http(s)://`` URL."""
    return isinstance(spec, str) and spec.strip().lower().startswith(SCHEMES)


class Url(str):
    """A URL where a path is expected: ``name`` its last segment, ``expanduser()``
    itself (``Path`` would fold its ``//``)."""

    @property
    def name(self) -> str:
        """The last segment of the URL's path (its query and fragment left out)."""
        return self.split("#")[0].split("?")[0].rstrip("/").rsplit("/", 1)[-1]

    def expanduser(self) -> Url:
        return self


def location(spec: str | os.PathLike) -> Path | Url:
    """A dataset's location: a :class:`Url` as it is, a local path expanded."""
    return Url(str(spec).strip().rstrip("/")) if is_url(spec) else Path(spec).expanduser()


def data_root(folder: str | os.PathLike | None) -> str | None:
    """A data folder as processes are told it: a URL as it is, a local folder resolved."""
    if folder is None:
        return None
    return str(location(folder)) if is_url(str(folder)) else str(Path(folder).resolve())


def cache_folder() -> Path:
    env = os.environ.get("LODSPRITE_HTTP_CACHE")
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "lodsprite" / "http"


def cache_cap_bytes() -> int:
    raw = os.environ.get("LODSPRITE_HTTP_CACHE_MB", str(DEFAULT_CAP_MB))
    try:
        mb = float(raw)
    except ValueError:
        raise InputError(f"LODSPRITE_HTTP_CACHE_MB must be a number, got {raw!r}") from None
    if not (mb > 0 and math.isfinite(mb)):
        raise InputError(f"LODSPRITE_HTTP_CACHE_MB must be a positive number, got {raw!r}")
    return int(mb * 2 ** 20)


def probe(url: str) -> None:
    """Ask for the first byte of ``url``; :class:`InputError` unless the answer is ``206``
    (a missing file, a server that does not answer, one that ignores ranges)."""
    req = urllib.request.Request(url, headers={"Range": "bytes=0-0"})
    try:
        with urllib.request.urlopen(req, timeout=PROBE_TIMEOUT_S) as resp:
            status = resp.status
            resp.read(1)
    except urllib.error.HTTPError as exc:
        raise InputError(f"{url}: the server answered {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise InputError(f"{url}: no answer ({reason})") from None
    if status != 206:
        raise InputError(f"{url}: the server does not answer range requests (status "
                         f"{status} to a one-byte range, not 206): serve it from one that "
                         "does, or copy it here")


@lru_cache(maxsize=4)
def _filesystem(folder: str):
    import fsspec

    Path(folder).mkdir(parents=True, exist_ok=True)
    return fsspec.filesystem("blockcache", target_protocol="http", cache_storage=folder,
                             check_files=False, target_options={"block_size": BLOCK})


TRIMMED = "LODSPRITE_HTTP_CACHE_TRIMMED"  # set once trimmed: children inherit it


def filesystem():
    """The cached HTTP filesystem (fsspec ``blockcache`` over ``http``) of the cache
    folder.  The first process to open one trims the cache to its cap, before it has
    opened any remote file; the processes it starts (renderers, readers) do not trim
    again, so no file one of them holds open is dropped."""
    folder = cache_folder()
    cap = cache_cap_bytes()
    try:
        fs = _filesystem(str(folder))
    except OSError as exc:
        raise InputError(f"the HTTP cache folder {folder} cannot be used: {exc}") from None
    if os.environ.get(TRIMMED) != str(folder):
        trim(fs, cap)
        os.environ[TRIMMED] = str(folder)
    return fs


def trim(fs, cap: int) -> int:
    """Drop the files cached longest ago until the cache is under ``cap`` bytes; returns
    the bytes it holds."""
    try:
        entries = dict(fs._metadata.cached_files[-1])
    except (AttributeError, IndexError):
        return 0
    folder = Path(fs.storage[-1])
    sizes = {}
    for url, detail in entries.items():
        f = folder / detail["fn"]
        sizes[url] = f.stat().st_blocks * 512 if f.exists() else 0  # sparse: blocks held
    total = sum(sizes.values())
    for url in sorted(entries, key=lambda u: entries[u].get("time", 0)):
        if total <= cap:
            break
        try:
            fs.pop_from_cache(url)
        except (OSError, KeyError):
            continue
        total -= sizes[url]
    return total


def probed(fs, url: str) -> None:
    """:func:`probe` ``url`` unless the block cache holds it already (a cached run asks
    the server nothing)."""
    try:
        known = bool(fs._check_file(fs._strip_protocol(url)))
    except (OSError, KeyError, AttributeError, ValueError):
        known = False
    if not known:
        probe(url)


def open_raster(url: str):
    """A rasterio dataset of the (Cloud Optimized) GeoTIFF at ``url``, read through the
    block cache (probed first)."""
    import rasterio

    fs = filesystem()
    probed(fs, url)
    try:  # no directory listing or sidecar probes: only the file's own ranges
        with rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN="EMPTY_DIR"):
            return rasterio.open(url, opener=fs)
    except (rasterio.errors.RasterioIOError, OSError) as exc:
        raise InputError(f"cannot read {url}: {str(exc).splitlines()[0]}") from None


_LOCK = threading.Lock()


def read_range(fs, path: str, start: int | None, end: int | None) -> bytes:
    """Bytes ``[start, end)`` of ``path`` (negative: from the end; None: the file's
    start or end) read through the block cache.  fsspec's cached file fetches a whole
    read of a file anew, past its cache: every read here names its length.  One at a
    time: the cache's metadata is not safe across the threads zarr reads from."""
    with _LOCK, fs.open(path, "rb") as f:
        size = f.size if hasattr(f, "size") else os.fstat(f.fileno()).st_size
        a = 0 if start is None else (start if start >= 0 else max(0, size + start))
        b = size if end is None else min(size, end if end >= 0 else size + end)
        f.seek(a)
        data = f.read(max(0, b - a))
    trace = os.environ.get("LODSPRITE_HTTP_TRACE")
    if trace:  # what the reads used, against what the server sent (benchmarks/geodata.py)
        with open(trace, "a") as t:
            t.write(f"{path}\t{a}\t{a + len(data)}\n")
    return data


def zarr_store(url: str):
    """A read-only zarr store over the terrain store at ``url`` through the block cache
    (its ``zarr.json`` probed first)."""
    import zarr
    from fsspec.implementations.asyn_wrapper import AsyncFileSystemWrapper

    class Cached(AsyncFileSystemWrapper):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._cat_file = self._cat_cached  # the wrapper binds the sync fs's own

        async def _cat_cached(self, path, start=None, end=None, **kwargs):
            import asyncio

            return await asyncio.to_thread(read_range, self.sync_fs, path, start, end)

    url = url.rstrip("/")
    sync = filesystem()
    probed(sync, url + "/zarr.json")
    fs = Cached(sync, asynchronous=True)
    return zarr.storage.FsspecStore(fs, path=url, read_only=True)
