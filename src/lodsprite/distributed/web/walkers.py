"""The moving objects of a scene file (and a crowd's members, standing: see
:func:`lodsprite.distributed.served.page_drawn`), as a web page draws them itself each
frame.

A scene's static layers (terrain, standing objects) reach the page as keyframes; its
walkers move every frame, so a keyframe of them would be stale by its latency.  The page
draws them (``static/walkers.js``): each frame it places every walker with the closed-form
walk (:func:`lodsprite.scene.walk.walk`, ported, cross-checked to 1e-9) on the ground
(:meth:`~lodsprite.terrain.HeightField.height_at`, ported), picks each walker's LOD by
its distance (Gumbau et al. §4.2, :func:`lodsprite.manager.core.desired_lod`: linear
between ``near`` and ``far``; the coarsest shipped level whose share of the triangles is
at or above it) and
draws each (type, level) as one instanced draw, depth tested against the spriteframe's
depth mesh (the keyframe's own surface).

:func:`walker_header` is the ``walkers`` entry of the ``scene`` message
(:class:`~lodsprite.distributed.messages.WalkerSet`): per moving type its vertices
(position, normal, colour: ``(V, 9) float32``) and index buffers at :data:`LEVELS` of its
triangles (its LOD model's own ``extract``), then per walker its start ``xy0``, heading,
speed, walking rectangle and type, and the ground heights (at most
:data:`~lodsprite.distributed.messages.MAX_GROUND_SIDE` a side: a larger terrain's are
sampled bilinearly on a coarser grid over the same extent, its walkers then standing on a
coarser ground than lodsprite's own).  Little-endian bytes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from lodsprite.scene.world import World

from lodsprite.distributed.messages import MAX_GROUND_SIDE

__all__ = ["LEVELS", "decode_walkers", "walker_arrays", "walker_header"]

LEVELS = (1.0, 0.5, 0.25, 0.0)
"""Fractions of a type's triangles shipped (0: its coarsest, the model's floor)."""
NEAR_HEIGHTS, FAR_HEIGHTS = 2.0, 150.0
"""The LOD range in heights of the tallest type (the window's objects layer's)."""


def _f32(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, "<f4").tobytes()


def _f64(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, "<f8").tobytes()


def walker_arrays(world: World, drawn: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``world``'s moving instances (``drawn``: those of that ``(count,) bool`` mask, the
    standing ones at speed 0) as the page gets them: ``xy0 (K, 2)`` metres,
    ``heading (K,)`` radians, ``speed (K,)`` m/s, ``box (K, 4)`` their walking rectangles
    ``(x0, y0, x1, y1)`` (float64 each) and ``type (K,) intp`` (an index into
    ``world.types``), in :attr:`~lodsprite.scene.world.World.instances` order."""
    moving = world.moving() if drawn is None else drawn
    lo, hi = world.walk_bounds()
    box = np.concatenate([np.broadcast_to(lo, (len(moving), 2)),
                          np.broadcast_to(hi, (len(moving), 2))], axis=1)
    return {"xy0": np.concatenate([i.xy for i in world.instances])[moving],
            "heading": np.concatenate([i.yaw for i in world.instances])[moving],
            "speed": np.concatenate([np.full(len(i), i.walk_mps)
                                     for i in world.instances])[moving],
            "box": box[moving], "type": world.type_indices()[moving]}


def walker_header(world: World, drawn: np.ndarray | None = None) -> dict[str, Any] | None:
    """The ``walkers`` entry of a scene message for ``world``'s moving instances (None:
    none walks); ``drawn``: the instances of that ``(count,) bool`` mask instead, the
    standing ones at speed 0 (:func:`lodsprite.distributed.served.page_drawn`)."""
    from lodsprite.layered.objects import world_crowd

    moving = world.moving() if drawn is None else drawn
    if not moving.any():
        return None
    crowd = world_crowd(world)
    a = walker_arrays(world, moving)
    type_of = a["type"]
    used = sorted(set(type_of.tolist()))
    remap = np.full(len(world.types), -1, np.int64)
    remap[used] = np.arange(len(used))
    types = []
    for t in used:
        model = crowd.models[t]
        vertices = np.concatenate([model.vertices, model.normals, model.colors], axis=1)
        levels, seen = [], set()
        for f in LEVELS:
            idx = np.asarray(model.extract(f), np.uint32)
            if len(idx) in seen:  # a level the model cannot make coarser
                continue
            seen.add(len(idx))
            levels.append({"fraction": float(f), "indices": idx.astype("<u4").tobytes()})
        types.append({"name": world.types[t].name, "vertices": _f32(vertices),
                      "levels": levels})
    hf = world.ground_field
    ground, gdx, gdy = hf.heights, hf.dx, hf.dy
    if max(hf.rows, hf.cols) > MAX_GROUND_SIDE:  # sampled over the whole extent, edges kept
        k = (max(hf.rows, hf.cols) - 1) / (MAX_GROUND_SIDE - 1)
        rows, cols = (max(2, int((n - 1) / k) + 1) for n in (hf.rows, hf.cols))
        xs = np.linspace(-hf.width / 2, hf.width / 2, cols)
        ys = np.linspace(hf.depth / 2, -hf.depth / 2, rows)  # row 0 north
        gx, gy = np.meshgrid(xs, ys)
        ground = hf.height_at(gx, gy).astype(np.float32)
        gdx, gdy = hf.width / (cols - 1), hf.depth / (rows - 1)
    height = max(float(t.height_m) for t in world.types)
    return {"types": types, "count": int(moving.sum()),
            "xy0": _f64(a["xy0"]), "heading": _f64(a["heading"]), "speed": _f64(a["speed"]),
            "box": _f64(a["box"]), "type": remap[type_of].astype("<u2").tobytes(),
            "ground": _f32(ground), "ground_shape": [int(ground.shape[0]), int(ground.shape[1])],
            "ground_dx": float(gdx), "ground_dy": float(gdy),
            "near": NEAR_HEIGHTS * height, "far": FAR_HEIGHTS * height}


def decode_walkers(ws: Any) -> dict[str, Any]:
    """The arrays of a scene message's :class:`~lodsprite.distributed.messages.WalkerSet`
    (its caps already checked by the schema): ``types`` (per type ``vertices (V, 9)
    float32`` and ``levels``, ``(fraction, indices (T, 3) uint32)`` each), ``xy0``,
    ``heading``, ``speed``, ``box``, ``type``, ``ground (rows, cols) float32`` and the
    scalars; raises :class:`~lodsprite.distributed.messages.ProtocolError` when a length,
    an index or a number is not what the header says."""
    from lodsprite.distributed.messages import ProtocolError

    def arr(b: bytes, dtype: str, width: int, what: str) -> np.ndarray:
        size = np.dtype(dtype).itemsize * width
        if len(b) % size:
            raise ProtocolError(f"walkers: {what} is not whole rows")
        return np.frombuffer(b, dtype).reshape(-1, width) if width > 1 else np.frombuffer(
            b, dtype)

    k = ws.count
    out: dict[str, Any] = {"types": []}
    for t in ws.types:
        v = arr(t.vertices, "<f4", 9, f"{t.name}: vertices")
        if not np.isfinite(v).all():
            raise ProtocolError(f"walkers: {t.name}: a vertex is not finite")
        levels = []
        for lv in t.levels:
            idx = arr(lv.indices, "<u4", 3, f"{t.name}: indices")
            if idx.size and int(idx.max()) >= len(v):
                raise ProtocolError(f"walkers: {t.name}: a triangle names vertex "
                                    f"{int(idx.max())} of {len(v)}")
            levels.append((lv.fraction, idx))
        out["types"].append({"name": t.name, "vertices": v, "levels": levels})
    fields = {"xy0": ("<f8", 2), "heading": ("<f8", 1), "speed": ("<f8", 1),
              "box": ("<f8", 4), "type": ("<u2", 1)}
    for name, (dtype, width) in fields.items():
        a = arr(getattr(ws, name), dtype, width, name)
        if len(a) != k:
            raise ProtocolError(f"walkers: {name} has {len(a)} rows, count is {k}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise ProtocolError(f"walkers: {name}: a number is not finite")
        out[name] = a
    if k and int(out["type"].max()) >= len(ws.types):
        raise ProtocolError(f"walkers: type {int(out['type'].max())} of {len(ws.types)}")
    rows, cols = ws.ground_shape
    ground = arr(ws.ground, "<f4", 1, "ground")
    if len(ground) != rows * cols or not np.isfinite(ground).all():
        raise ProtocolError(f"walkers: ground is not {rows} x {cols} finite heights")
    out["ground"] = ground.reshape(rows, cols)
    for name in ("ground_dx", "ground_dy", "near", "far"):
        out[name] = getattr(ws, name)
    return out
