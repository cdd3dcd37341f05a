"""LOD error tables (Scoggins et al. 2000 §4: "an array of error values stored in order of
LOD number, spherical coordinates (phi, theta), and distance z") and their file format.

File format (``.npz``, NumPy's zip of ``.npy`` arrays, read with ``allow_pickle=False``):

=================== ============================ ==========================================
array               shape, dtype                 meaning
=================== ============================ ==========================================
``error``           (L, nphi, ntheta, nz) f8     Eq. 7 error of LOD ``l`` (0 = coarsest,
                                                 L-1 = full model, always 0)
``error_csf``       (L, nphi, ntheta, nz) f8     Eq. 16 (contrast-sensitivity weighted)
``phi_deg``         (nphi,) f8                   view azimuths, degrees from object +x
``theta_deg``       (ntheta,) f8                 view elevations, degrees above the object's
                                                 xy-plane (90 = from +z)
``z``               (nz,) f8                     viewing distances, object units, z[0] = z0
``faces``           (L,) i8                      triangle count of each LOD
``geometric_error`` (L,) f8                      Hausdorff distance to the full model,
                                                 object units (for screen-space selection)
``meta``            () str                       JSON: format, version, model, digests,
                                                 fov_deg, image_size, z0, z_ratio, f_min,
                                                 light, ambient, samples, centre, radius,
                                                 csf, seconds, workers
=================== ============================ ==========================================
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import atomic_write_bytes

FORMAT = "lodsprite-lod-error-table"
VERSION = 1
ARRAYS = ("error", "error_csf", "phi_deg", "theta_deg", "z", "faces", "geometric_error")


class ProfileError(InputError):
    """An LOD error table file is missing, malformed or of another version."""


@dataclass(frozen=True, eq=False)
class ProfileTable:
    """An LOD error profile: errors per LOD, view direction and distance, with metadata."""

    error: np.ndarray
    error_csf: np.ndarray
    phi_deg: np.ndarray
    theta_deg: np.ndarray
    z: np.ndarray
    faces: np.ndarray
    geometric_error: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ARRAYS:
            dtype = np.int64 if name == "faces" else np.float64
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=dtype))
        shape = (len(self.faces), len(self.phi_deg), len(self.theta_deg), len(self.z))
        for name in ("error", "error_csf"):
            if getattr(self, name).shape != shape:
                raise ProfileError(f"table {name} has shape {getattr(self, name).shape}, "
                                   f"expected {shape}")
        if self.geometric_error.shape != (shape[0],):
            raise ProfileError("geometric_error must have one entry per LOD")
        if shape[0] < 1 or min(shape[1:]) < 1:
            raise ProfileError(f"table has an empty axis: {shape}")
        if np.any(np.diff(self.z) <= 0) or self.z[0] <= 0:
            raise ProfileError("table distances must be positive and increasing")
        if not (np.all(np.isfinite(self.error)) and np.all(np.isfinite(self.error_csf))):
            raise ProfileError("table errors must be finite")

    @property
    def levels(self) -> int:
        return len(self.faces)

    @property
    def fov_deg(self) -> float:
        return float(self.meta["fov_deg"])

    @property
    def image_size(self) -> int:
        return int(self.meta["image_size"])

    @property
    def centre(self) -> np.ndarray:
        """Object-space centre of the bounding sphere the views look at, ``(3,)``."""
        return np.asarray(self.meta.get("centre", (0.0, 0.0, 0.0)), dtype=np.float64)

    def errors(self, csf: bool) -> np.ndarray:
        return self.error_csf if csf else self.error

    def save(self, path: str | Path) -> Path:
        """Write the table atomically to ``path`` (``.npz``); returns the path."""
        buf = io.BytesIO()
        meta = {"format": FORMAT, "version": VERSION, **self.meta}
        np.savez_compressed(buf, meta=np.array(json.dumps(meta)),
                            **{name: getattr(self, name) for name in ARRAYS})
        path = Path(path)
        atomic_write_bytes(path, buf.getvalue())
        return path

    @classmethod
    def load(cls, path: str | Path) -> ProfileTable:
        """Read a table written by :meth:`save`; :class:`ProfileError` if it is not one."""
        path = Path(path)
        if not path.is_file():
            raise ProfileError(f"no such LOD error table: {path}")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in ARRAYS}
                meta = json.loads(str(data["meta"]))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
            raise ProfileError(f"{path} is not an LOD error table ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ProfileError(f"{path} is not an LOD error table")
        missing = [k for k in ("fov_deg", "image_size", "z0") if k not in meta]
        if missing:
            raise ProfileError(f"{path}: table metadata lacks {', '.join(missing)}")
        if meta.get("version") != VERSION:
            raise ProfileError(f"{path}: table version {meta.get('version')} is not supported "
                               f"(this lodsprite reads version {VERSION})")
        return cls(**arrays, meta=meta)
