"""Reference frames kept on disk, so that runs judged along the same path draw each
band-limited level-0 frame once.

A reference frame depends only on the terrain, the reference's settings and the view,
never on the technique judged.  A benchmark that runs many techniques (or one at many
settings) along the same path (``benchmarks/sprite_frontier.py``) would otherwise draw the
same frames again in every run; on a 16k² store seen to its horizon one frame is minutes
of llvmpipe.  Set ``LODSPRITE_REFERENCE_CACHE=DIR`` (a folder; created if missing) and the
runs' untimed replays read from and write to it.

Each frame is a ``.npy`` file named by a SHA-256 over everything that determines it: the
reference's :meth:`~lodsprite.gl.reference.LevelZeroReference.identity` (the store's
resolved path and header bytes and exaggeration, or the in-memory heights' digest; size,
field of view, samples, filter, colour space, shading, texture) and the view and
projection matrices' bytes.  A file is written whole under a temporary name and renamed,
so runs in parallel share a folder; one that does not read back as the expected
``(h, w, 3) uint8`` array is drawn again and replaced.  Nothing is ever evicted: the
folder is the user's to delete.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

ENV = "LODSPRITE_REFERENCE_CACHE"


def cache_folder() -> Path | None:
    """The folder ``LODSPRITE_REFERENCE_CACHE`` names, or None when it is unset or empty."""
    value = os.environ.get(ENV, "").strip()
    return Path(value) if value else None


def frame_key(identity: str, view: np.ndarray, projection: np.ndarray) -> str:
    """The file stem of one frame: SHA-256 over the reference's ``identity`` and the
    ``(4, 4)`` view and projection matrices (as float64 bytes)."""
    h = hashlib.sha256(identity.encode())
    h.update(np.ascontiguousarray(view, np.float64).tobytes())
    h.update(np.ascontiguousarray(projection, np.float64).tobytes())
    return h.hexdigest()


def _load(file: Path, shape: tuple[int, int, int]) -> np.ndarray | None:
    try:
        with open(file, "rb") as f:
            image = np.load(f, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    if image.shape != shape or image.dtype != np.uint8:
        return None
    return image


def _store(file: Path, image: np.ndarray) -> None:
    fd, tmp = tempfile.mkstemp(dir=file.parent, prefix=".part-", suffix=".npy")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, image, allow_pickle=False)
        os.replace(tmp, file)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def cached_images(ref, folder: Path) -> Callable:
    """``ref.image`` (a :class:`~lodsprite.gl.reference.LevelZeroReference`) behind the
    cache in ``folder``: ``image(viewpoint, projection=None) -> (h, w, 3) uint8``, read from
    the folder when the frame is there, else drawn and written."""
    folder.mkdir(parents=True, exist_ok=True)
    identity = ref.identity()
    w, h = ref.size

    def image(viewpoint, projection=None) -> np.ndarray:
        projection = projection or ref.projection(viewpoint)
        file = folder / (frame_key(identity, viewpoint.view_matrix(), projection.matrix())
                         + ".npy")
        kept = _load(file, (h, w, 3))
        if kept is not None:
            return kept
        drawn = ref.image(viewpoint, projection)
        _store(file, drawn)
        return drawn

    return image
