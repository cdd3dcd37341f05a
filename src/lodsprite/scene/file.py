"""The scene file: TOML, read and validated at the edge (issue 23, must-haves 1 and 6).

A scene file puts a terrain, mesh objects and light fields in one world
(``docs/scenes.md`` documents every field)::

    [terrain]                 # as --terrain takes: a DEM, a store, fractal:N, jacksboro
    source = "fractal:256"
    [[objects]]               # one mesh (or a glTF group of meshes) and its placement
    mesh = "ogre"             # a built-in (ogre, tree) or any mesh file trimesh reads
    count = 300               # scattered with `seed` over the terrain ... or
    points = "trees.csv"      # ... x,y per line, the terrain's world metres
    [[lightfields]]
    source = "statue.lf"
    position = [120.0, -30.0]
    height_m = 30.0
    [view]
    path = "flyover"

:func:`read_scene_file` parses the file with :mod:`tomllib`, converts it into the
msgspec structs below (unknown fields refused), checks every value and cap (but what a
technique makes of ``[terrain] mode`` and its options: the technique registry's check,
:func:`lodsprite.techniques.scenes.checked`, which :func:`lodsprite.open_scene` runs),
and resolves every path (:func:`resolve_path`: relative to the file's folder, never out of it).
Anything wrong is one :class:`~lodsprite.errors.SceneFileError` line naming the file and
the field, e.g. ``scene.toml: objects[1].count: must be <= 200000``; a syntax error names
the line and column.  What needs the terrain (points and positions inside its extent)
is checked by :func:`lodsprite.scene.world.load_scene_file`, still before anything is
written.
"""

from __future__ import annotations

import os
import re
import tomllib
from importlib.metadata import entry_points
from pathlib import Path
from typing import Literal, NoReturn

import msgspec

from lodsprite.errors import InputError, SceneFileError

#: Caps on what a scene file may ask for (documented in docs/scenes.md).
MAX_FILE_BYTES = 1 << 20
MAX_OBJECT_SECTIONS = 64
MAX_LIGHTFIELDS = 16
MAX_INSTANCES = 200_000          # count summed over the sections, and instances in all
MAX_POINTS_BYTES = 16 << 20
MAX_POINTS_ROWS = 200_000
MAX_MESH_BYTES = 256 << 20
MAX_MESH_FACES = 2_000_000
MAX_GLTF_NODES = 20_000          # mesh nodes in one glTF (each is a group member)
MAX_HEIGHT_M = 10_000.0
MAX_WALK_MPS = 100.0
MIN_LOD_FLOOR = 0.005            # [[objects]] lod_floor: the coarsest LOD's fraction
MAX_GRID = 8192                  # [terrain] grid, quads a side (as the server's cap)
MAX_TERRAIN_OPTIONS = 64         # [terrain.options] entries
TERRAIN_BUILTINS = ("jacksboro",)
#: The entry-point group of built-in models, mesh names that are not files: each entry
#: point names a callable ``(min_fraction=...) -> LOD model`` (``ogre`` and ``tree``, the
#: crowd's, registered in pyproject.toml); the scene package imports no technique package.
MESH_GROUP = "lodsprite.object_models"
_SIZE = r"\s*(\d+)\s*[xX]\s*(\d+)\s*"     # [view] size: WxH


class TerrainSection(msgspec.Struct, forbid_unknown_fields=True):
    """``[terrain]``: ``source`` as ``--terrain`` takes, ``grid`` (quads a side, a power of
    two), ``exaggeration`` and ``texture`` as the same options of ``lodsprite render``;
    ``mode``: the terrain technique that draws it (any of the registry's, ``lodsprite
    info``) and ``options``: that technique's options (``[terrain.options]``, name ->
    value, as written: checked by the technique's declarations when the scene opens,
    :func:`lodsprite.techniques.scenes.checked`)."""

    source: str
    grid: int | None = None
    exaggeration: float = 1.0
    texture: str = "terrain"
    mode: str | None = None
    options: dict[str, str | int | float | bool] = {}


class ObjectSection(msgspec.Struct, forbid_unknown_fields=True):
    """``[[objects]]``: a mesh and where its instances stand (see docs/scenes.md)."""

    mesh: str
    height_m: float | None = None
    count: int | None = None
    seed: int = 0
    points: str | None = None
    walk_mps: float = 0.0
    lod: Literal["profile", "linear"] = "linear"
    lod_floor: float = 0.1
    up: Literal["y", "z"] | None = None
    area: tuple[float, float, float, float] | None = None


class LightFieldSection(msgspec.Struct, forbid_unknown_fields=True):
    """``[[lightfields]]``: a lumigraph folder placed at ``position`` (world metres)."""

    source: str
    position: tuple[float, float]
    height_m: float


class ViewSection(msgspec.Struct, forbid_unknown_fields=True):
    """``[view]``: the camera ``path`` spec (or JSON file), and optional image ``size``
    (``WxH``), vertical ``fov`` (degrees) and ``target_fps`` for the commands to use."""

    path: str = "flyover"
    size: str | None = None
    fov: float | None = None
    target_fps: float | None = None

    def size_px(self) -> tuple[int, int] | None:
        """``size`` as ``(width, height)`` pixels, or None when the file gives none."""
        m = None if self.size is None else re.fullmatch(_SIZE, self.size)
        return None if m is None else (int(m.group(1)), int(m.group(2)))


class SceneFile(msgspec.Struct, forbid_unknown_fields=True):
    """A validated scene file: every path absolute (resolved against the file's folder)."""

    terrain: TerrainSection
    objects: list[ObjectSection] = []
    lightfields: list[LightFieldSection] = []
    view: ViewSection = msgspec.field(default_factory=ViewSection)


def builtin_meshes() -> tuple[str, ...]:
    """The built-in model names (the :data:`MESH_GROUP` entry points), sorted."""
    return tuple(sorted({ep.name for ep in entry_points(group=MESH_GROUP)}))


def read_scene_file(path: str | os.PathLike, root: str | os.PathLike | None = None
                    ) -> SceneFile:
    """Read, validate and resolve the scene file at ``path``; raises
    :class:`~lodsprite.errors.SceneFileError` (one line naming the field).  With ``root``
    (a server's data folder) the file and every file it refers to must resolve, symlinks
    followed, inside ``root``: relative names only, no URL, no symlink inside a store or
    a light field, a glTF's external files inside too (:mod:`lodsprite.scene.confine`)."""
    label = os.fspath(path)
    p = Path(path).expanduser()
    if root is not None:
        root = Path(root).resolve()
        if not p.resolve().is_relative_to(root):
            raise SceneFileError(f"{label}: the scene file lies outside the data folder")
    if not p.is_file():
        raise SceneFileError(f"{label}: no such scene file")
    if p.stat().st_size > MAX_FILE_BYTES:
        raise SceneFileError(f"{label}: the file is over {MAX_FILE_BYTES} bytes")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise SceneFileError(f"{label}: not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneFileError(f"{label}: {_syntax(str(exc))}") from None
    except (RecursionError, MemoryError):
        raise SceneFileError(f"{label}: nested too deeply (or too large) to read") from None
    try:
        scene = msgspec.convert(data, SceneFile)
    except msgspec.ValidationError as exc:
        raise SceneFileError(f"{label}: {_field_message(str(exc))}") from None
    except (RecursionError, MemoryError):
        raise SceneFileError(f"{label}: nested too deeply (or too large) to read") from None
    _Checker(label, p.resolve().parent, root).check(scene)
    return scene


def _syntax(message: str) -> str:
    """tomllib's ``"... (at line L, column C)"`` as ``"line L, column C: TOML syntax ..."``."""
    m = re.search(r"\s*\(at line (\d+), column (\d+)\)\s*$", message)
    if m is None:
        return f"TOML syntax error: {message}"
    return f"line {m.group(1)}, column {m.group(2)}: TOML syntax error: {message[:m.start()]}"


def _field_message(message: str) -> str:
    """msgspec's ``"WHAT - at `$.a[0].b`"`` as ``"a[0].b: WHAT"`` (a missing or unknown
    field named in the path)."""
    what, _, where = message.partition(" - at `$")
    where = where.rstrip("`").lstrip(".")
    field = re.search(r"(missing required|unknown) field `([^`]+)`", what)
    if field is not None:
        where = f"{where}.{field.group(2)}" if where else field.group(2)
        what = "required" if field.group(1) == "missing required" else "unknown field"
    what = what.replace(" | null", "")
    return f"{where or 'scene'}: {what[:1].lower()}{what[1:]}"


def resolve_path(value: str, folder: Path, field: str, label: str) -> Path:
    """``value`` as a path: absolute (or ``~``) as given; relative against ``folder``, the
    scene file's, and refused when its ``..`` parts lead out of it."""
    raw = Path(value).expanduser()
    if raw.is_absolute():
        return raw
    joined = Path(os.path.normpath(folder / raw))
    if not joined.is_relative_to(folder):
        raise SceneFileError(f"{label}: {field}: {value!r} leads out of the scene file's "
                             "folder; give an absolute path instead")
    return joined


class _Checker:
    """The checks :func:`read_scene_file` makes after the types, section by section; each
    ``fail`` is one line ``LABEL: FIELD: what``."""

    def __init__(self, label: str, folder: Path, root: Path | None = None) -> None:
        self.label, self.folder, self.root = label, folder, root

    def fail(self, field: str, what: str) -> NoReturn:
        raise SceneFileError(f"{self.label}: {field}: {what}")

    def file(self, value: str, field: str, max_bytes: int | None = None,
             folder_ok: bool = False) -> str:
        if self.root is None:
            p = resolve_path(value, self.folder, field, self.label)
        else:
            p = self.confined(value, field)
        if not (p.is_file() or (folder_ok and p.is_dir())):
            self.fail(field, f"no such file: {p}")
        if max_bytes is not None and p.is_file() and p.stat().st_size > max_bytes:
            self.fail(field, f"{p.name} is over {max_bytes} bytes")
        return str(p)

    def confined(self, value: str, field: str) -> Path:
        """``value`` inside the root, a folder there free of symlinks, a glTF's external
        files inside too."""
        from lodsprite.scene import confine

        assert self.root is not None
        try:
            p = confine.confined(value, self.folder, self.root, field)
            confine.check_tree(p, field)
            if p.is_file() and p.suffix.lower() in (".gltf", ".glb"):
                confine.check_gltf(p, self.root, field)
        except SceneFileError:
            raise
        except InputError as exc:
            raise SceneFileError(f"{self.label}: {exc}") from None
        return p

    def positive(self, value: float | None, field: str, cap: float) -> None:
        if value is not None and not 0 < value <= cap:
            self.fail(field, f"must be > 0 and <= {cap:g}")

    def check(self, scene: SceneFile) -> None:
        self.terrain(scene.terrain)
        if len(scene.objects) > MAX_OBJECT_SECTIONS:
            self.fail("objects", f"at most {MAX_OBJECT_SECTIONS} sections")
        if len(scene.lightfields) > MAX_LIGHTFIELDS:
            self.fail("lightfields", f"at most {MAX_LIGHTFIELDS} sections")
        total = 0
        for i, obj in enumerate(scene.objects):
            self.objects(obj, f"objects[{i}]")
            total += obj.count or 0
            if total > MAX_INSTANCES:
                self.fail(f"objects[{i}].count", f"the counts add up to more than "
                          f"{MAX_INSTANCES}")
        for i, lf in enumerate(scene.lightfields):
            self.lightfield(lf, f"lightfields[{i}]")
        self.view(scene.view)

    def terrain(self, t: TerrainSection) -> None:
        from lodsprite.terrain.heightfield import is_power_of_two
        from lodsprite.terrain.loaders import parse_fractal_spec

        source = t.source.strip()
        if not source:
            self.fail("terrain.source", "must not be empty")
        try:
            builtin = source.lower() in TERRAIN_BUILTINS or parse_fractal_spec(source)
        except ValueError as exc:
            self.fail("terrain.source", str(exc))
        if not builtin:
            t.source = self.file(source, "terrain.source", folder_ok=True)
        if t.grid is not None and not (16 <= t.grid <= MAX_GRID and is_power_of_two(t.grid)):
            self.fail("terrain.grid", f"must be a power of two >= 16 and <= {MAX_GRID}")
        self.positive(t.exaggeration, "terrain.exaggeration", 1000.0)
        name = t.texture.strip().lower()
        if not (name == "terrain" or name == "checker" or name.startswith("checker:")):
            t.texture = self.file(t.texture, "terrain.texture")
        self.technique(t)

    def technique(self, t: TerrainSection) -> None:
        """``options``: at most :data:`MAX_TERRAIN_OPTIONS`, kept as written; which
        technique ``mode`` names and what its options mean are the technique registry's
        to check (:func:`lodsprite.techniques.scenes.checked`: the scene model knows no
        technique)."""
        if len(t.options) > MAX_TERRAIN_OPTIONS:
            self.fail("terrain.options", f"at most {MAX_TERRAIN_OPTIONS} options")

    def objects(self, o: ObjectSection, at: str) -> None:
        if o.mesh.strip().lower() in builtin_meshes():  # built in (ogre, tree), not files
            o.mesh = o.mesh.strip().lower()
        else:
            o.mesh = self.file(o.mesh, f"{at}.mesh", MAX_MESH_BYTES)
            if o.height_m is None and Path(o.mesh).suffix.lower() not in (".glb", ".gltf"):
                self.fail(f"{at}.height_m", "required for a mesh file other than glTF "
                          "(its units are unknown)")
        self.positive(o.height_m, f"{at}.height_m", MAX_HEIGHT_M)
        if o.count is not None and o.points is not None:
            self.fail(f"{at}.points", "give count or points, not both")
        if o.count is not None and not 1 <= o.count <= MAX_INSTANCES:
            self.fail(f"{at}.count", f"must be >= 1 and <= {MAX_INSTANCES}")
        if o.points is not None:
            o.points = self.file(o.points, f"{at}.points", MAX_POINTS_BYTES)
        if not 0 <= o.seed < 2**63:
            self.fail(f"{at}.seed", "must be >= 0")
        if not 0 <= o.walk_mps <= MAX_WALK_MPS:
            self.fail(f"{at}.walk_mps", f"must be >= 0 and <= {MAX_WALK_MPS:g}")
        if not MIN_LOD_FLOOR <= o.lod_floor <= 1.0:
            self.fail(f"{at}.lod_floor", f"must be >= {MIN_LOD_FLOOR:g} and <= 1 (the "
                      "fraction of the triangles the coarsest LOD keeps)")
        if o.area is not None and not (all(map(_finite, o.area)) and o.area[0] < o.area[2]
                                       and o.area[1] < o.area[3]):
            self.fail(f"{at}.area", "expected [x0, y0, x1, y1], finite, x0 < x1 and y0 < y1")

    def lightfield(self, lf: LightFieldSection, at: str) -> None:
        source = self.file(lf.source, f"{at}.source", folder_ok=True)
        if not (Path(source) / "lumigraph.json").is_file():
            self.fail(f"{at}.source", f"not a lumigraph folder (no lumigraph.json): {source}")
        lf.source = source
        if not all(map(_finite, lf.position)):
            self.fail(f"{at}.position", "must be finite")
        self.positive(lf.height_m, f"{at}.height_m", MAX_HEIGHT_M)

    def view(self, v: ViewSection) -> None:
        if v.path.strip().lower().endswith(".json"):
            v.path = self.file(v.path, "view.path")
        if v.size is not None:
            m = re.fullmatch(_SIZE, v.size)
            if m is None or not all(16 <= int(g) <= 8192 for g in m.groups()):
                self.fail("view.size", "expected WxH, each 16..8192 pixels")
        if v.fov is not None and not 1.0 <= v.fov <= 170.0:
            self.fail("view.fov", "must be 1..170 degrees")
        self.positive(v.target_fps, "view.target_fps", 1000.0)


def _finite(x: float) -> bool:
    return x == x and abs(x) != float("inf")
