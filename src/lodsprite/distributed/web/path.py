"""The ``path`` control op of a web page's session: the viewpoints of a built-in camera
path (:func:`lodsprite.paths.get_path`: Chen, Swan & Kaufman 1999 Figure 7's orbit,
Swan et al. 2002's fly-in, ...) over the session's loaded terrain, computed by the server
so that the page plays exactly the path the Python side plays (one implementation of the
paths, not a second one in JavaScript).

The reply's ``data``: ``viewpoints`` (a list of 12 numbers per frame: the camera axes
``x, y, z`` then the eye ``o``, metres, as :class:`~lodsprite.camera.Viewpoint`) and
``fov`` (the path's vertical field of view in degrees).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lodsprite.distributed.protocol import LoadArgs, PathArgs

__all__ = ["path_data", "send_path"]


def path_data(load: LoadArgs, args: PathArgs) -> dict:
    """The reply data of ``path`` for a session whose resolved ``load`` is ``load``
    (terrain as a loader spec); raises :class:`~lodsprite.errors.LodspriteError` for a
    path the terrain cannot give."""
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene

    scene = load_scene(load.terrain, load.texture, load.grid, load.exaggeration)
    path = get_path(args.spec, scene.hf, args.frames)
    rows = np.array([np.concatenate([vp.x, vp.y, vp.z, vp.o]) for vp in path.viewpoints],
                    dtype=np.float64)
    return {"viewpoints": rows.tolist(), "fov": float(path.fov_y_deg)}


async def send_path(session: Any, args: PathArgs, seq: int) -> None:
    """Answer a session's ``path`` request (in a thread: the terrain may take a moment)."""
    import asyncio

    from lodsprite.errors import LodspriteError

    load = session.load
    if load is None:
        session.reply(seq, False, "path: load a scene first")
        return
    try:
        data = await asyncio.to_thread(path_data, load, args)
    except (LodspriteError, MemoryError, OSError, ValueError) as exc:
        session.reply(seq, False, f"path: {exc}")
        return
    if not session.closed:
        session.reply(seq, True, data=data)
