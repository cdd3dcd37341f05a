"""Machine-readable outputs (CSV, JSON, PNG, matplotlib figures) written atomically: a
file is either complete or absent, never half-written.

The base I/O of the package (runs, stores, tables, reports): it sits at the bottom,
importing nothing of lodsprite but its errors, so that every level writes through it
without reaching into :mod:`lodsprite.report`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from lodsprite.errors import InputError

#: Permissions of every file lodsprite writes (mkstemp's own are owner-only).
FILE_MODE = 0o644


def writable_folder(path: Path | str, option: str = "--out") -> Path:
    """``path`` checked as a folder outputs can be written to, before any work; raises
    :class:`~lodsprite.errors.InputError` (one line, naming ``option``) when it cannot
    be: a file in the way (``FILE/sub``), a place that cannot hold a folder
    (``/proc/x``), one this user may not write.  It makes nothing: a probe folder is made
    and removed in the nearest part of ``path`` that exists (the writer makes the rest)."""
    path = Path(path).expanduser()
    p = path.absolute()
    try:
        while not os.path.lexists(p) and p != p.parent:
            p = p.parent
        if os.path.islink(p) and not os.path.exists(p):
            raise InputError(f"{option} {path}: {p} is a broken link")
        if not os.path.isdir(p):
            raise InputError(f"{option} {path}: {p} is a file, not a folder")
        os.rmdir(tempfile.mkdtemp(dir=p, prefix=".lodsprite-probe-"))
    except OSError as exc:  # a folder it may not enter, a read-only place, /proc
        raise InputError(f"{option} {path}: cannot write in {p} "
                         f"({exc.strerror or type(exc).__name__})") from None
    return path


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it (mode FILE_MODE)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _jsonable(v):
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, Path):
        return str(v)
    return v


def write_json(path: Path, obj: dict) -> None:
    """Write ``obj`` as indented JSON; numpy values become plain numbers, NaN becomes null."""
    atomic_write_bytes(path, (json.dumps(_jsonable(obj), indent=2) + "\n").encode())


def write_csv(path: Path, rows: Sequence[dict], columns: Sequence[str] | None = None) -> None:
    """Write ``rows`` (dicts) as CSV with ``columns`` (default: the first row's keys)."""
    columns = list(columns or (rows[0].keys() if rows else []))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt(r.get(k, "")) for k in columns})
    atomic_write_bytes(path, buf.getvalue().encode())


def _fmt(v):
    if isinstance(v, float | np.floating):
        return f"{float(v):.6g}"
    return v


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an ``(H, W)`` or ``(H, W, 3)`` uint8 image as PNG."""
    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def save_figure(fig, path: Path) -> Path:
    """Write a matplotlib ``Figure`` as PNG atomically (Agg canvas, the figure's own dpi)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    atomic_write_bytes(Path(path), buf.getvalue())
    return Path(path)
