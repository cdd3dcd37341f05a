"""Perceptual LOD for a scene's object types: ``lod = "profile"`` (Scoggins, Machiraju &
Moorhead 2000, §4 and Eq. 17).

An object type with ``lod = "profile"`` gets a frequency-space LOD error profile
(:func:`lodsprite.profiles.generate.generate_profile`, Eq. 7 and the CSF-weighted Eq. 16)
on first use, built from its LOD model at the manager's LOD factors
:data:`PROFILE_FACTORS` (factor ``f`` of :mod:`lodsprite.manager.models`: triangles
linear in ``f`` from 10 % at 0 to the full mesh at 1), so that a profile level is a LOD
the LODManager extracts.  At run time each instance's LOD at its distance is the
coarsest level whose CSF error is at most one perceptual threshold
(:func:`lodsprite.profiles.select.select_profile`, Eq. 17), so every object shows about
the same perceptual error whatever its type; ``lod = "linear"`` keeps the manager's
distance-linear factor.

Scene settings (:data:`SCENE_SETTINGS`), reduced from ``lodsprite profile``'s 512²
images and 12 x 7 views: 128² images, azimuths every 90° and elevations 0°, 45°, 90°
(12 views), 4x multisampling, ``z0`` 9 bounding diameters and the paper's distance
ratio (about 9 distances down to a 10-pixel impostor).  The ogre builds in about 2 s,
the 97k-triangle tree in about 12 s (this machine, shared; noisy).  The Hausdorff
errors of ``lodsprite profile`` are not computed (NaN): a scene selects by profile.

Cache: a mesh file's profile is written beside it, ``<mesh>.<key>.lodprofile.npz``;
a built-in's (and one whose folder cannot be written) in the user cache folder
(:func:`user_cache_dir`: ``$LODSPRITE_CACHE``, else the platform's cache folder +
``lodsprite``).  ``key`` is a SHA-256 over the mesh file's bytes, the type's arrays, the
LOD model's triangle counts at the factors, the factors and the settings.  A cached file
is validated when read (:func:`read_cached`: size caps before unpacking, array names,
dtypes and shapes, the key, the settings' grids, finite non-negative errors); anything
else is rebuilt and rewritten, never trusted.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import weakref
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lodsprite.errors import InputError
from lodsprite.profiles.generate import ProfileSettings
from lodsprite.profiles.table import ARRAYS, ProfileError, ProfileTable

if TYPE_CHECKING:
    from lodsprite.profiles.chain import LodChain
    from lodsprite.scene.objects import ObjectType

#: The LOD factors a profile's levels are extracted at (coarsest first, the last 1: full).
PROFILE_FACTORS = (0.0, 0.1, 0.2, 0.35, 0.55, 0.8, 1.0)
#: Reduced profile settings for a scene's types (see the module doc).
SCENE_SETTINGS = ProfileSettings(image_size=128, phi_step_deg=90.0, theta_step_deg=45.0)
#: The default perceptual threshold: Eq. 16 (CSF-weighted) relative spectral error.
DEFAULT_THRESHOLD = 1e-3
#: The manager's progressive meshes keep this fraction of the triangles at factor 0.
MIN_FRACTION = 0.1
SUFFIX = ".lodprofile.npz"
CACHE_ENV = "LODSPRITE_CACHE"
FORMAT = "lodsprite-scene-profile"
MAX_FILE_BYTES = 8 << 20          # a cached table is a few kB; anything over is refused
MAX_UNPACKED_BYTES = 32 << 20     # the zip's declared contents, before any is read
#: What profile work this process did (tests read it): built, loaded, rebuilt (invalid).
stats = {"built": 0, "loaded": 0, "rebuilt": 0}


@dataclass(frozen=True, eq=False)
class TypeProfile:
    """A type's error profile ``table`` whose level ``l`` is the LOD at manager factor
    ``factors[l]`` (``(L,) float64``, coarsest first); ``path`` the cache file."""

    table: ProfileTable
    factors: np.ndarray
    path: Path | None = None


def user_cache_dir() -> Path:
    """``$LODSPRITE_CACHE``, else the platform's user cache folder + ``lodsprite``
    (``$XDG_CACHE_HOME`` or ``~/.cache`` on Linux, ``~/Library/Caches`` on macOS,
    ``%LOCALAPPDATA%`` on Windows)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    elif os.name == "nt":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "lodsprite"


def _model_of(t: ObjectType, model: Any) -> Any:
    """The LOD model a profile's levels come from: ``model``, else the type's own (a
    built-in's), else None (the levels are then simplified from the type's arrays)."""
    return model if model is not None else t.model


def cache_key(t: ObjectType, model: Any, settings: ProfileSettings,
              factors: tuple[float, ...]) -> str:
    """SHA-256 hex of everything the profile depends on (see the module doc)."""
    h = hashlib.sha256(FORMAT.encode())
    if t.source is not None and Path(t.source).is_file():
        h.update(Path(t.source).read_bytes())
    for a in (t.vertices, t.faces):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(json.dumps({"model": type(model).__name__, "factors": list(factors),
                         "triangles": _triangles(t, model, factors),
                         "settings": asdict(settings)}, sort_keys=True).encode())
    return h.hexdigest()


def cache_path(t: ObjectType, key: str) -> Path:
    """Beside the mesh file (``<mesh>.<key16>.lodprofile.npz``; a glTF group's part
    ``<mesh>.<part>.<key16>.lodprofile.npz``), or in the user cache folder for a
    built-in (``<name>.<key16>.lodprofile.npz``)."""
    if t.source is None:
        return user_cache_dir() / f"{_safe(t.name)}.{key[:16]}{SUFFIX}"
    src = Path(t.source)
    part = "" if t.name == src.name else "." + _safe(t.name.rpartition(":")[2])
    return src.with_name(f"{src.name}{part}.{key[:16]}{SUFFIX}")


def _safe(name: str) -> str:
    """``name`` as a file-name part: letters, digits, ``-_.``; at most 80 characters."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:80]


def _triangles(t: ObjectType, model: Any, factors: tuple[float, ...]) -> list[int]:
    """Triangles of each level: the model's at each factor, or (no model) as the manager's
    progressive meshes count them, 10 % of the mesh at 0 rising linearly to all at 1."""
    if model is not None:
        return [int(model.triangles(f)) for f in factors]
    full = len(t.faces)
    return [max(1, round(full * (MIN_FRACTION + (1 - MIN_FRACTION) * f))) for f in factors]


def level_chain(t: ObjectType, model: Any, factors: tuple[float, ...]
                ) -> tuple[LodChain, tuple[float, ...]]:
    """The LODs at ``factors`` as a chain, and the factors of its levels (a level no
    larger than the one before is dropped, as on a tiny mesh): the model's extractions
    (unreferenced vertices dropped), or with no model the type's mesh simplified to
    :func:`_triangles`."""
    from lodsprite.meshes import Mesh
    from lodsprite.profiles.chain import LodChain, build_chain

    if model is None:
        counts = np.array(_triangles(t, None, factors))
        chain = build_chain(Mesh(t.vertices, t.faces, t.name), face_counts=counts[:-1])
        near = [int(np.abs(counts - n).argmin()) for n in chain.faces[:-1]]
        return chain, tuple(factors[i] for i in near) + (1.0,)
    v = np.asarray(model.vertices, np.float32)
    levels: list = []
    kept: list[float] = []
    for f in factors:
        idx = np.asarray(model.extract(f), np.int64)
        used, inverse = np.unique(idx, return_inverse=True)
        if levels and len(inverse) // 3 <= levels[-1].n_faces:
            continue
        levels.append(Mesh(v[used], inverse.reshape(-1, 3), f"{t.name}@{f:g}"))
        kept.append(f)
    return LodChain(t.name, tuple(levels)), tuple(kept)


def read_cached(path: Path, key: str, settings: ProfileSettings,
                factors: tuple[float, ...]) -> ProfileTable | None:
    """The table cached at ``path`` if it is valid for ``key`` (see the module doc), else
    None (missing, oversized, malformed, or for other inputs)."""
    try:
        if not path.is_file() or path.stat().st_size > MAX_FILE_BYTES:
            return None
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
        names = {i.filename for i in infos}
        if (names != {f"{n}.npy" for n in (*ARRAYS, "meta")}
                or sum(i.file_size for i in infos) > MAX_UNPACKED_BYTES):
            return None
        with np.load(path, allow_pickle=False) as data:
            kinds = {n: data[n].dtype.kind for n in ARRAYS}
        if any(k != ("i" if n == "faces" else "f") for n, k in kinds.items()):
            return None
        table = ProfileTable.load(path)
        return table if _fits(table, key, settings, factors) else None
    except (OSError, ValueError, TypeError, KeyError, EOFError, RecursionError,
            zipfile.BadZipFile, ProfileError):
        return None


def _fits(table: ProfileTable, key: str, settings: ProfileSettings,
          factors: tuple[float, ...]) -> bool:
    m = table.meta
    grids = (np.array_equal(table.phi_deg, settings.phis())
             and np.array_equal(table.theta_deg, settings.thetas()))
    geo = table.geometric_error
    used = m.get("factors")
    steps = (isinstance(used, list) and len(used) == table.levels
             and all(isinstance(f, float) and f in factors for f in used)
             and used == sorted(set(used)) and used[-1] == 1.0)
    return bool(m.get("lodprofile_key") == key and steps
                and m.get("image_size") == settings.image_size and grids
                and np.all(np.diff(table.faces) > 0)
                and np.all(table.error >= 0) and np.all(table.error_csf >= 0)
                and np.all(np.isnan(geo) | (geo >= 0)) and 0 < table.fov_deg < 90)


def build_profile(t: ObjectType, model: Any, key: str, settings: ProfileSettings,
                  factors: tuple[float, ...], workers: int = 1) -> ProfileTable:
    """Generate the type's profile (real renders; ``workers`` 1: in this process)."""
    from lodsprite.profiles.generate import generate_profile, release_cached

    chain, used = level_chain(t, model, factors)
    try:
        table = generate_profile(chain, settings, workers=workers,
                                 geometric_error=np.full(len(chain), np.nan))
    finally:
        release_cached()
    stats["built"] += 1
    meta = {**table.meta, "lodprofile_key": key, "factors": list(used),
            "type": t.name, "source": None if t.source is None else str(t.source)}
    return ProfileTable(table.error, table.error_csf, table.phi_deg, table.theta_deg,
                        table.z, table.faces, table.geometric_error, meta)


def type_profile(t: ObjectType, model: Any = None, settings: ProfileSettings = SCENE_SETTINGS,
                 factors: tuple[float, ...] = PROFILE_FACTORS, workers: int = 1
                 ) -> TypeProfile:
    """The type's profile: read from its cache if valid, else built and cached (beside
    the mesh; the user cache folder for a built-in or an unwritable folder; nowhere,
    ``path`` None, when neither can be written).  ``model``: the LOD model the objects
    layer draws the type with (``extract(f)``, ``triangles(f)``, ``vertices``; default
    the type's own, else levels simplified from its mesh)."""
    factors = tuple(float(f) for f in factors)
    if len(factors) < 2 or factors[-1] != 1.0 or np.any(np.diff(factors) <= 0):
        raise InputError(f"profile LOD factors must increase to 1, got {factors}")
    model = _model_of(t, model)
    key = cache_key(t, model, settings, factors)
    path = cache_path(t, key)
    # A mesh in a folder that could not be written has its profile in the user cache.
    places = [path] + ([user_cache_dir() / path.name] if t.source is not None else [])
    for place in places:
        table = read_cached(place, key, settings, factors)
        if table is not None:
            stats["loaded"] += 1
            return TypeProfile(table, np.asarray(table.meta["factors"]), place)
    if any(p.exists() for p in places):
        stats["rebuilt"] += 1
    table = build_profile(t, model, key, settings, factors, workers)
    for place in places:
        try:
            table.save(place)
            return TypeProfile(table, np.asarray(table.meta["factors"]), place)
        except OSError:  # cannot be written: the next place, else used uncached
            continue
    return TypeProfile(table, np.asarray(table.meta["factors"]), None)


# --- run time: Eq. 17 per instance, in the manager's factors --------------------------------

#: Each live type's profile by ``id``: the type held weakly, its entry gone with it.
_MEMO: dict[int, tuple[weakref.ref, TypeProfile]] = {}


def profile_of(t: ObjectType | TypeProfile, model: Any = None) -> TypeProfile:
    """A :class:`TypeProfile` as is, or the type's (built or read once per process while
    the type lives; the memo keeps no type alive)."""
    if isinstance(t, TypeProfile):
        return t
    held = _MEMO.get(id(t))
    if held is None or held[0]() is not t:
        held = _MEMO[id(t)] = (weakref.ref(t), type_profile(t, model))
        weakref.finalize(t, _forget, id(t), held[0])
    return held[1]


def _forget(key: int, ref: weakref.ref) -> None:
    """Drop ``_MEMO[key]`` if it is still the entry of the type ``ref`` held."""
    if key in _MEMO and _MEMO[key][0] is ref:
        del _MEMO[key]


def instance_models(positions: np.ndarray) -> np.ndarray:
    """Object-to-world matrices ``(k, 4, 4)`` of instances at ``positions`` ``(k, 3)``
    (feet, metres) or ``(k, 4)`` ``x, y, z, yaw`` (radians about ``+z``; 0 when absent)."""
    p = np.asarray(positions, np.float64).reshape(len(positions), -1)
    yaw = p[:, 3] if p.shape[1] > 3 else np.zeros(len(p))
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.zeros((len(p), 4, 4))
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = c, -s, s, c
    m[:, 2, 2] = m[:, 3, 3] = 1.0
    m[:, :3, 3] = p[:, :3]
    return m


def lod_factors(t: ObjectType | TypeProfile, eye: np.ndarray, positions: np.ndarray,
                fov_y_deg: float, height_px: int, threshold: float = DEFAULT_THRESHOLD
                ) -> np.ndarray:
    """Each instance's LOD factor ``(k,) float64`` in the manager's terms (0 coarsest ..
    1 full): the profile level chosen by Eq. 17 (CSF error at most ``threshold``,
    :func:`~lodsprite.profiles.select.select_profile`) from ``eye (3,)`` world metres, on a
    camera of vertical field of view ``fov_y_deg`` over ``height_px`` rows; instances at
    ``positions`` as :func:`instance_models` takes them."""
    from lodsprite.profiles.select import select_views

    profile = profile_of(t)
    if len(positions) == 0:
        return np.zeros(0)
    phi, theta, dist = instance_views(positions, eye, profile.table.centre)
    lod = select_views(profile.table, phi, theta, dist, fov_y_deg, height_px, threshold)
    return profile.factors[lod]


def instance_views(positions: np.ndarray, eye: np.ndarray, centre: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`lodsprite.profiles.select.object_views` for instances that are turned and
    moved only (no scale), without a matrix inverse: the eye ``(3,)`` in each instance's
    frame is ``R(-yaw) (eye - position)``.  Returns ``phi_deg``, ``theta_deg``,
    ``distance`` ``(k,)`` (degrees, metres) from the frame's ``centre (3,)``."""
    p = np.asarray(positions, np.float64).reshape(len(positions), -1)
    yaw = p[:, 3] if p.shape[1] > 3 else np.zeros(len(p))
    rel = np.asarray(eye, np.float64)[None, :] - p[:, :3]
    c, s = np.cos(yaw), np.sin(yaw)
    v = np.stack([c * rel[:, 0] + s * rel[:, 1], c * rel[:, 1] - s * rel[:, 0], rel[:, 2]],
                 axis=1) - np.asarray(centre, np.float64)
    dist = np.linalg.norm(v, axis=1)
    phi = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360.0
    theta = np.degrees(np.arcsin(np.clip(v[:, 2] / np.where(dist > 0, dist, 1.0), -1, 1)))
    return phi, theta, dist


class ProfileLod:
    """The manager hook (:attr:`lodsprite.manager.engine.CrowdEngine.desired_hook`): the
    objects of profile types (``profiles`` by type index; ``object_types (N,)`` each
    object's type) take their factors from :func:`lod_factors`, the others keep the
    distance-linear ones.  The engine's LOD exponent ``p`` scales the threshold
    (``threshold · p``: larger is coarser, ``p = 0`` the full meshes), so the frame-rate
    feedback and the scene budget turn profile types too."""

    def __init__(self, profiles: dict[int, TypeProfile], object_types: np.ndarray,
                 fov_y_deg: float, height_px: int, threshold: float = DEFAULT_THRESHOLD
                 ) -> None:
        if not threshold >= 0:
            raise InputError(f"profile LOD threshold must be >= 0, got {threshold}")
        self.profiles, self.threshold = dict(profiles), float(threshold)
        self.fov_y_deg, self.height_px = float(fov_y_deg), int(height_px)
        types = np.asarray(object_types)
        self.members = {k: np.flatnonzero(types == k) for k in self.profiles}

    def __call__(self, viewpoint: Any, transforms: np.ndarray, desired: np.ndarray,
                 exponent: float) -> np.ndarray:
        """``desired (N,)`` with the profile types' objects replaced (a new array);
        ``transforms (N, 4)`` every object's ``x, y, z, yaw``."""
        out = np.array(desired, np.float64)
        threshold = self.threshold * max(float(exponent), 0.0)
        for k, idx in self.members.items():
            out[idx] = lod_factors(self.profiles[k], viewpoint.o, transforms[idx],
                                   self.fov_y_deg, self.height_px, threshold)
        return out


def profile_hook(types: list[ObjectType], models: list[Any], object_types: np.ndarray,
                 fov_y_deg: float, height_px: int, threshold: float = DEFAULT_THRESHOLD,
                 settings: ProfileSettings = SCENE_SETTINGS,
                 factors: tuple[float, ...] = PROFILE_FACTORS) -> ProfileLod | None:
    """The objects layer's hook: a :class:`ProfileLod` over the ``lod = "profile"`` types
    of ``types`` (their profiles read or built now, before any timed frame, from
    ``models``, the LOD models the layer draws them with; ``object_types (N,)`` each
    object's type), or None when no type is."""
    profiles = {k: type_profile(t, models[k], settings, factors) for k, t in enumerate(types)
                if t.lod == "profile"}
    if not profiles:
        return None
    return ProfileLod(profiles, object_types, fov_y_deg, height_px, threshold)
