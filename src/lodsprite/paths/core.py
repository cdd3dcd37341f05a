"""Camera path type and the JSON path file format.

JSON path files
---------------
:meth:`CameraPath.to_json` writes and :func:`load_path_json` reads UTF-8 JSON
of this form::

    {
      "format": "lodsprite-path",      required, exactly this string
      "version": 1,                    required, integer 1
      "name": "my-flight",             optional string (default: the file's stem)
      "fov_y_deg": 45.0,               optional number in (0, 180), degrees
                                       (default 45)
      "coordinates": "world",          optional: "world" (default) or "dataset"
      "frames": [ FRAME, FRAME, ... ]  required, at least one frame
    }

With ``"coordinates": "dataset"`` every frame is a look-at frame whose ``eye`` and
``target`` are (easting, northing, height) in the terrain dataset's own CRS (its units;
degrees east and north for a geographic one) and metres above its datum, as a GIS gives
them; they are placed in the world (metres from the terrain's centre, heights times the
vertical exaggeration) by :func:`dataset_to_world`, with the terrain the path is flown
over (a georeferenced GeoTIFF or store; any other terrain refuses such a path).

Each ``FRAME`` is an object in one of two forms (a file may mix them):

1. the viewpoint tuple of Swan et al. (2002, §3.1), as written by ``to_json``::

       {"x": [xx, xy, xz], "y": [yx, yy, yz], "z": [zx, zy, zz], "o": [ox, oy, oz]}

   ``x``, ``y``, ``z`` are the camera's unit axes in world space (screen-right,
   screen-up, and *backwards*: the camera looks along ``-z``); they must be
   orthonormal and right-handed (``x × y = z``) to within 1e-6.  ``o`` is the
   eye position in metres.

2. a look-at frame::

       {"eye": [ex, ey, ez], "target": [tx, ty, tz], "up": [ux, uy, uz]}

   ``eye`` and ``target`` are world points in metres and must differ; ``up``
   (optional, default ``[0, 0, 1]``) is the screen-up hint, which need not be
   orthogonal to the view direction but must not be parallel to it.  It is
   converted with :func:`lodsprite.camera.look_at`.

Every vector is a list of exactly three finite JSON numbers (not booleans,
strings or ``NaN``); other keys in a frame are an error.  ``to_json`` always
writes form 1 with full ``repr`` precision, so saving and loading a path is
exact.  Any problem with a file raises :class:`~lodsprite.errors.PathError`
with a one-line message naming the file and, where it applies, the frame.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lodsprite.camera import DEFAULT_FOV_Y_DEG, Viewpoint, look_at, rotated_viewpoint, view_rotation
from lodsprite.errors import InputError, PathError

PATH_FORMAT = "lodsprite-path"
PATH_VERSION = 1
CHEN1999_FRAMES = 460
SWAN2002_FRAMES = 600
BUILTIN_PATHS = ("chen1999", "swan2002")

#: The frame rate a path's frames are spaced at when it is played in time (frame ``i`` at
#: ``i / NOMINAL_FPS`` seconds): the 30 frames a second the papers' paths were made for.
NOMINAL_FPS = 30.0
_AXES_TOL = 1e-6  # the tolerance of Viewpoint's own orthonormality check


# --------------------------------------------------------------------------- path type


@dataclass(frozen=True, eq=False)
class CameraPath:
    """A named sequence of viewpoints with a vertical field of view (degrees).

    ``viewpoints`` is stored as a tuple of :class:`~lodsprite.camera.Viewpoint`
    (at least one).  Equality is identity (viewpoints hold numpy arrays);
    compare :meth:`eyes` or :meth:`to_dict` instead.
    """

    name: str
    viewpoints: tuple[Viewpoint, ...]
    fov_y_deg: float = DEFAULT_FOV_Y_DEG

    def __post_init__(self) -> None:
        vps = tuple(self.viewpoints)
        if not vps:
            raise PathError(f"camera path '{self.name}' has no frames")
        if not all(isinstance(v, Viewpoint) for v in vps):
            raise PathError(f"camera path '{self.name}': frames must be Viewpoint objects")
        fov = _finite_float(self.fov_y_deg)
        if fov is None or not (0.0 < fov < 180.0):
            raise PathError(f"camera path '{self.name}': fov_y_deg must be in (0, 180) degrees, "
                            f"got {self.fov_y_deg!r}")
        object.__setattr__(self, "viewpoints", vps)
        object.__setattr__(self, "fov_y_deg", fov)

    def __len__(self) -> int:
        return len(self.viewpoints)

    def eyes(self) -> np.ndarray:
        """Eye positions ``(N, 3) float64`` in metres."""
        return np.stack([v.o for v in self.viewpoints])

    def axes(self) -> np.ndarray:
        """Camera axes ``(N, 3, 3) float64``: ``axes[i]`` has rows ``x, y, z`` of frame ``i``."""
        return np.stack([np.stack([v.x, v.y, v.z]) for v in self.viewpoints])

    def resampled(self, n: int) -> CameraPath:
        """The same path with ``n >= 2`` frames.

        New frame ``j`` sits at the fractional old frame index
        ``u = j (N - 1) / (n - 1)``, so the path keeps its timing (speed profile)
        as well as its shape: the eye is interpolated linearly between old eyes
        ``floor(u)`` and ``ceil(u)`` (it lies on the old eye polyline) and the
        orientation by quaternion slerp between the same two frames.  Frames
        that land on an old frame (always the first and the last) are copied
        exactly.
        """
        n = _check_frames(n)
        u = np.linspace(0.0, len(self) - 1.0, n)
        return CameraPath(self.name, tuple(self.between(u)), self.fov_y_deg)

    def between(self, u: np.ndarray) -> list[Viewpoint]:
        """Viewpoints at fractional frame indices ``u`` (``(k,) float64`` in ``[0, N-1]``):
        the eye interpolated linearly between frames ``floor(u)`` and ``ceil(u)``, the
        orientation by quaternion slerp; an index on a frame gives that frame itself."""
        return self.sampler()(u)

    def sampler(self) -> Callable[[np.ndarray], list[Viewpoint]]:
        """:meth:`between` with the path's eyes, rotations and slerp made once: a callable
        ``u -> viewpoints`` for many calls (a played run asks one per frame)."""
        count = len(self)
        if count == 1:
            return lambda u: [self.viewpoints[0]] * np.asarray(u).reshape(-1).size
        eyes = self.eyes()
        from scipy.spatial.transform import Slerp  # on first use: a slow import

        slerp = Slerp(np.arange(count, dtype=np.float64), view_rotation(self.axes()))

        def at(u) -> list[Viewpoint]:
            u = np.clip(np.asarray(u, dtype=np.float64).reshape(-1), 0.0, count - 1.0)
            i0 = np.minimum(np.floor(u).astype(np.intp), count - 2)
            w = u - i0
            rotations = slerp(u)
            pos = eyes[i0] * (1.0 - w)[:, None] + eyes[i0 + 1] * w[:, None]
            out = []
            for j in range(len(u)):
                if w[j] == 0.0:
                    out.append(self.viewpoints[i0[j]])
                elif w[j] == 1.0:
                    out.append(self.viewpoints[i0[j] + 1])
                else:
                    out.append(rotated_viewpoint(rotations[j], pos[j]))
            return out

        return at

    def duration_s(self, fps: float = NOMINAL_FPS) -> float:
        """Seconds the path lasts played at ``fps`` frames a second (its nominal speed):
        frame ``i`` is at ``i / fps``."""
        return (len(self) - 1) / float(fps)

    def at_time(self, t_s: float, fps: float = NOMINAL_FPS) -> Viewpoint:
        """The viewpoint ``t_s`` seconds into the path played at ``fps`` frames a second
        (clamped to its ends; :meth:`between`)."""
        return self.between(np.array([t_s * float(fps)]))[0]

    def to_dict(self) -> dict:
        """The JSON document (see the module docstring) as plain Python objects."""
        return {
            "format": PATH_FORMAT,
            "version": PATH_VERSION,
            "name": self.name,
            "fov_y_deg": float(self.fov_y_deg),
            "frames": [v.to_dict() for v in self.viewpoints],
        }

    @classmethod
    def from_dict(cls, doc: object, source: str = "<dict>", default_name: str = "path",
                  terrain_meta: dict | None = None) -> CameraPath:
        """Parse a JSON document (see the module docstring); raises :class:`PathError`.

        ``source`` names the document in error messages; ``default_name`` is
        used when the document has no ``"name"``; ``terrain_meta``: the terrain's meta,
        for ``"coordinates": "dataset"`` (:func:`dataset_to_world`).
        """
        if not isinstance(doc, dict):
            raise PathError(f"{source}: a camera path must be a JSON object, "
                            f"got {type(doc).__name__}")
        if doc.get("format") != PATH_FORMAT:
            raise PathError(f"{source}: not a lodsprite camera path "
                            f"(\"format\" must be \"{PATH_FORMAT}\", got {doc.get('format')!r})")
        version = doc.get("version")
        if isinstance(version, bool) or version != PATH_VERSION:
            raise PathError(f"{source}: unsupported camera path version {version!r} "
                            f"(this lodsprite reads version {PATH_VERSION})")
        name = doc.get("name", default_name)
        if not isinstance(name, str):
            raise PathError(f"{source}: \"name\" must be a string, got {name!r}")
        fov = doc.get("fov_y_deg", DEFAULT_FOV_Y_DEG)
        fov_f = _finite_float(fov)
        if fov_f is None or not (0.0 < fov_f < 180.0):
            raise PathError(f"{source}: \"fov_y_deg\" must be a number in (0, 180), got {fov!r}")
        frames = doc.get("frames")
        if not isinstance(frames, list):
            raise PathError(f"{source}: \"frames\" must be a list of frame objects")
        if not frames:
            raise PathError(f"{source}: \"frames\" is empty; a path needs at least one frame")
        coords = doc.get("coordinates", "world")
        if coords not in ("world", "dataset"):
            raise PathError(f"{source}: \"coordinates\" must be \"world\" or \"dataset\", "
                            f"got {coords!r}")
        if coords == "dataset":
            frames = [_placed(f, i, source, terrain_meta or {}) for i, f in enumerate(frames)]
        vps = tuple(_parse_frame(f, i, source) for i, f in enumerate(frames))
        return cls(name, vps, fov_f)

    def to_json(self, path_file: str | os.PathLike) -> None:
        """Write the path as JSON (module docstring), one frame per line, exact floats."""
        head = {k: v for k, v in self.to_dict().items() if k != "frames"}
        lines = [f"  {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
        frames = ",\n".join(f"    {json.dumps(v.to_dict())}" for v in self.viewpoints)
        text = "{\n" + "\n".join(lines) + '\n  "frames": [\n' + frames + "\n  ]\n}\n"
        try:
            Path(path_file).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise PathError(f"cannot write camera path '{path_file}': "
                            f"{exc.strerror or exc}") from exc


def dataset_to_world(points: np.ndarray, meta: dict) -> np.ndarray:
    """``points (N, 3)`` (easting, northing, height: the dataset's CRS units and metres)
    as world points (metres from the terrain's centre; heights times its exaggeration),
    by the terrain's ``meta`` (a :class:`~lodsprite.terrain.HeightField`'s: ``georef``,
    :func:`~lodsprite.terrain.rasters.georef`, and ``exaggeration``).  The world's origin
    is the centre of the dataset's bounds (its samples are the cells' centres, spaced
    evenly about it); raises :class:`PathError` for a terrain without a georeference."""
    ref = meta.get("georef")
    if not ref:
        raise PathError("a path in dataset coordinates needs a georeferenced terrain "
                        "(a GeoTIFF or a store with a CRS)")
    w, s, e, n = ref["bounds"]
    fx, fy = ref["metres_per_unit"]
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ex = float(meta.get("exaggeration", 1.0))
    return np.stack([(p[:, 0] - 0.5 * (w + e)) * fx, (p[:, 1] - 0.5 * (s + n)) * fy,
                     p[:, 2] * ex], axis=1)


def load_path_json(path_file: str | os.PathLike, terrain_meta: dict | None = None
                   ) -> CameraPath:
    """Read a JSON camera path (format in the module docstring); ``terrain_meta``: the
    meta of the terrain it is flown over, for a path in dataset coordinates.

    Raises :class:`PathError` with a one-line message for a missing or
    unreadable file, invalid JSON, a wrong ``format``/``version``, an empty
    ``frames`` list or a malformed frame.
    """
    p = Path(path_file)
    if not p.is_file():
        raise PathError(f"camera path file not found: '{p}'")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise PathError(f"cannot read camera path '{p}': {exc}") from exc
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PathError(f"{p}: invalid JSON at line {exc.lineno}, column {exc.colno}: "
                        f"{exc.msg}") from exc
    return CameraPath.from_dict(doc, source=str(p), default_name=p.stem,
                                terrain_meta=terrain_meta)


def _finite_float(v: object) -> float | None:
    """``float(v)`` for a finite real number that is not a bool, else None."""
    if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _vec3(frame: dict, key: str, where: str) -> np.ndarray:
    v = frame[key]
    if not isinstance(v, list) or len(v) != 3:
        raise PathError(f"{where}: \"{key}\" must be a list of 3 numbers, got {v!r}")
    out = [_finite_float(c) for c in v]
    if any(c is None for c in out):
        raise PathError(f"{where}: \"{key}\" must hold 3 finite numbers, got {v!r}")
    return np.array(out, dtype=np.float64)


def _placed(frame: object, index: int, source: str, meta: dict) -> dict:
    """A look-at frame in dataset coordinates with its eye and target in the world's."""
    where = f"{source}: frame {index}"
    if not isinstance(frame, dict) or not {"eye", "target"} <= set(frame):
        raise PathError(f"{where}: a path in dataset coordinates has look-at frames "
                        "(eye, target[, up])")
    pts = np.stack([_vec3(frame, "eye", where), _vec3(frame, "target", where)])
    try:
        eye, target = dataset_to_world(pts, meta)
    except PathError as exc:
        raise PathError(f"{source}: {exc}") from None
    return {**frame, "eye": eye.tolist(), "target": target.tolist()}


def _parse_frame(frame: object, index: int, source: str) -> Viewpoint:
    where = f"{source}: frame {index}"
    if not isinstance(frame, dict):
        raise PathError(f"{where}: a frame must be a JSON object, got {type(frame).__name__}")
    keys = set(frame)
    tuple_keys, lookat_keys = {"x", "y", "z", "o"}, {"eye", "target", "up"}
    if keys == tuple_keys:
        x, y, z, o = (_vec3(frame, k, where) for k in ("x", "y", "z", "o"))
        axes = np.stack([x, y, z])
        if not np.allclose(axes @ axes.T, np.eye(3), atol=_AXES_TOL):
            raise PathError(f"{where}: axes x, y, z are not orthonormal")
        if np.linalg.det(axes) < 0:
            raise PathError(f"{where}: axes x, y, z are not right-handed (need x × y = z)")
        try:
            return Viewpoint(x, y, z, o)
        except InputError as exc:
            raise PathError(f"{where}: {exc}") from exc
    if {"eye", "target"} <= keys <= lookat_keys:
        eye, target = _vec3(frame, "eye", where), _vec3(frame, "target", where)
        up = _vec3(frame, "up", where) if "up" in frame else np.array([0.0, 0.0, 1.0])
        view = target - eye
        dist = float(np.linalg.norm(view))
        if dist <= 1e-9 * max(1.0, float(np.abs(eye).max())):
            raise PathError(f"{where}: \"eye\" and \"target\" are the same point")
        if float(np.linalg.norm(up)) == 0.0:
            raise PathError(f"{where}: \"up\" is the zero vector")
        if np.linalg.norm(np.cross(up / np.linalg.norm(up), view / dist)) < 1e-9:
            raise PathError(f"{where}: \"up\" is parallel to the viewing direction")
        try:
            return look_at(eye, target, up)
        except InputError as exc:
            raise PathError(f"{where}: {exc}") from exc
    raise PathError(f"{where}: expected keys x, y, z, o or eye, target[, up]; "
                    f"got {', '.join(sorted(map(str, keys))) or 'none'}")


def _check_frames(frames: object) -> int:
    if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or frames < 2:
        raise PathError(f"a camera path needs an integer number of frames >= 2, got {frames!r}")
    return int(frames)


