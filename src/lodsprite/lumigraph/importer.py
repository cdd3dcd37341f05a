"""Import of the Stanford Light Field Archive's ``rectified/`` layout into a lumigraph.

The archive's rectified light fields are a square grid of images from cameras on a plane,
rectified to a common image plane, named ``out_RR_CC_Y_X_.png`` (row, column, and the
camera's position in the archive's units).  That is a two-plane lumigraph already: the
cameras are the st nodes, the rectified image plane is the uv plane.  The archive gives
no distances, so the import places the uv plane at unit distance behind the st plane and
scales the st grid so that its extent relative to the uv square is the cameras' spread
relative to the images' width in the archive's units (``st_scale`` adjusts it).  Images
are centre-cropped to a square and resized to ``n_uv`` pixels (the archive's are not
square, nor powers of two).  Row 0 is the top row of cameras (t largest), column 0 the
leftmost (s smallest).

Anything else (no matching files, a grid that is not square or has gaps, unreadable
images) is one :class:`~lodsprite.errors.InputError` line.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from PIL import Image

from lodsprite.errors import InputError
from lodsprite.lumigraph.capture import ColorMesh
from lodsprite.lumigraph.geometry import Slab
from lodsprite.lumigraph.store import save

NAME = re.compile(r"^out_(\d+)_(\d+)_(-?\d+(?:\.\d+)?)_(-?\d+(?:\.\d+)?)_?\.(png|jpe?g)$",
                  re.IGNORECASE)
MAX_GRID = 64
MAX_IMAGE_PIXELS = 1 << 26


def scan(folder: Path) -> dict[tuple[int, int], tuple[Path, float, float]]:
    """``{(row, col): (file, y, x)}`` of the rectified images in ``folder``."""
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder")
    found = {}
    for p in sorted(folder.iterdir()):
        m = NAME.match(p.name)
        if m and p.is_file() and not p.is_symlink():
            found[(int(m[1]), int(m[2]))] = (p, float(m[3]), float(m[4]))
    if not found:
        raise InputError(f"{folder}: no images named like the Stanford archive's rectified "
                         "layout (out_RR_CC_Y_X_.png)")
    rows = sorted({r for r, _ in found})
    cols = sorted({c for _, c in found})
    if len(rows) != len(cols) or len(rows) < 2 or len(rows) > MAX_GRID:
        raise InputError(f"{folder}: a {len(rows)} x {len(cols)} camera grid; lodsprite "
                         f"imports square grids of 2 to {MAX_GRID} cameras per side")
    if (len(found) != len(rows) ** 2 or rows != list(range(rows[0], rows[0] + len(rows)))
            or cols != list(range(cols[0], cols[0] + len(cols)))):
        raise InputError(f"{folder}: the camera grid has gaps")
    return found


def _square(path: Path, n_uv: int) -> tuple[np.ndarray, int]:
    """The image centre-cropped to a square and resized to ``n_uv``; its original width."""
    try:
        with Image.open(path) as im:
            if im.width * im.height > MAX_IMAGE_PIXELS:
                raise InputError(f"{path}: image of {im.width}x{im.height} is too large")
            side = min(im.width, im.height)
            left, top = (im.width - side) // 2, (im.height - side) // 2
            sq = im.convert("RGB").crop((left, top, left + side, top + side))
            return np.asarray(sq.resize((n_uv, n_uv), Image.Resampling.LANCZOS)), side
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise InputError(f"cannot read {path}: {' '.join(str(exc).split())}") from exc


def import_stanford(folder: str | Path, out_dir: str | Path, n_uv: int = 256,
                    codec: str = "jpeg", quality: int = 90, st_scale: float = 1.0) -> dict:
    """Import ``folder`` (the rectified layout) into the lumigraph folder ``out_dir``."""
    found = scan(Path(folder))
    rows = sorted({r for r, _ in found})
    n = len(rows)
    r0, c0 = rows[0], min(c for _, c in found)
    images, side = {}, 1
    pos = np.array([[found[k][2], found[k][1]] for k in sorted(found)])  # (x, y)
    for (r, c), (path, _, _) in found.items():
        img, side = _square(path, n_uv)
        images[(c - c0, n - 1 - (r - r0))] = img  # i along s (columns), j along t (up)
    spread = float(np.ptp(pos, axis=0).max()) or 1.0
    uv_size = 1.0
    st_size = st_scale * uv_size * spread / side
    if not st_size > 0:
        raise InputError(f"{folder}: the cameras' positions do not spread")
    slab = Slab(np.eye(4), st_size, uv_size, 1.0, n, n_uv)
    plane = _uv_plane(uv_size)
    save(out_dir, [slab], [images], plane, f"stanford:{Path(folder).name}", 0.05, 4.0, codec,
         quality)
    return {"nodes": len(images), "grid": n, "uv": n_uv, "st_size": st_size}


def _uv_plane(size: float) -> ColorMesh:
    """The approximate geometry of an imported light field: the uv plane itself (no depth
    is known, so depth correction changes nothing)."""
    h = size / 2
    v = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    return ColorMesh(v, f, np.zeros_like(v), np.tile([0.0, 0.0, 1.0], (4, 1)))
