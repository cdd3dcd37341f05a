"""The battlefield's scene (Chen, Swan & Kaufman 1999 built LOD-sprite for a battlefield
of terrain and entities; issue 23): a terrain store, light fields captured of built-in
objects and the scene file that puts them with a crowd and trees on the terrain.

* the terrain: a fractal spec (``fractal:4096:1``) tiled into ``OUT/stores`` with the
  store builder (:func:`~lodsprite.terrain.store.build_store`), the scene's working grid
  the store's own side (4097² heights in memory: the ground the instances stand on and
  the paths clear is level 0's), or ``--terrain`` as given
  (a store is used as it is; ``jacksboro``, a DEM or another spec is read by the scene);
* the light fields: small lumigraphs (:func:`~lodsprite.lumigraph.run.
  capture_lumigraph`) of the built-in still life and of the built-in ogre (its mesh
  written to a PLY file first) into ``OUT/lightfields``, captured once and reused while
  their capture settings are unchanged;
* ``OUT/battlefield.toml``: the scene file (:mod:`lodsprite.scene.file`) with absolute
  paths, read back by :func:`~lodsprite.scene.world.load_scene_file`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lodsprite.files import atomic_write_bytes

#: The built-in objects captured as light fields, and where each stands (metres from the
#: centre of the crowd's area, as a fraction of its half side).
LIGHTFIELD_OBJECTS = (("still-life", (0.35, -0.2)), ("ogre", (-0.5, 0.3)))


def terrain_source(spec: str, stores: Path) -> tuple[str, dict]:
    """The scene's ``[terrain] source`` for ``spec`` and how it was made: a ``fractal:``
    spec tiled into a store under ``stores`` (reused when there), anything else as it is."""
    from lodsprite.terrain.store import build_store, is_store

    if not spec.startswith("fractal:") or is_store(Path(spec)):
        return spec, {"tiled": False, "grid": None}
    name = spec.replace(":", "_")
    out = stores / f"{name}.zarr"
    built = build_store(spec, out)
    side = int(spec.split(":")[1])
    grid = side if side >= 16 and side & (side - 1) == 0 else None
    return str(out.resolve()), {"tiled": True, "store": str(out), "grid": grid,
                                "tile_s": built.get("seconds")}


def _ogre_mesh(path: Path) -> Path:
    """The built-in ogre as a coloured PLY file (what the lumigraph capture reads), turned
    ``+z`` up (a scene type's frame) to ``+y`` up (a lumigraph's world)."""
    import trimesh

    from lodsprite.scene.objects import builtin_type

    if path.is_file():
        return path
    t = builtin_type("ogre", 2.2, "linear")
    colours = (np.clip(t.colours, 0, 1) * 255).astype(np.uint8)
    v = t.vertices
    y_up = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)
    mesh = trimesh.Trimesh(y_up, t.faces, vertex_colors=colours, process=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, mesh.export(file_type="ply"))
    return path


def capture_lightfields(folder: Path, st: int, uv: int, slabs: int, count: int) -> list[dict]:
    """``count`` light fields (at most :data:`LIGHTFIELD_OBJECTS`) under ``folder``, each
    ``slabs`` slabs of ``st``² nodes of ``uv``² pixels; one reused when its settings
    match (``capture.json``).  Returns what each is: folder, object, nodes, capture s."""
    from lodsprite.lumigraph.run import capture_lumigraph

    out = []
    for name, _ in LIGHTFIELD_OBJECTS[:count]:
        lf = folder / name
        settings = {"object": name, "st": st, "uv": uv, "slabs": slabs}
        stamp = lf / "capture.json"
        if stamp.is_file() and json.loads(stamp.read_text()).get("settings") == settings:
            out.append(json.loads(stamp.read_text())["summary"])
            continue
        model = name if name == "still-life" else str(_ogre_mesh(folder / "ogre.ply"))
        s = capture_lumigraph(model, lf, n_st=st, n_uv=uv, slabs=slabs)
        s = {"folder": str(lf), "object": name, "nodes": s["nodes"], "uv": uv,
             "slabs": slabs, "capture_s": s["capture_s"], "faces": s["faces"]}
        atomic_write_bytes(stamp, json.dumps({"settings": settings, "summary": s}).encode())
        out.append(s)
    return out


def scene_text(source: str, cfg, lightfields: list[dict], grid: int | None = None) -> str:
    """The scene file's text: the terrain (``grid``: its working grid, the store's own
    side, so that instances and paths stand on level 0's ground, not a 512² grid's), the
    crowd (``cfg.instances`` walking ogres in ``cfg.area_m``), ``cfg.trees`` trees round
    them, the light fields."""
    a, b = cfg.area_m, 1.5 * cfg.area_m
    lines = ["# The battlefield of lodsprite reproduce battlefield (written by the run).",
             "[terrain]", f"source = {json.dumps(source)}",
             *([f"grid = {grid}"] if grid else []), "",
             "[[objects]]", 'mesh = "ogre"', f"height_m = {cfg.ogre_m}",
             f"count = {cfg.instances}", "seed = 1", f"walk_mps = {cfg.walk_mps}",
             f"area = [{-a}, {-a}, {a}, {a}]", f'lod = "{cfg.ogre_lod}"',
             f"lod_floor = {cfg.lod_floor}", ""]
    if cfg.trees:
        lines += ["[[objects]]", 'mesh = "tree"', f"height_m = {cfg.tree_m}",
                  f"count = {cfg.trees}", "seed = 2", f"area = [{-b}, {-b}, {b}, {b}]",
                  f'lod = "{cfg.tree_lod}"', f"lod_floor = {cfg.lod_floor}", ""]
    for lf, (_, (fx, fy)) in zip(lightfields, LIGHTFIELD_OBJECTS, strict=False):
        lines += ["[[lightfields]]", f"source = {json.dumps(str(Path(lf['folder']).resolve()))}",
                  f"position = [{fx * a}, {fy * a}]", f"height_m = {cfg.lightfield_m}", ""]
    lines += ["[view]", f'path = "{cfg.paths[0]}"', ""]
    return "\n".join(lines)


def write_scene(cfg, out_dir: Path) -> tuple[Path, dict]:
    """Tile the terrain, capture the light fields, write ``OUT/battlefield.toml``; returns
    the file and what was made (``terrain``, ``lightfields``)."""
    source, how = terrain_source(cfg.terrain, out_dir / "stores")
    lights = capture_lightfields(out_dir / "lightfields", cfg.lf_st, cfg.lf_uv, cfg.lf_slabs,
                                 cfg.lightfields)
    path = out_dir / "battlefield.toml"
    atomic_write_bytes(path, scene_text(source, cfg, lights, how["grid"]).encode())
    return path, {"terrain": {"spec": cfg.terrain, "source": source, **how},
                  "lightfields": lights}
