"""Camera paths: the fly-throughs of the LOD-sprite papers and a JSON path format.

Two built-in paths reproduce the animations of the papers:

* :func:`chen1999` -- Chen, Swan & Kaufman (1999), "Multi-resolution Image-based
  Rendering for Time-critical Applications" (the LOD-sprite paper), **Figure 7**:
  a 460-frame orbit around the centre of the terrain that comes down from the
  zenith, circles it and closes in.  The paper's **Figure 10** renders the same
  path with 115, 230, 460, 920 and 1840 frames; ``chen1999(hf, frames=N)`` keeps
  the geometric curve fixed and only changes how densely it is sampled.
* :func:`swan2002` -- Swan, Arango & Nakshatrala (2002), "Interactive,
  Distributed, Hardware-Accelerated LOD-Sprite Terrain Rendering with Stable
  Frame Rates", whose 600-frame path "starts away from the terrain, zooms in,
  flies over a plain, and then over a mountain range and onto the plain
  beyond".  The paper does not give coordinates, so the plain and the range are
  found in the height field (see the function's docstring).

A :class:`CameraPath` is a sequence of :class:`~lodsprite.camera.Viewpoint`
(OpenGL convention: ``x`` screen-right, ``y`` screen-up, the camera looks along
``-z``) plus a vertical field of view.  World space is that of
:class:`~lodsprite.terrain.heightfield.HeightField`: metres, ``+x`` east,
``+y`` north, ``+z`` up, the terrain's horizontal centre at the origin.

A fourth, :func:`patrol`, flies back and forth over one stretch (several passes, the case
of the 1999 paper's keyframe cache, :mod:`lodsprite.paths.flyover`).

A third, :func:`flyover`, is not a paper's: a low flight of fixed height and length in
metres, the same over a terrain of any size (for comparing renderers across sizes).
A fourth, :func:`bank` (:mod:`lodsprite.paths.bank`), is a low S-turn that rolls into its
turns, in metres too (grazing views for the resampling metric).
A fifth, :func:`weave` (:mod:`lodsprite.paths.weave`), flies low among a scene's objects,
weaving east and west as it crosses the terrain's centre.

The JSON file format is documented in :mod:`lodsprite.paths.core`.
"""

from __future__ import annotations

import os
from pathlib import Path

from lodsprite.errors import PathError
from lodsprite.paths.bank import bank, parse_bank
from lodsprite.paths.core import (
    BUILTIN_PATHS,
    CHEN1999_FRAMES,
    PATH_FORMAT,
    PATH_VERSION,
    SWAN2002_FRAMES,
    CameraPath,
    _check_frames,
    load_path_json,
)
from lodsprite.paths.flyover import flyover, parse_flyover, parse_patrol, patrol
from lodsprite.paths.papers import chen1999, swan2002
from lodsprite.paths.weave import parse_weave, weave
from lodsprite.terrain.heightfield import HeightField

__all__ = [
    "BUILTIN_PATHS",
    "CHEN1999_FRAMES",
    "PATH_FORMAT",
    "PATH_VERSION",
    "SWAN2002_FRAMES",
    "CameraPath",
    "bank",
    "chen1999",
    "flyover",
    "get_path",
    "load_path_json",
    "patrol",
    "swan2002",
    "weave",
]


# --------------------------------------------------------------------------- lookup


def get_path(spec: str | os.PathLike, hf: HeightField, frames: int | None = None
             ) -> CameraPath:
    """A camera path by name or file.

    ``spec`` is ``"chen1999"`` (default 460 frames), ``"swan2002"`` (default
    600 frames), ``"flyover[:HEIGHT_M[:TRACK_M]]"`` (460 frames; a low flight of fixed
    height and length, :mod:`lodsprite.paths.flyover`),
    ``"patrol[:HEIGHT_M[:TRACK_M[:PASSES]]]"`` (460 frames; back and forth,
    :mod:`lodsprite.paths.flyover`), ``"bank[:HEIGHT_M[:TRACK_M]]"`` (460 frames; a low
    banking S-turn, :mod:`lodsprite.paths.bank`),
    ``"weave[:HEIGHT_M[:HALF_M[:TURNS]]]"`` (460 frames; low among the objects,
    :mod:`lodsprite.paths.weave`) or a JSON path file (module
    docstring), which is resampled to ``frames`` when given
    (:meth:`CameraPath.resampled`).  A spec ending in ``.json`` that does not exist
    reports the missing file; any other unknown spec raises :class:`PathError`.
    """
    if frames is not None:
        frames = _check_frames(frames)
    key = os.fspath(spec)
    if key.strip().lower() == "chen1999":
        return chen1999(hf, CHEN1999_FRAMES if frames is None else frames)
    if key.strip().lower() == "swan2002":
        return swan2002(hf, SWAN2002_FRAMES if frames is None else frames)
    low = parse_flyover(key)
    if low is not None:
        return flyover(hf, CHEN1999_FRAMES if frames is None else frames, *low)
    back_and_forth = parse_patrol(key)
    if back_and_forth is not None:
        return patrol(hf, CHEN1999_FRAMES if frames is None else frames, *back_and_forth)
    banked = parse_bank(key)
    if banked is not None:
        return bank(hf, CHEN1999_FRAMES if frames is None else frames, *banked)
    among = parse_weave(key)
    if among is not None:
        return weave(hf, CHEN1999_FRAMES if frames is None else frames, *among)
    if Path(key).is_file() or key.lower().endswith(".json"):
        path = load_path_json(key, getattr(hf, "meta", None))
        return path if frames is None else path.resampled(frames)
    raise PathError(f"unknown path '{key}': use chen1999, swan2002, "
                    "flyover[:HEIGHT_M[:TRACK_M]], patrol[:HEIGHT_M[:TRACK_M[:PASSES]]], "
                    "bank[:HEIGHT_M[:TRACK_M]], weave[:HEIGHT_M[:HALF_M[:TURNS]]] "
                    "or a .json file")
